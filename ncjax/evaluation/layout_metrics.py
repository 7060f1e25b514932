"""Layout metrics (paper Sections 5.3-5.5): 3D and 2D IoU, corner error, CEN, heights, lines.

These run on the host in numpy: they are evaluation code, not part of the traced
pipeline. Floor plans may be non-convex; intersections are exact polygon
intersections computed with shapely (GEOS), which handles the degenerate cases
(touching edges, collinear walls, self-touching predictions) that a hand-written
clipper gets wrong.

A layout is anything with ``ceiling_corners`` and ``floor_corners`` (K, 3) in
metres (camera frame) and optionally a ``mask`` (K,) — e.g. a pipeline Layout or
:class:`ncjax.synth.RoomLabels` (then ``corner_mask`` is used) — or a :class:`ncjax.synth.Room`
(the full room, its corners put in image order), or a dict with those keys.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import shapely

__all__ = [
    "aggregate",
    "corner_error",
    "evaluate_layout",
    "iou_2d",
    "iou_3d",
    "line_errors",
    "layout_arrays",
]


def layout_arrays(layout: Any) -> tuple[np.ndarray, np.ndarray]:
    """Valid ceiling and floor corners (N, 3) each, float64, in layout order."""
    if isinstance(layout, Mapping):
        ceiling, floor = layout["ceiling_corners"], layout["floor_corners"]
        mask = layout.get("mask")
    elif hasattr(layout, "ceiling_corners"):
        ceiling, floor = layout.ceiling_corners, layout.floor_corners
        mask = getattr(layout, "mask", getattr(layout, "corner_mask", None))
    elif hasattr(layout, "corners") and hasattr(layout, "ceiling_height"):
        from ..synth.rooms import room_corners_3d

        # Rooms are counter-clockwise; layouts run in image order (decreasing azimuth).
        ceiling, floor = (np.asarray(c)[np.asarray(layout.mask)][::-1] for c in room_corners_3d(layout))
        mask = None
    else:
        raise TypeError(f"not a layout: {type(layout).__name__} has no ceiling_corners/floor_corners")
    ceiling = np.asarray(ceiling, dtype=np.float64)
    floor = np.asarray(floor, dtype=np.float64)
    if ceiling.ndim != 2 or ceiling.shape[-1] != 3 or floor.shape != ceiling.shape:
        raise ValueError(f"corners must be (K, 3) each, got {ceiling.shape} and {floor.shape}")
    keep = np.ones(len(ceiling), bool) if mask is None else np.asarray(mask, bool)
    return ceiling[keep], floor[keep]


def _footprint(ceiling: np.ndarray, floor: np.ndarray) -> shapely.Geometry:
    """Floor plan polygon from the mean of ceiling and floor corners (made valid)."""
    plan = 0.5 * (ceiling[:, :2] + floor[:, :2])
    if len(plan) < 3 or not np.all(np.isfinite(plan)):
        return shapely.Polygon()
    polygon = shapely.Polygon(plan)
    return polygon if polygon.is_valid else shapely.make_valid(polygon)


def _heights(ceiling: np.ndarray, floor: np.ndarray) -> tuple[float, float]:
    return float(np.mean(ceiling[:, 2])), float(np.mean(floor[:, 2]))


def iou_2d(pred: Any, gt: Any) -> float:
    """Intersection over union of the floor plans (non-convex polygons)."""
    a, b = _footprint(*layout_arrays(pred)), _footprint(*layout_arrays(gt))
    union = shapely.area(shapely.union(a, b))
    return float(shapely.area(shapely.intersection(a, b)) / union) if union > 0 else 0.0


def iou_3d(pred: Any, gt: Any, up_to_scale: bool = False) -> float:
    """Intersection over union of the room prisms (floor plan x [floor, ceiling]).

    Args:
        pred, gt: layouts.
        up_to_scale: first scale ``pred`` so that its camera height (-floor) equals
            the ground truth's, the "3D IoU (u2s)" of the paper's Table comparison.
    """
    pred_ceiling, pred_floor = layout_arrays(pred)
    gt_ceiling, gt_floor = layout_arrays(gt)
    if up_to_scale:
        scale = _heights(gt_ceiling, gt_floor)[1] / _heights(pred_ceiling, pred_floor)[1]
        pred_ceiling, pred_floor = pred_ceiling * scale, pred_floor * scale
    a, b = _footprint(pred_ceiling, pred_floor), _footprint(gt_ceiling, gt_floor)
    top_a, bottom_a = _heights(pred_ceiling, pred_floor)
    top_b, bottom_b = _heights(gt_ceiling, gt_floor)
    overlap = max(0.0, min(top_a, top_b) - max(bottom_a, bottom_b))
    intersection = shapely.area(shapely.intersection(a, b)) * overlap
    volume_a = shapely.area(a) * max(0.0, top_a - bottom_a)
    volume_b = shapely.area(b) * max(0.0, top_b - bottom_b)
    union = volume_a + volume_b - intersection
    return float(intersection / union) if union > 0 else 0.0


def corner_error(pred: Any, gt: Any) -> tuple[float, int | None]:
    """Mean L2 distance (metres) between matched ceiling and floor corners (CE).

    Both layouts list corners in image order, so the one-to-one matching is the
    cyclic shift of the prediction with the smallest mean distance. A different
    number of corners cannot be matched one-to-one: CE is NaN (a failure).

    Returns:
        ``(ce, shift)``: ``shift`` aligns prediction corner ``(i + shift) % N``
        with ground-truth corner ``i`` (None on a count mismatch).
    """
    pred_ceiling, pred_floor = layout_arrays(pred)
    gt_ceiling, gt_floor = layout_arrays(gt)
    n = len(gt_ceiling)
    if len(pred_ceiling) != n or n == 0:
        return math.nan, None
    pred_points = np.concatenate([pred_ceiling, pred_floor], 1).reshape(n, 2, 3)
    gt_points = np.concatenate([gt_ceiling, gt_floor], 1).reshape(n, 2, 3)
    errors = [np.mean(np.linalg.norm(np.roll(pred_points, -s, 0) - gt_points, axis=-1)) for s in range(n)]
    best = int(np.argmin(errors))
    return float(errors[best]), best


def _layout_diagonal(ceiling: np.ndarray, floor: np.ndarray) -> float:
    points = np.concatenate([ceiling, floor])
    return float(np.linalg.norm(points.max(0) - points.min(0)))


def line_errors(pred: Any, gt: Any) -> tuple[float, float]:
    """Mean direction error (degrees) and depth error (metres) of the wall lines.

    Wall ``i`` runs from corner ``i`` to ``i + 1``; walls are matched through the
    corner matching of :func:`corner_error`. Direction error
    ``arccos(|l . l_gt|)``, depth error ``| |lbar| - |lbar_gt| |`` for unit
    directions (paper Section 5.3), over ceiling and floor lines.
    """
    _, shift = corner_error(pred, gt)
    if shift is None:
        return math.nan, math.nan

    def lines(ceiling, floor):
        out = []
        for points in (ceiling, floor):
            following = np.roll(points, -1, 0)
            direction = following - points
            direction /= np.maximum(np.linalg.norm(direction, axis=-1, keepdims=True), 1e-12)
            out.append((direction, np.cross(points, direction)))
        return out

    pred_ceiling, pred_floor = layout_arrays(pred)
    pred_lines = lines(np.roll(pred_ceiling, -shift, 0), np.roll(pred_floor, -shift, 0))
    gt_lines = lines(*layout_arrays(gt))
    direction_errors, depth_errors = [], []
    for (pd, pm), (gd, gm) in zip(pred_lines, gt_lines, strict=True):
        cosine = np.clip(np.abs(np.sum(pd * gd, -1)), 0.0, 1.0)
        direction_errors.append(np.degrees(np.arccos(cosine)))
        depth_errors.append(np.abs(np.linalg.norm(pm, axis=-1) - np.linalg.norm(gm, axis=-1)))
    return float(np.mean(direction_errors)), float(np.mean(depth_errors))


def evaluate_layout(pred: Any, gt: Any) -> dict[str, float]:
    """All layout metrics of one prediction against its ground truth.

    Returns:
        A dict with "iou3d", "iou3d_up_to_scale", "iou2d" (fractions in [0, 1]),
        "ce" (metres; NaN when the corner counts differ), "cen" (CE divided by the
        diagonal of the ground truth's bounding box), "height_error" (|room
        height - true room height|, metres), "ceiling_error" and "floor_error"
        (metres), "direction_error" (degrees), "depth_error" (metres),
        "corner_count_match" (1.0 or 0.0).
    """
    gt_ceiling, gt_floor = layout_arrays(gt)
    pred_ceiling, pred_floor = layout_arrays(pred)
    ce, shift = corner_error(pred, gt)
    direction_error, depth_error = line_errors(pred, gt)
    pred_top, pred_bottom = _heights(pred_ceiling, pred_floor) if len(pred_ceiling) else (math.nan, math.nan)
    gt_top, gt_bottom = _heights(gt_ceiling, gt_floor)
    return {
        "iou3d": iou_3d(pred, gt),
        "iou3d_up_to_scale": iou_3d(pred, gt, up_to_scale=True) if len(pred_ceiling) else 0.0,
        "iou2d": iou_2d(pred, gt),
        "ce": ce,
        "cen": ce / _layout_diagonal(gt_ceiling, gt_floor),
        "height_error": abs((pred_top - pred_bottom) - (gt_top - gt_bottom)),
        "ceiling_error": abs(pred_top - gt_top),
        "floor_error": abs(pred_bottom - gt_bottom),
        "direction_error": direction_error,
        "depth_error": depth_error,
        "corner_count_match": float(shift is not None),
    }


def aggregate(results: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Mean of each metric over rooms (NaN-skipping) plus "failure_rate" (corner
    count mismatches) and "rooms"."""
    results = list(results)
    if not results:
        raise ValueError("no results to aggregate")
    summary = {key: float(np.nanmean([r[key] for r in results])) for key in results[0] if key != "corner_count_match"}
    summary["failure_rate"] = 1.0 - float(np.mean([r["corner_count_match"] for r in results]))
    summary["rooms"] = float(len(results))
    return summary
