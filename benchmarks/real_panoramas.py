"""The shipped network on real, labelled equirectangular panoramas: boundary rows, corners and raw-layout IoU.

    uv run python benchmarks/real_panoramas.py --data DIR [--views N] [--model FILE] [--out DIR] [--limit N]

Input: a folder of full panoramas (``*.jpg``, ``*.jpeg``, ``*.png``; width = 2 x height, any size), each with
a ``label_cor`` file of the same stem: ``<stem>.txt`` beside the image, or ``label_cor/<stem>.txt`` for an
image in ``img/`` (the layout ``ncjax synth`` writes). Images without a label are skipped. ``label_cor`` is
HorizonNet's format: one ``x y`` line per point, the ceiling then the floor point of each corner, corners in
polygon order, pixels of that image with pixel centres at integers. A ``<stem>.json`` beside the image may add
``tags`` (``closed`` / ``open_plan`` give separate means; ``ceiling_not_flat`` leaves the ceiling rows
unscored) and per-corner ``counted`` / ``occluded`` flags (which label corners a peak must find, and on which
a peak counts neither way). Without flags every label corner counts, once per column: an occlusion's near and
far points share theirs.

The label's boundaries per column come from its 3D room, seen by a central camera: the floor at z = -1
(camera height 1), each floor corner placed in plan from its row, the flat ceiling at the median height its
corners' ceiling rows give, and every column's ray cast to the nearest wall of that polygon (a straight
wall is a curve in the panorama, not a line between its corners' pixels).

Per image and on average it prints (and writes to ``real_panoramas.csv``):

- ceiling and floor row error: mean |predicted - label row| over the columns where the label sees a wall,
  in pixels of a 512-row image (``REFERENCE_WIDTH / W`` = 512 / H);
- corner precision and recall within 1% and 2.5% of the width: the peaks of the corner probability found
  by the pipeline's peak finder with the network pipeline's settings, matched one-to-one (nearest pairs
  first, wrap-around) to the label's corner columns; pooled over the images in the means;
- whether the number of peaks equals the label's corner count (the mean: the share of images);
- the 2D and 3D IoU of the raw prediction (every column's floor row back-projected at camera height 1,
  the ceiling at the median height its ceiling rows give) and the label, up to scale (a central panorama
  has none).

It also writes ``contact_sheet.png``: each panorama downscaled with the label's boundaries and corners in
green, the prediction's in red, and the corner probability below it with the peak threshold in grey.
Bad input (a missing folder, no labelled image, an unreadable image, a malformed label) is one line on
stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import math
import os
import pathlib
import sys
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # OpenBLAS threads busy-wait on a loaded CPU

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax import metrics
from ncjax.geometry.gravity import panorama_size_error
from ncjax.io.files import write_atomic
from ncjax.io.images import PanoramaError, read_rgb
from ncjax.network.model import check_views
from ncjax.network.predict import default_model
from ncjax.network.scores import REFERENCE_WIDTH
from ncjax.pipeline.corners import configured_corners

DEFAULT_OUT = pathlib.Path(__file__).resolve().parent / "out" / "real_panoramas"
CSV_NAME = "real_panoramas.csv"
SHEET_NAME = "contact_sheet.png"
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
TOLERANCES = (0.01, 0.025)  # corner match distance, fraction of the width
SUBSET_TAGS = ("closed", "open_plan")
FLAT_CEILING_EXCLUSION_TAG = "ceiling_not_flat"
SAME_CORNER_COLUMNS = 1.0  # label corners closer than this (columns of a 1024-wide image) are one corner
MAX_FLOOR_DISTANCE = 50.0  # camera heights: a predicted floor row at or above the horizon is put this far
TILE_WIDTH = 512
STRIP_HEIGHT = 40
CAPTION_HEIGHT = 18
CAPTION_NAME_LENGTH = 30  # the end of a longer name is shown
LABEL_COLOUR = (0, 220, 0)  # RGB
PREDICTION_COLOUR = (255, 40, 40)
THRESHOLD_COLOUR = (130, 130, 130)
OCCLUDED_COLOUR = (200, 200, 200)


class InputError(Exception):
    """Input that cannot be benchmarked; the message is the one line printed."""


@dataclasses.dataclass(frozen=True)
class LabelledPanorama:
    """One panorama and what its label says, at the image's own size.

    Attributes:
        name: the file stem.
        image_path: the image file.
        width, height: the image size in pixels.
        tags: the json's tags (empty without a json).
        score_ceiling: False where the json marks the ceiling as not flat.
        plan: (N, 2) the label's floor corners at camera height 1, polygon order.
        ceiling_height: the flat ceiling's height above the camera, camera heights.
        ceiling_v, floor_v: (W,) the label's boundary rows; NaN where no wall is seen.
        corner_columns: the label's corners a peak must find.
        occluded_columns: label corners on which a peak counts neither way.
    """

    name: str
    image_path: pathlib.Path
    width: int
    height: int
    tags: tuple[str, ...]
    score_ceiling: bool
    plan: np.ndarray
    ceiling_height: float
    ceiling_v: np.ndarray
    floor_v: np.ndarray
    corner_columns: np.ndarray
    occluded_columns: np.ndarray


# ----------------------------------------------------------------------------- geometry (central camera)


def central_camera(width: int, height: int) -> ncjax.NonCentralPanorama:
    """The equirectangular (rc = 0) camera of a ``width x height`` panorama."""
    return ncjax.NonCentralPanorama(width, height, rc=0.0)


def pixel_angles(cam: ncjax.NonCentralPanorama, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (radians, float64) of pixels, with the project's conventions."""
    azimuth, elevation = ncjax.pixel_to_angles(cam, np.asarray(u, np.float32), np.asarray(v, np.float32))
    return np.asarray(azimuth, np.float64), np.asarray(elevation, np.float64)


