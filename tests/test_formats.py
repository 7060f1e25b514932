"""Layout formats of central-panorama tools (label_cor, HorizonNet, PanoAnnotator, ZInD), their metrics and CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import tempfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jaxtyping import install_import_hook

import ncjax
from ncjax import cli

# Shapes and dtypes checked at run time, as conftest.py does for the modules ncjax imports itself.
with install_import_hook(
    ["ncjax.io.formats", "ncjax.io.formats_read", "ncjax.io.layout_corners", "ncjax.evaluation.central_metrics"],
    "beartype.beartype",
):
    from ncjax.evaluation.central_metrics import evaluate_corners, room_geometry
    from ncjax.io.formats import FORMATS, SUFFIXES, write_layout_formats
    from ncjax.io.formats_read import layout_files, read_layout, read_mp3d
    from ncjax.io.layout_corners import LayoutCorners, project_points

DATA = pathlib.Path(__file__).parent / "data" / "formats"
W, H = 1024, 512
H_C, H_F = 1.0, -1.5
# Floor plan in image order (decreasing azimuth, clockwise seen from above), camera inside: 5 x 5 m less 2 x 2 m.
L_SHAPE = [(-2.0, 3.0), (1.0, 3.0), (1.0, 1.0), (3.0, 1.0), (3.0, -2.0), (-2.0, -2.0)]
CENTRAL = ncjax.NonCentralPanorama(W, H, rc=0.0)
NON_CENTRAL = ncjax.NonCentralPanorama(W, H, rc=0.5)


def record_of(plan, ceiling_height=H_C, floor_height=H_F, cam=CENTRAL) -> dict:
    """The corner keys of a layout record (:func:`ncjax.io.export.layout_record`)."""
    plan = np.asarray(plan, np.float64)
    ones = np.ones((len(plan), 1))
    return {
        "ceiling_corners": np.concatenate([plan, ceiling_height * ones], 1).tolist(),
        "floor_corners": np.concatenate([plan, floor_height * ones], 1).tolist(),
        "rc": float(cam.rc),
        "image_size": [cam.width, cam.height],
        "status": "OK",
    }


def leftmost(record: dict, cam) -> int:
    """Index of the corner the writers put first: the leftmost in the image."""
    return int(np.argmin(project_points(cam, np.asarray(record["ceiling_corners"]))[:, 0]))


def expected_pixels(record: dict, cam) -> tuple[np.ndarray, np.ndarray]:
    """Projected ceiling and floor pixels, rolled so the leftmost corner comes first (as the writers do)."""
    ceiling = project_points(cam, np.asarray(record["ceiling_corners"]))
    floor = project_points(cam, np.asarray(record["floor_corners"]))
    shift = leftmost(record, cam)
    return np.roll(ceiling, -shift, 0), np.roll(floor, -shift, 0)


def write_one(tmp_path, record, cam, format) -> pathlib.Path:
    (path,) = write_layout_formats(tmp_path / "room", record, cam, [format])
    return path


# --- round trips ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("cam", [CENTRAL, NON_CENTRAL], ids=["central", "rc=0.5"])
@pytest.mark.parametrize("format", FORMATS)
def test_every_format_round_trips_the_corner_pixels(tmp_path, cam, format):
    record = record_of(L_SHAPE, cam=cam)
    path = write_one(tmp_path, record, cam, format)
    assert path.name == f"room{SUFFIXES[format]}"
    corners = read_layout(path) if format != "label_cor" else read_layout(path, rc=float(cam.rc))
    ceiling, floor = expected_pixels(record, cam)
    assert (corners.width, corners.height, corners.count) == (W, H, 6)
    np.testing.assert_allclose(corners.ceiling, ceiling, atol=0.01)
    np.testing.assert_allclose(corners.floor, floor, atol=0.01)
    if format != "label_cor":  # the JSON formats carry the camera: the 3D corners come back exactly
        assert corners.units == "metres" and corners.rc == pytest.approx(float(cam.rc))
        shift = leftmost(record, cam)
        np.testing.assert_allclose(corners.floor_corners, np.roll(record["floor_corners"], -shift, 0), atol=1e-6)
        np.testing.assert_allclose(corners.ceiling_corners, np.roll(record["ceiling_corners"], -shift, 0), atol=1e-6)


def test_a_layout_and_its_record_write_the_same_files(tmp_path):
    from test_export import make_layout

    layout = make_layout(L_SHAPE, H_C, H_F)
    record = ncjax.io.export.layout_record(layout, NON_CENTRAL, name="room", world="auto")
    from_layout = write_layout_formats(tmp_path / "a", layout, NON_CENTRAL, "label_cor,mp3d")
    from_record = write_layout_formats(tmp_path / "b", record, NON_CENTRAL, ["label_cor", "mp3d"])
    assert [path.name for path in from_layout] == ["a.label_cor.txt", "a.mp3d.json"]
    text_a, text_b = (read_layout(path) for path in (from_layout[0], from_record[0]))
    np.testing.assert_allclose(text_a.label_cor, text_b.label_cor, atol=2e-3)


@pytest.mark.slow
@settings(max_examples=15)
@given(
    corners=st.integers(3, 8),
    radius=st.floats(1.0, 6.0),
    seed=st.integers(0, 2**16),
    rc=st.sampled_from([0.0, 0.3]),
    format=st.sampled_from(FORMATS),
)
def test_random_convex_rooms_round_trip(corners, radius, seed, rc, format):
    """Random convex polygons around the camera (vertices on an ellipse, decreasing azimuth)."""
    generator = np.random.default_rng(seed)
    angles = np.sort(generator.uniform(0, 2 * np.pi, corners))[::-1]
    gaps = np.diff(np.concatenate([angles, angles[:1] - 2 * np.pi]))
    if np.min(np.abs(gaps)) < 0.2 or np.max(np.abs(gaps)) > np.pi - 0.2:  # keeps the camera well inside
        angles = np.linspace(2 * np.pi, 0, corners, endpoint=False) - generator.uniform(0, 1)
    plan = np.stack([radius * np.cos(angles), 0.7 * radius * np.sin(angles)], -1)
    cam = ncjax.NonCentralPanorama(W, H, rc=rc)
    record = record_of(plan, 1.1, -1.4, cam)
    with tempfile.TemporaryDirectory() as folder:
        path = write_one(pathlib.Path(folder), record, cam, format)
        read = read_layout(path, rc=rc)
    ceiling, floor = expected_pixels(record, cam)
    np.testing.assert_allclose(read.ceiling, ceiling, atol=0.01)
    np.testing.assert_allclose(read.floor, floor, atol=0.01)


# --- the files as the other tools read them -----------------------------------------------------------------


def test_label_cor_is_x_y_lines_ceiling_then_floor_leftmost_first(tmp_path):
    path = write_one(tmp_path, record_of(L_SHAPE), CENTRAL, "label_cor")
    rows = [line.split() for line in path.read_text().splitlines()]
    assert len(rows) == 12 and all(len(row) == 2 for row in rows)
    points = np.array(rows, float)
    assert np.array_equal(points[0::2, 0], points[1::2, 0])  # one column per corner (vertical edges)
    assert np.all(points[0::2, 1] < H / 2) and np.all(points[1::2, 1] > H / 2)  # ceiling above, floor below
    assert np.argmin(points[0::2, 0]) == 0 and np.all(np.diff(points[0::2, 0]) > 0)  # left to right


def test_label_cor_of_a_levelled_panorama_is_in_the_input_image(tmp_path):
    """With the levelling rotation R (input -> level), the pixels are those of R^T p in the input image."""
    from ncjax.geometry.gravity import rotation_from_tilt

    record = record_of(L_SHAPE)
    rotation = rotation_from_tilt(4.0, -7.0)
    (path,) = write_layout_formats(tmp_path / "room", record, CENTRAL, ["label_cor"], rotation=rotation)
    points = np.loadtxt(path)
    for key, found in (("ceiling_corners", points[0::2]), ("floor_corners", points[1::2])):
        expected = project_points(CENTRAL, np.asarray(record[key]) @ rotation)
        expected = expected[np.argsort(expected[:, 0])]
        np.testing.assert_allclose(found[np.argsort(found[:, 0])], expected, atol=1e-3)


def test_label_cor_of_a_levelled_rig_panorama_is_where_the_tilted_rig_sees_each_corner(tmp_path):
    """A rig's panorama levelled before the reconstruction: the tilted rig's ray through each written pixel, taken into
    the levelled frame, passes through its corner (its optical centre off the level circle)."""
    from ncjax.geometry.gravity import rotation_from_tilt

    record = record_of(L_SHAPE, cam=NON_CENTRAL)
    rotation = rotation_from_tilt(3.0, -2.0)
    (path,) = write_layout_formats(tmp_path / "room", record, NON_CENTRAL, ["label_cor"], rotation=rotation)
    points = np.loadtxt(path)
    for key, found in (("ceiling_corners", points[0::2]), ("floor_corners", points[1::2])):
        rays = np.asarray(ncjax.geometry.pixel_to_ray(NON_CENTRAL, found[:, 0], found[:, 1]), np.float64)
        direction = rays[:, :3] @ rotation.T  # the rig's frame -> the levelled frame
        origin = np.cross(rays[:, :3], rays[:, 3:]) @ rotation.T  # the point of each ray nearest the rig's centre
        corners = np.asarray(record[key])
        # each written pixel's ray passes through one of the corners
        offsets = corners[None] - origin[:, None]
        along = np.einsum("rk,rck->rc", direction, offsets)
        distance = np.linalg.norm(offsets - along[..., None] * direction[:, None], axis=-1)
        assert np.all(distance.min(axis=1) < 2e-3), distance.min(axis=1)


def test_horizonnet_json_keys(tmp_path):
    data = json.loads(write_one(tmp_path, record_of(L_SHAPE), CENTRAL, "horizonnet").read_text())
    assert data["z0"] == 50.0 and data["z1"] == pytest.approx(50.0 * H_F / H_C)
    uv = np.array(data["uv"])
    assert uv.shape == (12, 2) and np.all((uv >= 0) & (uv < 1))
    ceiling, floor = expected_pixels(record_of(L_SHAPE), CENTRAL)
    np.testing.assert_allclose(uv[1::2] * [W, H], floor, atol=1e-4)  # HorizonNet: pixel = uv * (W, H)
    without_camera = {key: data[key] for key in ("z0", "z1", "uv")}  # as HorizonNet writes it
    path = tmp_path / "inference.json"
    path.write_text(json.dumps(without_camera))
    pixels_only = read_layout(path)
    assert pixels_only.units is None and pixels_only.format == "horizonnet"
    np.testing.assert_allclose(pixels_only.ceiling, ceiling, atol=1e-4)


def test_mp3d_json_follows_panoannotator_and_lgt_net(tmp_path):
    data = json.loads(write_one(tmp_path, record_of(L_SHAPE), NON_CENTRAL, "mp3d").read_text())
    assert data["cameraHeight"] == 1.5 and data["layoutHeight"] == 2.5 and data["cameraCeilingHeight"] == 1.0
    points, walls = data["layoutPoints"]["points"], data["layoutWalls"]["walls"]
    assert data["layoutPoints"]["num"] == data["layoutWalls"]["num"] == len(points) == len(walls) == 6
    xyz = np.array([point["xyz"] for point in points])
    # LGT-Net reads u = atan2(X, -Z) / (2 pi) + 0.5 and the pixel u W - 0.5; the azimuth of the
    # non-central camera is the plan point's, so the column is ncjax's.
    u = np.arctan2(xyz[:, 0], -xyz[:, 2]) / (2 * np.pi) + 0.5
    np.testing.assert_allclose([point["coords"][0] for point in points], u, atol=1e-7)
    _, floor = expected_pixels(record_of(L_SHAPE), NON_CENTRAL)
    np.testing.assert_allclose(u * W - 0.5, floor[:, 0], atol=1e-4)
    for wall in walls:
        plane = np.array(wall["planeEquation"])
        first, second = xyz[wall["pointsIdx"][0]], xyz[wall["pointsIdx"][1]]
        assert plane[:3] @ first + plane[3] == pytest.approx(0, abs=1e-6)
        assert plane[:3] @ second + plane[3] == pytest.approx(0, abs=1e-6)
        assert plane[3] < 0 and wall["width"] == pytest.approx(np.linalg.norm(second - first))  # normal outwards
    assert [wall["pointsIdx"] for wall in walls] == [[k, (k + 1) % 6] for k in range(6)]


def test_zind_json_follows_zind_axes(tmp_path):
    record = record_of(L_SHAPE)
    data = json.loads(write_one(tmp_path, record, CENTRAL, "zind").read_text())
    assert data["camera_height"] == 1.0 and data["ceiling_height"] == pytest.approx((H_C - H_F) / -H_F)
    assert data["scale_meters_per_coordinate"] == 1.5
    vertices = np.array(data["layout_visible"]["vertices"])
    assert data["layout_raw"]["vertices"] == data["layout_visible"]["vertices"]
    # ZInD's TransformationSpherical: azimuth atan2(-x, y), increasing to the right from -pi.
    theta = np.arctan2(-vertices[:, 0], vertices[:, 1])
    _, floor = expected_pixels(record, CENTRAL)
    np.testing.assert_allclose((theta / (2 * np.pi) + 0.5) * W - 0.5, floor[:, 0], atol=1e-4)
    np.testing.assert_allclose(vertices[:, ::-1] * 1.5, np.roll(L_SHAPE, -leftmost(record, CENTRAL), 0), atol=1e-6)


def test_reads_an_lgt_net_example_json():
    corners = read_layout(DATA / "lgt_net_example.json")
    data = json.loads((DATA / "lgt_net_example.json").read_text())
    assert corners.format == "mp3d" and corners.count == 6 and corners.units == "metres"
    assert corners.camera_height == pytest.approx(1.6)
    coords = np.array([point["coords"] for point in data["layoutPoints"]["points"]])
    np.testing.assert_allclose(corners.floor[:, 0], coords[:, 0] * W - 0.5, atol=1e-5)
    np.testing.assert_allclose(corners.ceiling[:, 0], corners.floor[:, 0])
    xyz = np.array([point["xyz"] for point in data["layoutPoints"]["points"]])
    distance = np.hypot(xyz[:, 0], xyz[:, 2])
    # LGT-Net: latitude increases downwards, v = (lat / pi + 0.5) H - 0.5.
    for height, rows in ((1.6, corners.floor[:, 1]), (1.6 - 2.8, corners.ceiling[:, 1])):
        np.testing.assert_allclose(rows, (np.arctan2(height, distance) / np.pi + 0.5) * H - 0.5, atol=1e-5)
    assert corners.ceiling_corners[:, 2] == pytest.approx(np.full(6, 1.2))


def test_mp3d_corners_follow_the_walls():
    data = json.loads((DATA / "lgt_net_example.json").read_text())
    reference = read_mp3d(data)
    shuffled = json.loads(json.dumps(data))
    order = [3, 0, 5, 1, 4, 2]
    shuffled["layoutPoints"]["points"] = [data["layoutPoints"]["points"][k] for k in order]
    new_index = {old: new for new, old in enumerate(order)}
    for wall in shuffled["layoutWalls"]["walls"]:
        wall["pointsIdx"] = [new_index[k] for k in wall["pointsIdx"]]
    np.testing.assert_allclose(read_mp3d(shuffled).floor, reference.floor)


def test_reads_an_authors_label_cor():
    """A label_cor as the authors and HorizonNet write it: the L-shaped room 1.5 m below and 1.2 m above a central
    camera, leftmost corner first, 3 decimals."""
    corners = read_layout(DATA / "AFimg_label_cor.txt")
    assert (corners.format, corners.count, corners.width, corners.height, corners.units) == ("label_cor", 6, W, H, None)
    room = room_geometry(corners, metric=False)  # at camera height 1: the room scaled by 1 / 1.5
    expected = np.array(L_SHAPE) / 1.5
    shift = int(np.argmin(np.linalg.norm(expected - room.floor_plan[0], axis=1)))
    np.testing.assert_allclose(room.floor_plan, np.roll(expected, -shift, 0), atol=2e-3)
    np.testing.assert_allclose(room.ceiling_plan, room.floor_plan, atol=2e-3)
    assert room.ceiling_height == pytest.approx(1.2 / 1.5, abs=1e-3) and room.floor_height == -1.0


def test_bad_files_are_one_line_errors(tmp_path):
    cases = {
        "odd.txt": "1 2\n3 4\n5 6\n7 8\n9 10\n11 12\n13 14\n",
        "words.txt": "1 2\nceiling floor\n",
        "short.txt": "1 2\n3 4\n",
        "other.json": json.dumps({"rooms": []}),
        "broken.json": "{",
        "failed.json": json.dumps({"ceiling_corners": [], "floor_corners": [], "status": "NO_CORNERS"}),
        "heights.json": json.dumps({"cameraHeight": 3.0, "layoutHeight": 2.0, "layoutPoints": {"points": []}}),
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError) as error:
            read_layout(tmp_path / name)
        assert "\n" not in str(error.value) and name in str(error.value)
    (tmp_path / "binary.txt").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))  # not text, as an image
    with pytest.raises(ValueError, match="binary.txt: not a layout file: a label_cor is text"):
        read_layout(tmp_path / "binary.txt")
    with pytest.raises(FileNotFoundError):
        read_layout(tmp_path / "missing.txt")


def test_writes_refuse_bad_input_and_write_nothing(tmp_path):
    with pytest.raises(ValueError, match="unknown layout format 'obj'"):
        write_layout_formats(tmp_path / "room", record_of(L_SHAPE), CENTRAL, "label_cor,obj")
    with pytest.raises(ValueError, match="no corners"):
        write_layout_formats(tmp_path / "room", {"ceiling_corners": [], "floor_corners": []}, CENTRAL, "zind")
    inside = [(0.3, 0.0), (-2.0, 2.0), (-2.0, -2.0)]  # a corner inside the circle of optical centres
    with pytest.raises(ValueError, match="inside the circle"):
        write_layout_formats(tmp_path / "room", record_of(inside), NON_CENTRAL, FORMATS)
    assert list(tmp_path.iterdir()) == []


def test_folder_listing_prefers_metric_files(tmp_path):
    for name in ("a.json", "a.label_cor.txt", "b.mp3d.json", "b.txt", "c.txt", "summary.csv", "a_plan.png"):
        (tmp_path / name).write_text("")
    assert {stem: path.name for stem, path in layout_files(tmp_path).items()} == {
        "a": "a.json",
        "b": "b.mp3d.json",
        "c": "c.txt",
    }


# --- metrics -------------------------------------------------------------------------------------------


def corners_of(plan, ceiling_height=H_C, floor_height=H_F, cam=CENTRAL, metric=True) -> LayoutCorners:
    ceiling, floor = (
        np.asarray(record_of(plan, ceiling_height, floor_height, cam)[key])
        for key in ("ceiling_corners", "floor_corners")
    )
    pixels = dict(ceiling=project_points(cam, ceiling), floor=project_points(cam, floor), width=W, height=H)
    if not metric:
        return LayoutCorners(**pixels, format="label_cor", rc=float(cam.rc))
    return LayoutCorners(
        **pixels, format="ncjax", rc=float(cam.rc), ceiling_corners=ceiling, floor_corners=floor, units="metres"
    )


SQUARE = [(-2.0, 2.0), (2.0, 2.0), (2.0, -2.0), (-2.0, -2.0)]


@pytest.mark.parametrize("metric", [True, False], ids=["metres", "pixels"])
def test_identical_layouts_score_perfectly(metric):
    layout = corners_of(L_SHAPE, metric=metric)
    scores = evaluate_corners(layout, layout)
    assert scores["iou2d"] == pytest.approx(1.0) and scores["iou3d"] == pytest.approx(1.0)
    assert scores["corner_error"] == pytest.approx(0.0, abs=1e-9) and scores["pixel_error"] == 0.0
    assert scores["depth_rmse"] == pytest.approx(0.0, abs=1e-9) and scores["delta1"] == 1.0
    assert scores["corner_count_match"] == 1.0 and scores["metric"] == float(metric)


def test_corner_matching_ignores_start_and_direction():
    layout = corners_of(L_SHAPE)
    turned = dataclasses.replace(  # listed the other way round, from another corner
        layout, ceiling=np.roll(layout.ceiling[::-1], 2, 0), floor=np.roll(layout.floor[::-1], 2, 0)
    )
    assert evaluate_corners(turned, layout)["corner_error"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("metric", [True, False], ids=["metres", "pixels"])
def test_a_square_of_0_9_times_the_side_has_iou_0_81(metric):
    scores = evaluate_corners(corners_of(np.array(SQUARE) * 0.9, metric=metric), corners_of(SQUARE, metric=metric))
    assert scores["iou2d"] == pytest.approx(0.81, abs=1e-6)
    assert scores["iou3d"] == pytest.approx(0.81, abs=1e-6)  # same heights
    assert 0 < scores["pixel_error"] < 10 and scores["depth_rmse"] > 0 and scores["delta1"] == 1.0


def test_3d_iou_of_a_lower_ceiling_and_the_corner_error_of_a_shift():
    low = corners_of(SQUARE, ceiling_height=0.5)
    assert evaluate_corners(low, corners_of(SQUARE))["iou3d"] == pytest.approx(2.0 / 2.5)
    truth = corners_of(SQUARE)
    shifted = dataclasses.replace(truth, ceiling=truth.ceiling + [10, 0], floor=truth.floor + [10, 0])
    shifted = dataclasses.replace(shifted, ceiling_corners=None, floor_corners=None, units=None)
    assert evaluate_corners(shifted, truth)["corner_error"] == pytest.approx(100 * 10 / math.hypot(W, H))


def test_a_prediction_at_another_resolution_is_rescaled():
    truth = corners_of(L_SHAPE, metric=False)
    half = dataclasses.replace(
        truth, ceiling=(truth.ceiling + 0.5) / 2 - 0.5, floor=(truth.floor + 0.5) / 2 - 0.5, width=W // 2, height=H // 2
    )
    assert evaluate_corners(half, truth)["corner_error"] == pytest.approx(0.0, abs=1e-9)


# --- command line ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "argv, message",
    [
        (["evaluate"], "give PRED GT"),
        (["evaluate", "pred.txt"], "needs both PRED and GT"),
        (["evaluate", "pred.txt", "gt.txt", "--data", "dataset"], "not both"),
    ],
)
def test_evaluate_dispatch_errors_are_one_line(argv, message, capsys):
    assert cli.main(argv) == 2
    error = capsys.readouterr().err
    assert message in error and error.count("\n") == 1


def test_evaluate_two_files_and_two_folders(tmp_path, capsys):
    predictions, truths = tmp_path / "pred", tmp_path / "gt"
    predictions.mkdir(), truths.mkdir()
    write_layout_formats(predictions / "room", record_of(np.array(SQUARE) * 0.9), CENTRAL, ["horizonnet"])
    write_layout_formats(truths / "room", record_of(SQUARE), CENTRAL, ["label_cor"])
    write_layout_formats(truths / "other", record_of(SQUARE), CENTRAL, ["label_cor"])
    out = tmp_path / "scores.json"
    assert cli.main(["evaluate", str(predictions / "room.horizonnet.json"), str(truths / "room.label_cor.txt")]) == 0
    assert "room" in capsys.readouterr().out
    assert cli.main(["evaluate", str(predictions), str(truths), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "mean of 1" in printed and "1 ground truths without prediction: other" in printed
    scores = json.loads(out.read_text())
    assert scores["images"]["room"]["iou2d"] == pytest.approx(0.81, abs=1e-4) and scores["failures"] == {}
    assert cli.main(["evaluate", str(predictions), str(truths / "room.label_cor.txt")]) == 2


def test_evaluate_refuses_an_image_as_a_layout_file_in_one_line(tmp_path, capsys):
    import cv2

    label = write_one(tmp_path, record_of(SQUARE), CENTRAL, "label_cor")
    image = tmp_path / "room.png"
    cv2.imwrite(str(image), np.zeros((8, 16, 3), np.uint8))
    for pred, gt, role in ((label, image, "GT"), (image, label, "PRED")):
        assert cli.main(["evaluate", str(pred), str(gt)]) == 2
        error = capsys.readouterr().err
        assert error.startswith(f"ncjax evaluate: error: {role} {image} is an image: give its layout file (label_cor")
        assert error.count("\n") == 1


def test_evaluate_reads_a_label_cor_at_the_size_the_other_file_records(tmp_path, capsys):
    """A label_cor records no image size: beside a file that records one (ncjax's JSON, the JSON formats) it is
    read at that size, else at --size, else 1024 x 512. Labels of a 4096 x 2048 panorama, scored against the
    same layout's record, are a perfect match without --size."""
    big = ncjax.NonCentralPanorama(4096, 2048, rc=0.0)
    truth = write_one(tmp_path, record_of(L_SHAPE, cam=big), big, "label_cor")
    record = tmp_path / "room.json"
    record.write_text(json.dumps(record_of(L_SHAPE, cam=big)))
    scores = tmp_path / "scores.json"

    def score(*argv):
        assert cli.main(["evaluate", *map(str, argv), "--json", str(scores)]) == 0
        return next(iter(json.loads(scores.read_text())["images"].values()))

    for pred, gt in ((record, truth), (truth, record)):
        row = score(pred, gt)
        assert row["iou2d"] == pytest.approx(1.0, abs=1e-4) and row["corner_error"] < 1e-4, row  # 3-decimal pixels
    assert score(truth, record, "--size", "2048x4096")["iou2d"] == pytest.approx(1.0, abs=1e-4)
    # at 1024 x 512 the label's pixels are off the image: a bad score or no score, not a perfect one
    assert cli.main(["evaluate", str(truth), str(record), "--size", "512x1024", "--json", str(scores)]) in (0, 1)
    result = json.loads(scores.read_text())
    assert result["failures"] or next(iter(result["images"].values()))["iou2d"] < 0.9


def test_unknown_export_format_stops_before_any_work(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit:
        cli.main(["reconstruct", "room.png", "--rc", "0.5", "--out", str(tmp_path / "out"), "--export", "zind,obj"])
    assert exit.value.code == 2 and "unknown layout format 'obj'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_reconstruct_outputs_write_and_remove_the_formats(tmp_path):
    from test_export import failed_layout, make_layout

    from ncjax.cli.outputs import ReconstructedImage, write_outputs

    image = np.zeros((64, 128, 3), np.uint8)
    rows = np.full(128, 20.0), np.full(128, 44.0), np.zeros(128), 0, None  # boundaries, scale source, geometry
    result = (make_layout(L_SHAPE, H_C, H_F), *rows)
    write_outputs(str(tmp_path), ReconstructedImage("room", image, result, 0.3), "auto", export=FORMATS)
    written = sorted(path.name for path in tmp_path.iterdir() if path.name.startswith("room."))
    assert written == sorted(
        ["room.json", "room.obj", "room.ply", "room.glb", "room.html", *(f"room{s}" for s in SUFFIXES.values())]
    )
    corners = read_layout(tmp_path / "room.label_cor.txt", 128, 64, rc=0.3)
    np.testing.assert_allclose(corners.floor, read_layout(tmp_path / "room.json").floor, atol=0.01)
    failed_result = (failed_layout(), *rows)
    write_outputs(str(tmp_path), ReconstructedImage("room", image, failed_result, 0.3), "auto", export=("label_cor",))
    assert not any((tmp_path / f"room{suffix}").exists() for suffix in SUFFIXES.values())
