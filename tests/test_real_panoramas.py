"""The real-panorama benchmark (``benchmarks/real_panoramas.py`` and its scoring in :mod:`ncjax.evaluation`): label
rows from label_cor, corner matching, bad input, and a run on renders."""

import csv
from pathlib import Path

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from _scripts import script_module

import ncjax
from ncjax.evaluation.panorama_labels import distinct_corners, label_boundaries, read_label_cor
from ncjax.evaluation.panorama_scores import match_one_to_one, one_to_one_pairs, row_error
from ncjax.synth.dataset import label_cor_rows

WIDTH, HEIGHT = 1024, 512


def benchmark_module():
    """The module of ``benchmarks/real_panoramas.py``."""
    return script_module("benchmarks", "real_panoramas")


def central_room(corners, ceiling_height=1.5, floor_height=-1.4) -> ncjax.synth.Room:
    """A room seen by a central camera (rc = 0) at the origin; ``corners`` counter-clockwise."""
    corners = jnp.asarray(corners, jnp.float32)
    return ncjax.synth.Room(
        corners=corners,
        mask=jnp.ones(len(corners), bool),
        ceiling_height=jnp.asarray(ceiling_height, jnp.float32),
        floor_height=jnp.asarray(floor_height, jnp.float32),
        rc=jnp.asarray(0.0, jnp.float32),
        camera_position=jnp.asarray([0.0, 0.0, -floor_height], jnp.float32),
        is_atlanta=jnp.array(True),
        status=jnp.array(ncjax.synth.RoomStatus.OK, jnp.int32),
    )


ROOMS = {
    "off-centre rectangle": [(-1.5, -2.0), (3.0, -2.0), (3.0, 1.2), (-1.5, 1.2)],
    "L with an occlusion": [(-5.0, -1.0), (1.0, -1.0), (1.0, 2.0), (-2.0, 2.0), (-2.0, 4.0), (-5.0, 4.0)],
    "oblique pentagon": [(-2.0, -1.5), (2.5, -2.0), (3.0, 1.0), (0.5, 2.5), (-2.5, 1.5)],
}


def exact_label_cor(labels: ncjax.synth.RoomLabels, cam: ncjax.NonCentralPanorama) -> np.ndarray:
    """The (2N, 2) label_cor of :func:`label_cor_rows` before its rounding to integer pixels."""
    mask = np.asarray(labels.corner_mask)
    points = np.stack([np.asarray(labels.ceiling_corners)[mask], np.asarray(labels.floor_corners)[mask]], 1)
    _, rows = ncjax.geometry.project(cam, points)
    columns = np.repeat(np.asarray(labels.corner_u)[mask], 2)
    return np.stack([columns, np.asarray(rows).reshape(-1)], axis=-1)


def label_rows_from_file(label_cor: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The benchmark's label rows of a label_cor array written to ``path``, and its label corner columns."""
    path.write_text("".join(f"{x:.4f} {y:.4f}\n" for x, y in label_cor))
    corners = read_label_cor(path, WIDTH, HEIGHT)
    _, _, ceiling_v, floor_v = label_boundaries(corners, WIDTH, HEIGHT)
    return ceiling_v, floor_v, corners[:, 1, 0]


@pytest.mark.slow
@pytest.mark.parametrize("corners", ROOMS.values(), ids=ROOMS.keys())
def test_label_rows_match_the_renderers_exact_rows(corners, tmp_path):
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.0)
    labels = ncjax.synth.room_labels(central_room(corners), cam, corner_capacity=2 * len(corners))
    assert bool(labels.ok)
    exact = (np.asarray(labels.ceiling_v), np.asarray(labels.floor_v))

    # Unrounded corners: the walls cast in 3D give the renderer's rows in every column (interpolating
    # rows linearly between the corners' pixels is 10-30 px off on these rooms).
    *rows, _ = label_rows_from_file(exact_label_cor(labels, cam), tmp_path / "exact.txt")
    for boundary, truth in zip(rows, exact, strict=True):
        assert np.max(np.abs(boundary - truth)) < 0.01

    # The integer pixels the dataset writes: off by the rounding, a fraction of a pixel.
    *rows, columns = label_rows_from_file(label_cor_rows(labels, cam), tmp_path / "rounded.txt")
    for boundary, truth in zip(rows, exact, strict=True):
        assert np.mean(np.abs(boundary - truth)) < 0.5 and np.max(np.abs(boundary - truth)) < 1.0
    # an occlusion's near and far points are one corner to find
    mask = np.asarray(labels.corner_mask)
    distinct = len(np.unique(np.asarray(labels.corner_u)[mask]))
    assert distinct_corners(columns, WIDTH).sum() == distinct