def elevation_rows(cam: ncjax.NonCentralPanorama, elevation: np.ndarray) -> np.ndarray:
    """Image rows of elevations (the row does not depend on the azimuth)."""
    _, rows = ncjax.angles_to_pixel(cam, 0.0, np.asarray(elevation, np.float32))
    return np.asarray(rows, np.float64)


def label_room(corners: np.ndarray, cam: ncjax.NonCentralPanorama) -> tuple[np.ndarray, float]:
    """The label's room at camera height 1: floor corners in plan and the flat ceiling's height.

    Args:
        corners: (N, 2, 2) label points, ``[k, 0]`` the ceiling and ``[k, 1]`` the floor point of corner k.
        cam: the central camera of the image.

    Returns:
        ``(plan, ceiling_height)``: (N, 2) floor corners (the floor at z = -1) and the median over the
        corners of the height their ceiling rows give at their floor corners' distances.
    """
    azimuth, floor_elevation = pixel_angles(cam, corners[:, 1, 0], corners[:, 1, 1])
    distance = 1.0 / np.tan(-floor_elevation)
    plan = distance[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    _, ceiling_elevation = pixel_angles(cam, corners[:, 0, 0], corners[:, 0, 1])
    return plan, float(np.median(distance * np.tan(ceiling_elevation)))


def wall_distances(plan: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Horizontal distance from the camera to the first wall of a polygon along each azimuth (inf: none).

    Wall k runs from ``plan[k]`` to ``plan[k + 1]`` (closed polygon); a ray from the origin along
    ``(cos a, sin a)`` meets it at ``t`` with ``t d = p_k + s (p_k+1 - p_k)``, ``0 <= s <= 1``.
    """
    start = plan[None, :, :]
    edge = (np.roll(plan, -1, axis=0) - plan)[None, :, :]
    direction = np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)[:, None, :]
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    denominator = cross(direction, edge)
    usable = np.abs(denominator) > 1e-12
    safe = np.where(usable, denominator, 1.0)
    t = cross(start, edge) / safe
    s = cross(start, direction) / safe
    hit = usable & (t > 1e-9) & (s >= -1e-9) & (s <= 1 + 1e-9)
    return np.min(np.where(hit, t, np.inf), axis=1)


def boundary_rows(
    distance: np.ndarray, ceiling_height: float, cam: ncjax.NonCentralPanorama
) -> tuple[np.ndarray, np.ndarray]:
    """Ceiling and floor rows of walls at horizontal ``distance`` (camera height 1); NaN where inf."""
    seen = np.isfinite(distance)
    safe = np.where(seen, distance, 1.0)
    ceiling_v = elevation_rows(cam, np.arctan2(ceiling_height, safe))
    floor_v = elevation_rows(cam, np.arctan2(-1.0, safe))
    return np.where(seen, ceiling_v, np.nan), np.where(seen, floor_v, np.nan)


def label_boundaries(corners: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The label's room and its boundary row in every column of a ``width x height`` central panorama.

    Returns:
        ``(plan, ceiling_height, ceiling_v, floor_v)``, see :func:`label_room` and :func:`boundary_rows`.
    """
    cam = central_camera(width, height)
    plan, ceiling_height = label_room(corners, cam)
    azimuth, _ = pixel_angles(cam, np.arange(width), np.zeros(width))
    ceiling_v, floor_v = boundary_rows(wall_distances(plan, azimuth), ceiling_height, cam)
    return plan, ceiling_height, ceiling_v, floor_v


def raw_prediction_room(ceiling_v: np.ndarray, floor_v: np.ndarray, cam: ncjax.NonCentralPanorama) -> dict:
    """The predicted rows as a prism at camera height 1: one floor corner per column, one ceiling height.

    A floor row at or above the horizon is put at :data:`MAX_FLOOR_DISTANCE`; the ceiling height is the
    median over the columns whose ceiling row is above and floor row below the horizon.
    """
    width = len(floor_v)
    azimuth, floor_elevation = pixel_angles(cam, np.arange(width), floor_v)
    _, ceiling_elevation = pixel_angles(cam, np.arange(width), ceiling_v)
    distance = 1.0 / np.tan(np.maximum(-floor_elevation, math.atan(1.0 / MAX_FLOOR_DISTANCE)))
    usable = (ceiling_elevation > 1e-3) & (floor_elevation < -1e-3)
    ceiling_height = (
        float(np.median(distance[usable] * np.tan(ceiling_elevation[usable]))) if usable.any() else math.nan
    )
    plan = distance[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    return prism(plan, ceiling_height)


def prism(plan: np.ndarray, ceiling_height: float) -> dict:
    """A layout for :mod:`ncjax.metrics`: vertical walls on ``plan`` from z = -1 to ``ceiling_height``."""
    ones = np.ones((len(plan), 1))
    return {
        "ceiling_corners": np.concatenate([plan, ceiling_height * ones], axis=1),
        "floor_corners": np.concatenate([plan, -ones], axis=1),
    }


# ----------------------------------------------------------------------------- reading the folder


def labelled_image_paths(directory: pathlib.Path) -> list[tuple[pathlib.Path, pathlib.Path]]:
    """(image, label_cor) path pairs of a folder: ``<stem>.txt`` beside the image or ``label_cor/<stem>.txt``."""
    pairs = []
    for folder, label_folder in ((directory, directory), (directory / "img", directory / "label_cor")):
        if not folder.is_dir():
            continue
        for image_path in sorted(folder.iterdir()):
            label_path = label_folder / f"{image_path.stem}.txt"
            if image_path.suffix.lower() in IMAGE_SUFFIXES and image_path.is_file() and label_path.is_file():
                pairs.append((image_path, label_path))
    return pairs


def read_labelled_image(path: pathlib.Path) -> np.ndarray:
    """A full panorama file as RGB uint8 (H, W, 3), W = 2 H, at its own size (its label's pixels)."""
    try:
        image = read_rgb(path)
    except PanoramaError as error:
        raise InputError(str(error)) from None
    size_error = panorama_size_error(image.shape[1], image.shape[0])
    if size_error:
        raise InputError(f"{path}: {size_error}")
    return image


def read_label_cor(path: pathlib.Path, width: int, height: int) -> np.ndarray:
    """A label_cor file as (N, 2, 2) points: ``[k, 0]`` the ceiling (upper) and ``[k, 1]`` the floor point."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file: refused below
            points = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{path}: malformed label_cor ({error})") from None
    if points.ndim != 2 or points.shape[1] != 2 or len(points) % 2 or len(points) < 6:
        raise InputError(f"{path}: malformed label_cor: expected an even number (>= 6) of 'x y' lines")
    if not np.all(np.isfinite(points)):
        raise InputError(f"{path}: malformed label_cor: a coordinate is not a finite number")
    inside = (points[:, 0] >= -1) & (points[:, 0] <= width) & (points[:, 1] >= -1) & (points[:, 1] <= height)
    if not inside.all():
        raise InputError(f"{path}: malformed label_cor: a point lies outside the {width} x {height} image")
    corners = points.reshape(-1, 2, 2)
    upper_first = np.argsort(corners[:, :, 1], axis=1)
    corners = np.take_along_axis(corners, upper_first[:, :, None], axis=1)
    horizon = height / 2 - 0.5
    if np.any(corners[:, 1, 1] <= horizon) or np.any(corners[:, 0, 1] >= horizon):
        raise InputError(
            f"{path}: malformed label_cor: a ceiling point is not above or a floor point not below the horizon"
        )
    return corners


def read_side_metadata(path: pathlib.Path, corner_count: int) -> dict:
    """The json beside an image: ``tags`` and the per-corner ``counted`` / ``occluded`` flags ({} without one)."""
    if not path.is_file():
        return {}
    try:
        metadata = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"{path}: unreadable json ({error})") from None
    tags = metadata.get("tags", []) if isinstance(metadata, dict) else None
    if not isinstance(tags, list) or not all(isinstance(tag, str) for tag in tags):
        raise InputError(f"{path}: expected a json object whose 'tags' is a list of strings")
    for key in ("counted", "occluded"):
        flags = metadata.get(key)
        malformed = not isinstance(flags, list) or len(flags) != corner_count
        if flags is not None and (malformed or not all(isinstance(flag, bool) for flag in flags)):
            raise InputError(f"{path}: '{key}' must hold one true/false per label corner ({corner_count})")
    return metadata


def distinct_corners(columns: np.ndarray, width: int) -> np.ndarray:
    """Which label corners to score when the json has no flags: one per column.

    A corner within :data:`SAME_CORNER_COLUMNS` (of a 1024-wide image) of the previous one's column, as an
    occlusion's far point is of its near point, is the same corner.
    """
    gap = circular_distance(columns, np.roll(columns, 1), width)
    distinct = gap > SAME_CORNER_COLUMNS * width / REFERENCE_WIDTH
    if not distinct.any():
        distinct[0] = True
    return distinct


def load_panorama(image_path: pathlib.Path, label_path: pathlib.Path) -> LabelledPanorama:
    """Read and check one labelled panorama (the image is decoded to check it, not kept)."""
    height, width = read_labelled_image(image_path).shape[:2]
    corners = read_label_cor(label_path, width, height)
    metadata = read_side_metadata(image_path.with_suffix(".json"), len(corners))
    tags = tuple(metadata.get("tags", ()))
    columns = corners[:, 1, 0]
    counted = np.asarray(metadata.get("counted", distinct_corners(columns, width)), bool)
    occluded = np.asarray(metadata.get("occluded", np.zeros(len(corners), bool)), bool)
    plan, ceiling_height, ceiling_v, floor_v = label_boundaries(corners, width, height)
    return LabelledPanorama(
        name=image_path.stem,
        image_path=image_path,
        width=width,
        height=height,
        tags=tags,
        score_ceiling=FLAT_CEILING_EXCLUSION_TAG not in tags and metadata.get("ceiling_flat", True) is not False,
        plan=plan,
        ceiling_height=ceiling_height,
        ceiling_v=ceiling_v,
        floor_v=floor_v,
        corner_columns=columns[counted],
        occluded_columns=columns[occluded],
    )


def load_panoramas(directory: pathlib.Path, limit: int | None) -> list[LabelledPanorama]:
    """Every labelled panorama of a folder (the first ``limit`` by name), all checked before any is scored."""
    if not directory.is_dir():
        raise InputError(f"{directory}: no such folder")
    pairs = labelled_image_paths(directory)
    if not pairs:
        raise InputError(f"{directory}: no labelled panorama (an image with <stem>.txt beside it or in label_cor/)")
    return [load_panorama(*pair) for pair in pairs[:limit]]


def load_network(path: pathlib.Path | None) -> ncjax.HorizonNet:
    """The model in ``path``, or the shipped one."""
    try:
        return default_model() if path is None else ncjax.load_model(path)
    except Exception as error:  # safetensors and the checkpoint reader raise several kinds
        raise InputError(f"cannot load the model: {error}") from None


# ----------------------------------------------------------------------------- scores


# the pipeline's corner peak finder, its settings static
peak_finder = jax.jit(configured_corners, static_argnames="config")


def predicted_corners(corner_prob: np.ndarray) -> np.ndarray:
    """Corner columns: the peaks the network pipeline would take (:data:`ncjax.NETWORK_PIPELINE_CONFIG`)."""
    columns, mask, _, _ = peak_finder(jnp.asarray(corner_prob, jnp.float32), ncjax.NETWORK_PIPELINE_CONFIG)
    return np.asarray(columns, np.float64)[np.asarray(mask)]


def circular_distance(a: np.ndarray, b: np.ndarray, width: int) -> np.ndarray:
    """Wrap-around distance in columns between column positions (broadcast)."""
    gap = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)) % width
    return np.minimum(gap, width - gap)


def match_one_to_one(columns: np.ndarray, targets: np.ndarray, tolerance: float, width: int) -> np.ndarray:
    """Which ``columns`` pair with a distinct target within ``tolerance``, the nearest pairs first."""
    matched = np.zeros(len(columns), bool)
    if len(columns) == 0 or len(targets) == 0:
        return matched
    distance = circular_distance(columns[:, None], targets[None, :], width)
    taken = np.zeros(len(targets), bool)
    for flat in np.argsort(distance, axis=None, kind="stable"):
        i, j = np.unravel_index(flat, distance.shape)
        if distance[i, j] > tolerance:
            break
        if not matched[i] and not taken[j]:
            matched[i] = taken[j] = True
    return matched


def corner_counts(peaks: np.ndarray, panorama: LabelledPanorama, fraction: float) -> tuple[int, int]:
    """``(matched, scored)`` peaks within ``fraction`` of the width; a peak on an occluded corner is not scored."""
    tolerance = fraction * panorama.width
    matched = match_one_to_one(peaks, panorama.corner_columns, tolerance, panorama.width)
    on_occluded = match_one_to_one(peaks[~matched], panorama.occluded_columns, tolerance, panorama.width)
    return int(matched.sum()), int(len(peaks) - on_occluded.sum())


def row_error(predicted: np.ndarray, label: np.ndarray) -> float:
    """Mean |row error| over the columns where both are finite, in pixels of a 512-row image."""
    both = np.isfinite(predicted) & np.isfinite(label)
    scale = REFERENCE_WIDTH / len(label)  # = 512 / H for a W = 2 H panorama
    return float(scale * np.mean(np.abs(predicted[both] - label[both]))) if both.any() else math.nan


def ratio(numerator: float, denominator: float) -> float:
    return numerator / denominator if denominator else math.nan


def tolerance_key(fraction: float) -> str:
    return f"{100 * fraction:g}pct"


def raw_layout_ious(panorama: LabelledPanorama, ceiling_v: np.ndarray, floor_v: np.ndarray) -> tuple[float, float]:
    """2D and 3D IoU of the raw predicted prism and the label's, both at camera height 1 (up to scale)."""
    predicted = raw_prediction_room(ceiling_v, floor_v, central_camera(panorama.width, panorama.height))
    label = prism(panorama.plan, panorama.ceiling_height)
    iou_2d = metrics.iou_2d(predicted, label)
    finite_height = np.isfinite(predicted["ceiling_corners"][0, 2])
    iou_3d = metrics.iou_3d(predicted, label, up_to_scale=True) if finite_height else math.nan
    return iou_2d, iou_3d


def score_image(panorama: LabelledPanorama, ceiling_v: np.ndarray, floor_v: np.ndarray, peaks: np.ndarray) -> dict:
    """The figures of one image (a CSV row)."""
    scores = {
        "name": panorama.name,
        "tags": " ".join(panorama.tags),
        "ceiling_error_px": row_error(ceiling_v, panorama.ceiling_v) if panorama.score_ceiling else math.nan,
        "floor_error_px": row_error(floor_v, panorama.floor_v),
        "label_corners": len(panorama.corner_columns),
        "predicted_corners": len(peaks),
        "exact_corner_count": float(len(peaks) == len(panorama.corner_columns)),
    }
    for fraction in TOLERANCES:
        matched, scored = corner_counts(peaks, panorama, fraction)
        key = tolerance_key(fraction)
        scores[f"precision_{key}"] = ratio(matched, scored)
        scores[f"recall_{key}"] = ratio(matched, len(panorama.corner_columns))
        scores[f"matched_{key}"] = matched
        scores[f"scored_peaks_{key}"] = scored
    scores["iou_2d"], scores["iou_3d"] = raw_layout_ious(panorama, ceiling_v, floor_v)
    return scores


def nan_mean(values: list[float]) -> float:
    finite = [v for v in values if np.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def summarise(rows: list[dict], name: str) -> dict:
    """The mean row of several images: errors, IoUs and the exact-count share averaged, corners pooled."""
    summary = {"name": name, "tags": ""}
    for key in ("ceiling_error_px", "floor_error_px", "exact_corner_count", "iou_2d", "iou_3d"):
        summary[key] = nan_mean([row[key] for row in rows])
    for key in ("label_corners", "predicted_corners"):
        summary[key] = sum(row[key] for row in rows)
    for fraction in TOLERANCES:
        key = tolerance_key(fraction)
        matched = sum(row[f"matched_{key}"] for row in rows)
        scored = sum(row[f"scored_peaks_{key}"] for row in rows)
        summary[f"precision_{key}"] = ratio(matched, scored)
        summary[f"recall_{key}"] = ratio(matched, summary["label_corners"])
        summary[f"matched_{key}"], summary[f"scored_peaks_{key}"] = matched, scored
    return summary


def summaries(rows: list[dict]) -> list[dict]:
    """The mean of all images, then one per :data:`SUBSET_TAGS` tag that some images have."""
    means = [summarise(rows, f"mean ({len(rows)} images)")]
    for tag in SUBSET_TAGS:
        subset = [row for row in rows if tag in row["tags"].split()]
        if subset:
            means.append(summarise(subset, f"mean {tag} ({len(subset)} images)"))
    return means


# ----------------------------------------------------------------------------- printing and files


COLUMNS = (
    ("ceiling_error_px", "ceil", ".1f"),
    ("floor_error_px", "floor", ".1f"),
    ("label_corners", "gt", "d"),
    ("predicted_corners", "pred", "d"),
    ("precision_1pct", "P@1%", ".2f"),
    ("recall_1pct", "R@1%", ".2f"),
    ("precision_2.5pct", "P@2.5%", ".2f"),
    ("recall_2.5pct", "R@2.5%", ".2f"),
    ("exact_corner_count", "count", ".2f"),
    ("iou_2d", "IoU2D", ".3f"),
    ("iou_3d", "IoU3D", ".3f"),
)
NAME_WIDTH = 44


def table_header() -> str:
    return f"{'image':{NAME_WIDTH}s}" + "".join(f" {title:>6s}" for _, title, _ in COLUMNS)


def table_line(row: dict) -> str:
    cells = []
    for key, _, spec in COLUMNS:
        value = row[key]
        cells.append("     -" if isinstance(value, float) and not np.isfinite(value) else f"{value:6{spec}}")
    return f"{row['name'][:NAME_WIDTH]:{NAME_WIDTH}s} " + " ".join(cells)


def csv_bytes(rows: list[dict]) -> bytes:
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue().encode()


def tile_coordinate(pixels: np.ndarray, scale: float) -> np.ndarray:
    """Image pixel coordinates (centres at integers) in an image downscaled by ``scale``."""
    return (np.asarray(pixels, np.float64) + 0.5) * scale - 0.5


def draw_curve(canvas: np.ndarray, u: np.ndarray, v: np.ndarray, colour, max_jump: float = math.inf) -> None:
    """Draw a curve through canvas points, broken at NaNs and where ``v`` jumps by more than ``max_jump``."""
    finite = np.isfinite(v)
    breaks = ~finite[1:] | ~finite[:-1] | (np.abs(np.diff(v)) > max_jump)
    for run in np.split(np.arange(len(v)), np.flatnonzero(breaks) + 1):
        if len(run) > 1 and finite[run[0]]:
            points = np.round(np.stack([u[run], v[run]], axis=-1) * 16).astype(np.int32)
            cv2.polylines(canvas, [points], False, colour, 1, cv2.LINE_AA, shift=4)


def draw_rows(canvas: np.ndarray, rows: np.ndarray, scale: float, colour) -> None:
    """Draw per-column image rows on a downscaled image, broken at occlusions (jumps of over 5% of the height)."""
    columns = tile_coordinate(np.arange(len(rows)), scale)
    draw_curve(canvas, columns, tile_coordinate(rows, scale), colour, max_jump=0.05 * canvas.shape[0])


def draw_ticks(canvas: np.ndarray, columns: np.ndarray, scale: float, top: int, bottom: int, colour) -> None:
    """Short vertical marks at image columns."""
    for x in np.round(tile_coordinate(columns, scale)).astype(int):
        cv2.line(canvas, (x, top), (x, bottom), colour, 2)


def probability_strip(corner_prob: np.ndarray, panorama: LabelledPanorama, peaks: np.ndarray, scale: float):
    """The corner probability under a tile: the curve, the peak threshold, label and predicted corner ticks."""
    strip = np.full((STRIP_HEIGHT, TILE_WIDTH, 3), 25, np.uint8)
    y_of = lambda p: (STRIP_HEIGHT - 3) - (STRIP_HEIGHT - 10) * np.clip(p, 0.0, 1.0)  # noqa: E731
    threshold_y = int(round(y_of(ncjax.NETWORK_PIPELINE_CONFIG.corner_threshold)))
    cv2.line(strip, (0, threshold_y), (TILE_WIDTH, threshold_y), THRESHOLD_COLOUR, 1)
    columns = tile_coordinate(np.arange(len(corner_prob)), scale)
    draw_curve(strip, columns, y_of(np.where(np.isfinite(corner_prob), corner_prob, 0.0)), PREDICTION_COLOUR)
    draw_ticks(strip, panorama.corner_columns, scale, 0, 5, LABEL_COLOUR)
    draw_ticks(strip, peaks, scale, STRIP_HEIGHT - 5, STRIP_HEIGHT, PREDICTION_COLOUR)
    return strip


def contact_tile(
    panorama: LabelledPanorama, image: np.ndarray, prediction: tuple[np.ndarray, ...], peaks: np.ndarray, scores: dict
) -> np.ndarray:
    """One panorama of the contact sheet (RGB): caption, downscaled image with both boundaries, probability strip."""
    ceiling_v, floor_v, corner_prob = prediction
    scale = TILE_WIDTH / panorama.width
    tile = cv2.resize(image, (TILE_WIDTH, TILE_WIDTH // 2), interpolation=cv2.INTER_AREA)
    for rows in (panorama.ceiling_v, panorama.floor_v):
        draw_rows(tile, rows, scale, LABEL_COLOUR)
    for rows in (ceiling_v, floor_v):
        draw_rows(tile, rows, scale, PREDICTION_COLOUR)
    draw_ticks(tile, panorama.corner_columns, scale, 0, 8, LABEL_COLOUR)
    draw_ticks(tile, panorama.occluded_columns, scale, 0, 8, OCCLUDED_COLOUR)
    draw_ticks(tile, peaks, scale, TILE_WIDTH // 2 - 9, TILE_WIDTH // 2 - 1, PREDICTION_COLOUR)
    caption = np.zeros((CAPTION_HEIGHT, TILE_WIDTH, 3), np.uint8)
    text = (
        f"{panorama.name[-CAPTION_NAME_LENGTH:]}  ceil {scores['ceiling_error_px']:.1f} floor "
        f"{scores['floor_error_px']:.1f} px  corners {scores['predicted_corners']}/{scores['label_corners']}  "
        f"IoU3D {scores['iou_3d']:.2f}"
    )
    cv2.putText(caption, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.37, (255, 255, 255), 1, cv2.LINE_AA)
    strip = probability_strip(corner_prob, panorama, peaks, scale)
    return np.vstack([caption, tile, strip, np.zeros((4, TILE_WIDTH, 3), np.uint8)])


def contact_sheet_png(tiles: list[np.ndarray], columns: int = 2) -> bytes:
    """The tiles in a grid of ``columns``, PNG-encoded."""
    tiles = tiles + [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    grid = np.vstack([np.hstack(tiles[i : i + columns]) for i in range(0, len(tiles), columns)])
    ok, encoded = cv2.imencode(".png", grid[..., ::-1])
    if not ok:
        raise OSError("could not encode the contact sheet")
    return encoded.tobytes()


# ----------------------------------------------------------------------------- main


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor files")
    parser.add_argument("--views", type=int, default=4, help="views the network averages (1 or even; default 4)")
    parser.add_argument("--model", type=pathlib.Path, default=None, help="model file (default: the shipped model)")
    parser.add_argument("--out", type=pathlib.Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    parser.add_argument("--limit", type=int, default=None, help="only the first N images (by name)")
    args = parser.parse_args(argv)
    try:
        check_views(args.views)
    except ValueError as error:
        parser.error(str(error))
    if args.limit is not None and args.limit < 1:
        parser.error(f"--limit must be >= 1, got {args.limit}")
    return args


def run(args: argparse.Namespace) -> None:
    """Score every labelled panorama of ``args.data``, print the table, write the CSV and the contact sheet."""
    panoramas = load_panoramas(args.data, args.limit)
    if args.out.exists() and not args.out.is_dir():
        raise InputError(f"--out {args.out} exists and is not a folder")
    model = load_network(args.model)
    rows, tiles = [], []
    tqdm.write(table_header())
    for panorama in tqdm(panoramas, desc="panoramas", unit="image"):
        image = read_labelled_image(panorama.image_path)
        prediction = tuple(np.asarray(a, np.float64) for a in ncjax.predict_boundaries(image, model, views=args.views))
        peaks = predicted_corners(prediction[2])
        scores = score_image(panorama, prediction[0], prediction[1], peaks)
        rows.append(scores)
        tiles.append(contact_tile(panorama, image, prediction, peaks, scores))
        tqdm.write(table_line(scores))
    means = summaries(rows)
    for mean in means:
        print(table_line(mean))
    config = ncjax.NETWORK_PIPELINE_CONFIG
    print(
        f"row errors in px of a 512-row image (ceiling not scored for '{FLAT_CEILING_EXCLUSION_TAG}'); gt, pred: "
        f"corners (totals in the means); corner P/R pooled over images; count: share with the label's corner "
        f"count; peaks: find_corners(threshold="
        f"{config.corner_threshold}, nms_radius={config.nms_radius} columns at 1024, min_corners={config.min_corners}, "
        f"fallback={config.fallback_corner_threshold}); views {args.views}"
    )
    table, sheet = csv_bytes(rows + means), contact_sheet_png(tiles)
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / CSV_NAME, table)
    write_atomic(args.out / SHEET_NAME, sheet)
    print(f"wrote {args.out / CSV_NAME} and {args.out / SHEET_NAME}")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 on bad input (one line on stderr, nothing written)."""
    args = parse_arguments(argv)
    try:
        run(args)
    except InputError as error:
        print(f"real_panoramas: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
