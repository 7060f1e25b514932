"""What several experiments share: the rooms they score on, the routes that lay them out, and how they score.

- The test renders (:func:`test_renders`, seeds :data:`TEST_SEEDS`, never seen in training) and the tuning renders
  (:func:`tuning_boundaries`, :data:`TUNING_SEEDS`), their ground truth (:func:`ground_truth`) and the network's
  rows on them, cached per model (:func:`model_suffix`).
- The paper's "Solvers" route and the full pipeline, compiled once per world (:func:`compiled`); the full
  reconstruction of renders (:func:`layouts_of`).
- The scores of layouts against the truth (:func:`layout_scores`, :func:`scores_summary`, :func:`failure_causes`),
  of their rows (:func:`used_row_errors`) and of their corner covariances (:func:`corner_calibration`).
- The labelled photographs through the network (:func:`labelled_rows`, and each single view alone:
  :func:`single_view_rows`) and the central pipeline (:func:`central_layout`, :func:`written_layout`,
  :func:`corners_iou`), and renders made to look like photographs (:func:`photo_like_image`).

Python puts a script's folder first on its path, so the scripts of ``experiments/`` import this module by name.
"""

from __future__ import annotations

import collections
import contextlib
import csv
import dataclasses
import functools
import hashlib
import importlib
import io
import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.evaluation import layout_metrics
from ncjax.evaluation.central_metrics import evaluate_corners, rescaled
from ncjax.evaluation.panorama_labels import labelled_image_paths
from ncjax.io.export import status_has_geometry
from ncjax.io.formats import format_path, write_layout_formats
from ncjax.io.formats_read import read_layout
from ncjax.io.images import read_panorama_file
from ncjax.io.layout_corners import LayoutCorners
from ncjax.network.checkpoint import load_model
from ncjax.network.predict import DEFAULT_MODEL_PATH, default_model, predict_boundaries
from ncjax.pipeline.config import RENAMED, PipelineConfig
from ncjax.pipeline.corners import column_walls, find_corners
from ncjax.pipeline.manhattan import manhattan_frame
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior
from ncjax.pipeline.run import layout_of
from ncjax.pipeline.types import Rows
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG, reconstruct_batch
from ncjax.synth.augment import random_augment
from ncjax.synth.dataset import list_samples, read_sample, rendering_rgb8, write_dataset
from ncjax.synth.rooms import RoomConfig
from ncjax.synth.scene import SceneConfig
from ncjax.training.data import SYNTH_SOURCES
from ncjax.viz.plan import CHI2_2D_95

OUT = Path(__file__).parent / "out"
WIDTH, HEIGHT = 1024, 512  # the panoramas of the tables
CAPACITY = 32  # walls of a room, corners of a layout
BATCH = 8
TEST_SEEDS = {"manhattan": 99, "atlanta": 98}
TUNING_SEEDS = {"manhattan": 71, "atlanta": 72}
# seeds of no training stage (model card): 11-16, 21-22, 31-33, 61-63, 82-84; tests and tuning 71-72, 96-99
PHOTO_LIKE_SEED = 401
# the default 4 views are 2 rolls, each also mirrored; 4 rolls give 8 distinct single views
SINGLE_VIEW_ROLLS = 4


# ----------------------------------------------------------------------------- renders and their truth


def test_renders(world: str, count: int, out: Path, seeds: dict[str, int] = TEST_SEEDS, name: str = "test") -> Path:
    """The folder of ``count`` test renders of ``world`` (rendered on first use); other ``seeds`` give
    another set of the same generator, named ``name``."""
    folder = out / f"{name}_renders_{world}_{count}"
    if folder.is_dir() and len(list_samples(str(folder))) == count:
        return folder
    config = ncjax.SynthConfig(room=ncjax.RoomConfig(world=world, rc_range=(0.3, 1.0)))
    with tqdm(total=count, desc=f"render {world} {name} set") as bar:
        write_dataset(str(folder), count, seeds[world], config, batch_size=BATCH, overwrite=True, progress=bar.update)
    return folder