def test_row_errors_in_rows_of_512_absolute_and_signed_over_the_finite_columns():
    label = np.array([100.0, 100.0, 100.0, np.nan])  # a 4-column panorama of 2 rows: 256 rows of 512 a row
    predicted = np.array([101.0, 97.0, np.nan, 50.0])
    assert row_error(predicted, label) == 256 * (1 + 3) / 2
    assert row_error(predicted, label, signed=True) == 256 * (1 - 3) / 2  # below the label is positive
    assert np.isnan(row_error(np.full(4, np.nan), label))


def test_corners_match_one_to_one_across_the_seam():
    peaks = np.array([1023.4, 3.0, 500.0, 700.0])
    targets = np.array([0.2, 505.0, 900.0])
    matched = match_one_to_one(peaks, targets, tolerance=10.0, width=1024)
    assert matched.tolist() == [True, False, True, False]  # one peak per corner, the nearest across the seam
    assert one_to_one_pairs(peaks, targets, tolerance=10.0, width=1024) == [(0, 0), (2, 1)]  # nearest pairs first


def write_image(path: Path, width: int = 128) -> None:
    cv2.imwrite(str(path), np.full((width // 2, width, 3), 128, np.uint8))


def bad_folder(tmp_path: Path, problem: str) -> Path:
    folder = tmp_path / problem
    folder.mkdir()
    if problem == "no labelled image":
        write_image(folder / "a.png")
    elif problem == "unreadable image":
        (folder / "a.jpg").write_bytes(b"not a jpeg")
        (folder / "a.txt").write_text("10 20\n10 40\n40 20\n40 40\n90 20\n90 40\n")
    elif problem == "malformed label":
        write_image(folder / "a.png")
        (folder / "a.txt").write_text("10 20 5\n10 x\n")
    elif problem == "floor above the horizon":
        write_image(folder / "a.png")
        (folder / "a.txt").write_text("10 20\n10 25\n40 20\n40 40\n90 20\n90 40\n")
    return folder


@pytest.mark.slow
@pytest.mark.parametrize(
    "problem", ["missing folder", "no labelled image", "unreadable image", "malformed label", "floor above the horizon"]
)
def test_bad_input_is_one_line_and_exit_code_2(problem, tmp_path, capsys):
    folder = tmp_path / "absent" if problem == "missing folder" else bad_folder(tmp_path, problem)
    out = tmp_path / "out"
    assert benchmark_module().main(["--data", str(folder), "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert error.startswith("real_panoramas: error:") and "\n" not in error
    assert not out.exists()


@pytest.fixture(scope="module")
def rendered_folder(tmp_path_factory):
    """Two rendered central rooms without furniture at the network's input size, in ``ncjax synth``'s folders."""
    folder = tmp_path_factory.mktemp("renders") / "data"
    room, scene = ncjax.RoomConfig(rc_range=(0.0, 0.0)), ncjax.synth.SceneConfig(furniture_probability=0.0)
    config = ncjax.SynthConfig(room=room, scene=scene, width=WIDTH, height=HEIGHT)
    names = ncjax.synth.write_dataset(str(folder), 2, seed=5, config=config, batch_size=2)
    return folder, names


@pytest.mark.slow
def test_benchmark_on_renders(rendered_folder, tmp_path):
    folder, names = rendered_folder
    out = tmp_path / "out"
    assert benchmark_module().main(["--data", str(folder), "--out", str(out), "--views", "1"]) == 0

    with open(out / "real_panoramas.csv") as file:
        rows = list(csv.DictReader(file))
    assert [row["name"] for row in rows[:-1]] == sorted(names) and rows[-1]["name"].startswith("mean")
    assert (out / "contact_sheet.png").stat().st_size > 0
    for row in rows:
        figures = {key: float(value) for key, value in row.items() if key not in ("name", "tags")}
        assert all(np.isfinite(value) for value in figures.values())
        assert figures["ceiling_error_px"] < 5.0 and figures["floor_error_px"] < 5.0
        assert abs(figures["floor_signed_error_px"]) <= figures["floor_error_px"]
        for key in ("precision_1pct", "recall_1pct", "precision_2.5pct", "recall_2.5pct", "iou_2d", "iou_3d"):
            assert 0.0 <= figures[key] <= 1.0
        assert figures["iou_2d"] > 0.8 and figures["iou_3d"] > 0.7


@pytest.mark.slow
def test_benchmark_adapts_the_network_to_each_panorama_when_asked(rendered_folder, tmp_path):
    """``--adapt``: the network fitted to each render's flat floor and ceiling first reads its rows as well (renders
    of furniture-free rooms, whose rows are already on the walls)."""
    folder, _ = rendered_folder
    runs = {}
    for run, options in (("plain", []), ("adapted", ["--adapt"])):
        out = tmp_path / run
        assert benchmark_module().main(["--data", str(folder), "--out", str(out), "--views", "1", *options]) == 0
        runs[run] = scored_rows(out)
    for name, plain in runs["plain"].items():
        adapted = runs["adapted"][name]
        assert adapted["floor_error_px"] < plain["floor_error_px"] + 1.0, (name, plain, adapted)
        assert adapted["ceiling_error_px"] < plain["ceiling_error_px"] + 1.0, (name, plain, adapted)
    moved = [
        abs(runs["adapted"][name][key] - plain[key])
        for name, plain in runs["plain"].items()
        for key in ("ceiling_error_px", "floor_error_px")
    ]
    assert np.nanmax(moved) > 0.05, moved  # the adaptation moved the rows


def scored_rows(out: Path) -> dict[str, dict[str, float]]:
    with open(out / "real_panoramas.csv") as file:
        return {
            row["name"]: {k: float(v) for k, v in row.items() if k not in ("name", "tags")}
            for row in csv.DictReader(file)
        }


@pytest.mark.slow
def test_benchmark_pads_photo_spheres_and_applies_a_transform(rendered_folder, tmp_path):
    """The renders cut to photo spheres (rows within 70 degrees of the horizon, XMP GPano) score in their full
    panoramas' pixels, as the renders do; a transform given to ``run`` reaches the network."""
    from ncjax.io.photo_sphere import XMP_GPANO, SphereCrop, gpano_packet, png_with_xmp

    folder, names = rendered_folder
    spheres = tmp_path / "spheres"
    spheres.mkdir()
    crop = SphereCrop(WIDTH, HEIGHT, HEIGHT // 9, WIDTH, HEIGHT - 2 * (HEIGHT // 9), XMP_GPANO)
    for name in names:
        image = cv2.imread(str(folder / "img" / f"{name}.png"))[..., ::-1]
        rows = image[crop.top : crop.top + crop.height]
        (spheres / f"{name}.png").write_bytes(png_with_xmp(rows, gpano_packet(crop)))
        (spheres / f"{name}.txt").write_bytes((folder / "label_cor" / f"{name}.txt").read_bytes())
    module = benchmark_module()
    runs = {}
    for run, data, transform in (
        ("full", folder, None),
        ("spheres", spheres, None),
        ("blacked out", folder, lambda image: np.zeros_like(image)),
    ):
        args = module.parse_arguments(["--data", str(data), "--out", str(tmp_path / run), "--views", "1"])
        module.run(args, transform)
        runs[run] = scored_rows(tmp_path / run)
    for name in names:
        full, sphere = runs["full"][name], runs["spheres"][name]
        assert sphere["floor_error_px"] < full["floor_error_px"] + 2.0, (full, sphere)
        assert sphere["ceiling_error_px"] < full["ceiling_error_px"] + 2.0, (full, sphere)
        assert runs["blacked out"][name]["floor_error_px"] > full["floor_error_px"] + 10.0
