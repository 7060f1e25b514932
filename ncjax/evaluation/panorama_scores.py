"""The scores of the network on labelled real panoramas: boundary rows, corners and the raw layout's IoU.

Per image (:func:`score_image`, one CSV row) and pooled (:func:`summaries`); ``benchmarks/real_panoramas.py``
states each figure's definition. The table's lines and the CSV are built here too.
"""

from __future__ import annotations

import csv
import io
import math

import jax
import jax.numpy as jnp
import numpy as np

from ..pipeline.config import PipelineConfig
from ..pipeline.corners import configured_corners
from . import layout_metrics
from .network_metrics import REFERENCE_WIDTH
from .panorama_labels import LabelledPanorama, central_camera, circular_distance, prism, raw_prediction_room

TOLERANCES = (0.01, 0.025)  # corner match distance, fraction of the width
SUBSET_TAGS = ("closed", "open_plan")


# the pipeline's corner peak finder, its settings static
peak_finder = jax.jit(configured_corners, static_argnames="config")


def predicted_corners(corner_prob: np.ndarray, config: PipelineConfig) -> np.ndarray:
    """Corner columns: the peaks the pipeline takes with ``config`` (the benchmark's:
    :data:`ncjax.NETWORK_PIPELINE_CONFIG`)."""
    columns, mask, _, _ = peak_finder(jnp.asarray(corner_prob, jnp.float32), config)
    return np.asarray(columns, np.float64)[np.asarray(mask)]


def one_to_one_pairs(columns: np.ndarray, targets: np.ndarray, tolerance: float, width: int) -> list[tuple[int, int]]:
    """The ``(column, target)`` index pairs of ``columns`` and distinct targets within ``tolerance`` of each other
    (circularly), the nearest pairs first."""
    pairs = []
    if len(columns) == 0 or len(targets) == 0:
        return pairs
    distance = circular_distance(columns[:, None], targets[None, :], width)
    matched, taken = np.zeros(len(columns), bool), np.zeros(len(targets), bool)
    for flat in np.argsort(distance, axis=None, kind="stable"):
        i, j = np.unravel_index(flat, distance.shape)
        if distance[i, j] > tolerance:
            break
        if not matched[i] and not taken[j]:
            matched[i] = taken[j] = True
            pairs.append((int(i), int(j)))
    return pairs


def match_one_to_one(columns: np.ndarray, targets: np.ndarray, tolerance: float, width: int) -> np.ndarray:
    """Which ``columns`` pair with a distinct target within ``tolerance``, the nearest pairs first."""
    matched = np.zeros(len(columns), bool)
    for i, _ in one_to_one_pairs(columns, targets, tolerance, width):
        matched[i] = True
    return matched


def corner_counts(peaks: np.ndarray, panorama: LabelledPanorama, fraction: float) -> tuple[int, int]:
    """``(matched, scored)`` peaks within ``fraction`` of the width; a peak on an occluded corner is not scored."""
    tolerance = fraction * panorama.width
    matched = match_one_to_one(peaks, panorama.corner_columns, tolerance, panorama.width)
    on_occluded = match_one_to_one(peaks[~matched], panorama.occluded_columns, tolerance, panorama.width)
    return int(matched.sum()), int(len(peaks) - on_occluded.sum())


def row_error(predicted: np.ndarray, label: np.ndarray, signed: bool = False) -> float:
    """Mean |row error| over the columns where both are finite, in pixels of a 512-row image; ``signed``: the mean
    row error itself (positive below the label, towards the nadir)."""
    both = np.isfinite(predicted) & np.isfinite(label)
    scale = REFERENCE_WIDTH / len(label)  # = 512 / H for a W = 2 H panorama
    error = predicted[both] - label[both]
    return float(scale * np.mean(error if signed else np.abs(error))) if both.any() else math.nan


def ratio(numerator: float, denominator: float) -> float:
    return numerator / denominator if denominator else math.nan


def tolerance_key(fraction: float) -> str:
    return f"{100 * fraction:g}pct"


def raw_layout_ious(panorama: LabelledPanorama, ceiling_v: np.ndarray, floor_v: np.ndarray) -> tuple[float, float]:
    """2D and 3D IoU of the raw predicted prism and the label's, both at camera height 1 (up to scale)."""
    predicted = raw_prediction_room(ceiling_v, floor_v, central_camera(panorama.width, panorama.height))
    label = prism(panorama.plan, panorama.ceiling_height)
    iou_2d = layout_metrics.iou_2d(predicted, label)
    finite_height = np.isfinite(predicted["ceiling_corners"][0, 2])
    iou_3d = layout_metrics.iou_3d(predicted, label, up_to_scale=True) if finite_height else math.nan
    return iou_2d, iou_3d


def score_image(panorama: LabelledPanorama, ceiling_v: np.ndarray, floor_v: np.ndarray, peaks: np.ndarray) -> dict:
    """The figures of one image (a CSV row)."""
    scores = {
        "name": panorama.name,
        "tags": " ".join(panorama.tags),
        "ceiling_error_px": row_error(ceiling_v, panorama.ceiling_v) if panorama.score_ceiling else math.nan,
        "floor_error_px": row_error(floor_v, panorama.floor_v),
        "floor_signed_error_px": row_error(floor_v, panorama.floor_v, signed=True),
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
    for key in (
        "ceiling_error_px",
        "floor_error_px",
        "floor_signed_error_px",
        "exact_corner_count",
        "iou_2d",
        "iou_3d",
    ):
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