def ground_truth(sample, world: str) -> dict:
    """Manhattan: the true room in image order (the pipeline recovers the hidden wall at an occlusion); Atlanta: the
    visible layout (its inserted walls lie in the corner rays' planes)."""
    meta = sample.metadata
    if world == "atlanta":
        return {"ceiling_corners": meta["ceiling_corners"], "floor_corners": meta["floor_corners"]}
    plan = np.asarray(meta["room_corners"])[::-1]  # rooms are counter-clockwise, layouts clockwise
    ones = np.ones((len(plan), 1))
    return {
        "ceiling_corners": np.hstack([plan, meta["ceiling_height"] * ones]),
        "floor_corners": np.hstack([plan, meta["floor_height"] * ones]),
    }


def tuning_boundaries(world: str, rooms: int, views: int, out: Path, model_path: Path | None = None) -> dict:
    """Rows, corner probability, radii, ground truths, true rows and occlusion flags of the tuning renders of ``world``.

    The rows and corner probability are those of the model in ``model_path``
    (default: the shipped one), cached per model (:func:`model_suffix`).
    """
    folder = out / f"tune_renders_{world}_{rooms}"
    if not (folder.is_dir() and len(list_samples(str(folder))) == rooms):
        config = ncjax.SynthConfig(room=ncjax.RoomConfig(world=world, rc_range=(0.3, 1.0)))
        with tqdm(total=rooms, desc=f"render {world} tuning set") as bar:
            write_dataset(
                str(folder), rooms, TUNING_SEEDS[world], config, batch_size=BATCH, overwrite=True, progress=bar.update
            )
    cache = out / f"tune_{world}_{rooms}_views{views}{model_suffix(model_path)}.npz"
    return rendered_boundaries(folder, world, cache, views, model_path)


def rendered_boundaries(folder: Path, world: str, cache: Path, views: int, model_path: Path | None = None) -> dict:
    """:func:`tuning_boundaries` of the renders in ``folder``, the network's outputs cached in ``cache``."""
    samples = [read_sample(str(folder), name) for name in list_samples(str(folder))]
    data = {
        "rc": np.array([s.rc for s in samples], np.float32),
        "truth": [ground_truth(s, world) for s in samples],
        "clear": np.array([not any(s.metadata["corner_is_occlusion"]) for s in samples]),
        "true_rows": np.stack([[s.metadata["ceiling_v"] for s in samples], [s.metadata["floor_v"] for s in samples]]),
    }
    if cache.is_file():
        with np.load(cache) as stored:
            return data | dict(stored)
    model, rows, rooms = (default_model() if model_path is None else load_model(model_path)), [], len(samples)
    for start in tqdm(range(0, rooms, BATCH), desc=f"network {world}"):
        chunk = samples[start : start + BATCH]
        chunk = chunk + [chunk[-1]] * (BATCH - len(chunk))
        rows.append(
            [
                part[: min(BATCH, rooms - start)]
                for part in predict_boundaries(np.stack([s.image for s in chunk]), model, views)
            ]
        )
    boundaries = dict(
        zip(
            ("ceiling_v", "floor_v", "corner_prob"),
            (np.concatenate(parts) for parts in zip(*rows, strict=False)),
            strict=False,
        )
    )
    np.savez(cache, **boundaries)
    return data | boundaries


def model_suffix(model_path: Path | None) -> str:
    """What names a model's cached rows and tables: the file's name and the start of its SHA-256 (the
    shipped model's when ``model_path`` is None), so that new weights saved under an old name are not
    mistaken for it."""
    path = DEFAULT_MODEL_PATH if model_path is None else model_path
    return f"_{path.stem}_{hashlib.sha256(path.read_bytes()).hexdigest()[:8]}"


# ----------------------------------------------------------------------------- layouts


def noisy_rows(labels, sigma: float, seed: int):
    """The labels' ceiling and floor rows with Gaussian noise of ``sigma`` pixels (the same noise for one seed)."""
    k1, k2 = jax.random.split(jax.random.key(seed + 1000))
    return (
        labels.ceiling_v + sigma * jax.random.normal(k1, labels.ceiling_v.shape),
        labels.floor_v + sigma * jax.random.normal(k2, labels.floor_v.shape),
    )


def solvers_only(ceiling_v, floor_v, corner_prob, cam, world: str):
    """The paper's "Solvers" route: walls split at the corner peaks, each wall fitted alone (``solve_wall``) for the
    Manhattan labels / the Atlanta directions, then ``solve_manhattan_layout`` / ``solve_atlanta_layout`` and corners
    as line intersections; no RANSAC, no occlusion handling."""
    config = PipelineConfig()
    columns = jnp.arange(WIDTH, dtype=ceiling_v.dtype)
    ceiling_rays = ncjax.geometry.pixel_to_ray(cam, columns, ceiling_v)
    floor_rays = ncjax.geometry.pixel_to_ray(cam, columns, floor_v)
    # the paper's peaks: no minimum count, no peak split in two
    paper_peaks = dataclasses.replace(config.corners, min_corners=0, exact_target_tolerance=0.0)
    corners, mask, _, _ = find_corners(corner_prob, CAPACITY, 2, paper_peaks)
    wall_index = column_walls(corners, mask, WIDTH)
    own = wall_index[None, :] == jnp.arange(CAPACITY)[:, None]
    walls = jax.vmap(lambda m: ncjax.solvers.solve_wall(ceiling_rays, floor_rays, m, m))(own)
    if world == "manhattan":
        labels, _ = manhattan_frame(walls.direction, jnp.sum(own, 1).astype(ceiling_v.dtype))
        layout = ncjax.solvers.solve_manhattan_layout(ceiling_rays, floor_rays, wall_index, mask, labels)
    else:
        layout = ncjax.solvers.solve_atlanta_layout(ceiling_rays, floor_rays, wall_index, mask, walls.direction)
    ceiling = ncjax.solvers.layout_corners(layout.ceiling_lines, layout.mask)
    floor = ncjax.solvers.layout_corners(layout.floor_lines, layout.mask)
    return {
        "ceiling_corners": ceiling,
        "floor_corners": floor,
        "mask": layout.mask,
        "ok": layout.ok & jnp.all(walls.ok | ~mask),
    }


@functools.cache
def compiled(method: str, world: str, config: PipelineConfig = PipelineConfig()):
    """One jit(vmap) per method and world (``config``: the pipeline's)."""
    if method == "pipeline":
        return jax.jit(jax.vmap(lambda c, f, p, cam, k: layout_of(Rows(c, f, p), cam, None, k, config, world)))
    return jax.jit(jax.vmap(lambda c, f, p, cam, k: solvers_only(c, f, p, cam, world)))


def layouts_of(samples, world: str, model, config: PipelineConfig, views: int, edge_snap):
    """Full-pipeline reconstructions and the network's boundaries of the samples, in fixed-size batches."""
    layouts, boundaries = [], []
    for start in tqdm(range(0, len(samples), BATCH), desc=f"reconstruct {world}"):
        chunk = samples[start : start + BATCH]
        chunk = chunk + [chunk[-1]] * (BATCH - len(chunk))
        images = np.stack([s.image for s in chunk])
        result = jax.device_get(
            reconstruct_batch(
                images,
                np.array([s.rc for s in chunk], np.float32),
                world,
                model=model,
                config=config,
                views=views,
                edge_snap=edge_snap,
            )
        )
        for index in range(min(BATCH, len(samples) - start)):
            layouts.append(jax.tree.map(lambda x: x[index], result.layout))
            boundaries.append((result.ceiling_v[index], result.floor_v[index], result.corner_prob[index]))
    return layouts, boundaries


# ----------------------------------------------------------------------------- scores


def _field(layout, name: str):
    return layout.get(name) if isinstance(layout, dict) else getattr(layout, name, None)


def layout_scores(layouts, truths) -> list[dict]:
    """Per room: the metrics of a layout with geometry, whether it failed, its status (-1: unknown) and corner counts.

    ``returned``: the layout is ok. ``written``: ok, or flagged ``UNCERTAIN_SCALE``, whose geometry
    ``ncjax reconstruct`` writes too (:func:`ncjax.io.export.has_geometry`); both are scored. A failure
    is a layout that is not ok or has another corner count than the truth.
    """
    out = []
    for layout, truth in zip(layouts, truths, strict=False):
        ok = bool(_field(layout, "ok"))
        status, mask = _field(layout, "status"), _field(layout, "mask")
        written = status_has_geometry(ok, -1 if status is None else status)
        result = layout_metrics.evaluate_layout(layout, truth) if written else None
        failed = not ok or not math.isfinite(result["ce"])
        out.append(
            {
                "returned": ok,
                "written": written,
                "failed": failed,
                "status": (0 if ok else -1) if status is None else int(status),
                "corners": -1 if mask is None else int(np.sum(mask)),
                "true_corners": len(truth["ceiling_corners"]),
                **({} if result is None else result),
            }
        )
    return out


def scores_summary(results: list[dict]) -> dict:
    """The table figures of :func:`layout_scores` over rooms: CE, CEN and 3D IoU of the rooms that did not fail,
    the failure rate, and the share and 3D IoU of the layouts returned and flagged."""
    good = [r for r in results if not r["failed"]]
    returned = [r["iou3d"] for r in results if r["returned"]]
    flagged = [r["iou3d"] for r in results if r["written"] and not r["returned"]]
    mean = lambda key: float(np.mean([r[key] for r in good])) if good else math.nan  # noqa: E731
    return {
        "returned": 100.0 * len(returned) / len(results),
        "iou3d_returned": 100 * float(np.mean(returned)) if returned else math.nan,
        "iou3d_returned_median": 100 * float(np.median(returned)) if returned else math.nan,
        "iou3d_all_returned": 100 * float(np.sum(returned)) / len(results),
        "flagged": 100.0 * len(flagged) / len(results),
        "iou3d_flagged": 100 * float(np.mean(flagged)) if flagged else math.nan,
        "iou3d_all_written": 100 * float(np.sum(returned) + np.sum(flagged)) / len(results),
        "rooms": len(results),
        "failed": 100.0 * (1 - len(good) / len(results)),
        "ce": mean("ce"),
        "ce_median": float(np.median([r["ce"] for r in good])) if good else math.nan,
        "cen": 100 * mean("cen"),
        "iou3d": 100 * mean("iou3d"),
        "iou3d_all": 100 * float(np.sum([r["iou3d"] for r in good]) / len(results)),
        "iou3d_u2s": 100 * mean("iou3d_up_to_scale"),
        "height_error": mean("height_error"),
    }


def failure_causes(per_room: list[dict]) -> str:
    """Why the failed rooms failed, in % of all rooms.

    A status other than OK (by name), or too few or too many corners."""

    def cause(r):
        if r["status"]:
            return ncjax.LayoutStatus(r["status"]).name if r["status"] > 0 else "not ok"
        return "too few corners" if r["corners"] < r["true_corners"] else "too many corners"

    causes = collections.Counter(cause(r) for r in per_room if r["failed"])
    return ", ".join(f"{name} {100 * count / len(per_room):.1f}" for name, count in causes.most_common())


def used_row_errors(samples, boundaries) -> dict:
    """|row - true row| over every column of the samples, per boundary: mean, median, share within 1 px."""
    out = {}
    for index, name in ((0, "ceiling"), (1, "floor")):
        error = np.abs(np.stack([b[index] for b in boundaries]) - np.stack([s.metadata[f"{name}_v"] for s in samples]))
        out |= {
            f"{name}_mean": float(error.mean()),
            f"{name}_median": float(np.median(error)),
            f"{name}_within_1px": float(np.mean(error < 1)),
        }
    return out


def corner_calibration(layout, truth, shift: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per matched corner: inside its 95% ellipse (``Layout.corner_covariance``)? its sigma and its plan error (m)."""
    mask = np.asarray(layout.mask, bool)
    error = np.roll(np.asarray(layout.floor_corners)[mask, :2], -shift, 0) - np.asarray(truth["floor_corners"])[:, :2]
    covariance = np.roll(np.asarray(layout.corner_covariance, np.float64)[mask], -shift, 0)
    finite = np.all(np.isfinite(covariance), axis=(1, 2))
    safe = np.where(finite[:, None, None], covariance, np.eye(2))
    mahalanobis = np.einsum("ki,kij,kj->k", error, np.linalg.pinv(safe), error)
    sigma = np.sqrt(np.trace(safe, axis1=1, axis2=2))
    return finite & (mahalanobis <= CHI2_2D_95), np.where(finite, sigma, np.inf), np.linalg.norm(error, axis=1)


# ----------------------------------------------------------------------------- photographs and photo-like renders


def labelled_rows(folder: Path, model) -> Iterator[tuple[Path, ncjax.NonCentralPanorama, LayoutCorners, tuple]]:
    """Per labelled panorama of ``folder``: its path, its central camera, its label (in the camera's pixels: the
    file's brought to the size it is reconstructed at) and ``model``'s ``(ceiling_v, floor_v, corner_prob)`` (4 views,
    edge snap)."""
    for image_path, label_path in labelled_image_paths(folder):
        image, file_size, _ = read_panorama_file(image_path)
        height, width = image.shape[:2]
        cam = ncjax.NonCentralPanorama(width, height, rc=0.0)
        label = rescaled(read_layout(label_path, *file_size), width, height)
        yield image_path, cam, label, ncjax.predict_boundaries(image, model)


def central_layout(
    ceiling_v, floor_v, corner_prob, cam: ncjax.NonCentralPanorama, config: PipelineConfig = NETWORK_PIPELINE_CONFIG
) -> ncjax.Layout:
    """The central pipeline's layout of these rows (``config``, world auto, camera height 1.6 m)."""
    prior = HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT)
    layout = ncjax.layout_from_boundaries(ceiling_v, floor_v, corner_prob, cam, "auto", config, prior=prior)
    return jax.device_get(layout)


def written_layout(layout: ncjax.Layout, cam: ncjax.NonCentralPanorama, folder: Path) -> LayoutCorners | None:
    """One layout as its label_cor in ``folder`` gives it back (None without a layout)."""
    if not status_has_geometry(bool(layout.ok), int(layout.status)):
        return None
    stem = folder / "layout"
    write_layout_formats(stem, layout, cam, "label_cor")
    return read_layout(format_path(stem, "label_cor"), cam.width, cam.height)


def corners_iou(corners: LayoutCorners | None, label: LayoutCorners) -> float:
    """3D IoU of written corners against the label (0 without a layout or a scorable one)."""
    if corners is None:
        return 0.0
    try:
        return evaluate_corners(corners, label)["iou3d"]
    except ValueError:  # a corner at or across the horizon: no point at camera height 1
        return 0.0


def print_mean_ious(scores: dict[str, list[float]]) -> None:
    """A blank line, then each way's mean 3D IoU over its panoramas (the experiments on labelled photographs)."""
    print()
    for name, values in scores.items():
        print(f"mean 3D IoU, {name}: {np.mean(values):.3f} ({len(values)} panoramas)")


def each_view(image: np.ndarray, rolls: int, read) -> list[tuple[np.ndarray, ...]]:
    """``read``'s per-column outputs (a tuple of arrays) on each view of a panorama (rolled by ``k / rolls`` of a turn,
    plain and mirrored), mapped back to the panorama's own columns."""
    width = image.shape[1]
    outputs = []
    for k in range(rolls):
        shift = width * k // rolls
        for mirrored in (False, True):
            view = np.roll(image, shift, axis=1)
            view = np.ascontiguousarray(view[:, ::-1] if mirrored else view)
            columns = [np.asarray(a) for a in read(view)]
            outputs.append(tuple(np.roll(a[::-1] if mirrored else a, -shift) for a in columns))
    return outputs


def single_view_rows(image: np.ndarray, model) -> list[Rows]:
    """The network's rows of each single view of a panorama (:func:`each_view`, :data:`SINGLE_VIEW_ROLLS` rolls)."""
    views = each_view(image, SINGLE_VIEW_ROLLS, lambda view: predict_boundaries(view, model, views=1))
    return [Rows(*rows) for rows in views]


def source_config(kind: str, rooms: dict[str, tuple[float, float]], scene: dict[str, float] | None = None):
    """The :class:`~ncjax.synth.render.SynthConfig` of a training source, its ``RoomConfig`` ranges replaced by
    ``rooms`` (:func:`room_ranges`; ``RoomConfig`` checks them together: the camera below the ceiling, ...) and its
    ``SceneConfig`` probabilities by ``scene`` (:func:`scene_probabilities`)."""
    config = SYNTH_SOURCES[kind]
    return dataclasses.replace(
        config,
        room=dataclasses.replace(config.room, **rooms),
        scene=dataclasses.replace(config.scene, **(scene or {})),
    )


def scene_probabilities(settings: list[str]) -> dict[str, float]:
    """``--scene`` settings ``FIELD=P`` as :class:`~ncjax.synth.scene.SceneConfig` probability fields."""
    probabilities = {}
    for setting in settings:
        field, _, value = setting.partition("=")
        if not field.endswith("_probability") or field not in SceneConfig.__dataclass_fields__:
            raise ValueError(f"--scene {setting!r}: not a probability of SceneConfig (furniture_probability, ...)")
        try:
            probabilities[field] = float(value)
        except ValueError:
            raise ValueError(f"--scene {setting!r}: expected {field}=P, a probability") from None
        if not 0.0 <= probabilities[field] <= 1.0:
            raise ValueError(f"--scene {setting!r}: a probability is in [0, 1]")
    return probabilities


def room_ranges(settings: list[str]) -> dict[str, tuple[float, float]]:
    """``--room`` settings ``FIELD=LOW:HIGH`` as :class:`~ncjax.synth.rooms.RoomConfig` range fields."""
    ranges = {}
    for setting in settings:
        field, _, bounds = setting.partition("=")
        low, _, high = bounds.partition(":")
        if not field.endswith("_range") or field not in RoomConfig.__dataclass_fields__:
            raise ValueError(f"--room {setting!r}: not a range of RoomConfig (size_range, camera_height_range, ...)")
        try:
            ranges[field] = (float(low), float(high))
        except ValueError:
            raise ValueError(f"--room {setting!r}: expected {field}=LOW:HIGH in metres") from None
    return ranges


_augment = jax.jit(random_augment)


def photo_like_image(seed: int, index: int, rendering) -> np.ndarray:
    """Rendering ``index`` of ``seed``'s through its random camera of the training augmentation: an RGB uint8 image."""
    rgb = rendering_rgb8(rendering).astype(np.float32) / 255.0
    photo = _augment(jax.random.fold_in(jax.random.key(seed), index), jnp.asarray(rgb))
    return np.round(np.clip(np.asarray(photo), 0, 1) * 255).astype(np.uint8)


def network_config(**settings) -> PipelineConfig:
    """:data:`NETWORK_PIPELINE_CONFIG` with ``settings`` given by their flat names (``corner_threshold=0.4``, the
    ``ncjax reconstruct`` options' names) placed in their stages' parts (``corners.threshold``)."""
    changes: dict = {}
    for name, value in settings.items():
        stage, _, field = RENAMED.get(name, name).rpartition(".")
        if stage:
            changes.setdefault(stage, {})[field] = value
        else:
            changes[field] = value
    return NETWORK_PIPELINE_CONFIG.replace(**changes)


def network_setting(name: str):
    """The value of a :data:`NETWORK_PIPELINE_CONFIG` setting given by its flat name (see :func:`network_config`)."""
    value = NETWORK_PIPELINE_CONFIG
    for part in RENAMED.get(name, name).split("."):
        value = getattr(value, part)
    return value


BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def benchmark_module(name: str):
    """``benchmarks/<name>.py`` as a module (its ``main``, and whatever else it offers)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(BENCHMARKS))


def quietly(function: Callable, *args):
    """``function(*args)`` with its printing kept back; what it wrote to stderr is shown when it raises or returns a
    non-zero exit code."""
    errors = io.StringIO()
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(errors):
            result = function(*args)
    except BaseException:
        sys.stderr.write(errors.getvalue())
        raise
    if isinstance(result, int) and result != 0:
        sys.stderr.write(errors.getvalue())
    return result


def csv_means(path: Path) -> dict[str, dict[str, str]]:
    """A benchmark CSV's rows whose name starts with "mean", by name."""
    with open(path, newline="") as file:
        return {row["name"]: row for row in csv.DictReader(file) if row["name"].startswith("mean")}
