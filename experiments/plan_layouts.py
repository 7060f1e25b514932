"""Would a Manhattan room read straight off the floor plan of the network's rows beat the pipeline's layouts?

On real photographs the raw rows' polygon beats the layouts made from them (experiments/RESULTS.md, "Real
photographs"): where the rows are jagged or run through doorways, RANSAC's single-wall fits and the least-squares
adjustment follow them. This experiment builds the simplest robust alternative, in the manner of HorizonNet's
post-processing, and scores it beside the pipeline on the same rows:

1. each column's floor row is a plan point at camera height 1 (central camera; the ceiling's height from the
   panorama's median ratio of the two rows' tangents);
2. the columns between consecutive corner peaks (the pipeline's own, ``NETWORK_PIPELINE_CONFIG``) are one wall;
   the yaw is the one, on a 0.25-degree grid, at which the walls are straightest: the count-weighted sum of each
   wall's median absolute deviation across the nearer Manhattan direction, over its median range;
3. each wall takes that direction and the median offset of its points; consecutive walls of one direction whose
   offsets agree within 15% are merged, otherwise a wall is inserted between them along the ray of their shared
   corner (an occlusion).

No least squares: medians ignore the rows that leave the wall as long as most stay on it. Per labelled panorama
(``*.jpg``/``*.png`` with its label_cor ``<stem>.txt``) it prints the 3D IoU of the pipeline's layout (central mode,
world auto, camera height 1.6 m, the rows of 4 views with edge snap, no gravity alignment, as
``experiments/corners_or_rows.py``), of the plan layout, and of the one of the two whose rows lie within the
inlier threshold of more of the network's rows (a choice the pipeline could make), scored as
``benchmarks/central_layouts.py`` scores (no layout counts 0); then the means and the mean of the better of the two.

    uv run python experiments/plan_layouts.py --data DIR
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.evaluation.central_metrics import evaluate_corners, room_geometry, surface_classes
from ncjax.io.layout_corners import LayoutCorners, corners_from_3d, pixel_angles
from ncjax.network.predict import default_model
from ncjax.pipeline.corners import configured_corners
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import central_layout, corners_iou, labelled_rows, print_mean_ious, written_layout

YAWS = np.radians(np.arange(0.0, 90.0, 0.25))
CORNER_MARGIN = 4  # columns next to a corner peak left out of its walls
MERGE_FRACTION = 0.15
MIN_POINTS = 3


def rotation(yaw: float) -> np.ndarray:
    """Plan points times its transpose: coordinates along the Manhattan axes at ``yaw``."""
    return np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])


def spreads(points: np.ndarray) -> np.ndarray:
    """Median absolute deviation of each Manhattan coordinate of a wall's points (axis 0: x = const walls)."""
    return np.median(np.abs(points - np.median(points, axis=0)), axis=0)


def wall_columns(corners: np.ndarray, width: int) -> list[np.ndarray]:
    """Columns of the wall after each corner peak, ``CORNER_MARGIN`` columns from both of its corners."""
    walls = []
    for start, end in zip(corners, np.roll(corners, -1), strict=True):
        end = end + width if end <= start else end
        columns = np.arange(start + CORNER_MARGIN, end - CORNER_MARGIN + 1)
        walls.append((columns if len(columns) >= MIN_POINTS else np.arange(start, end + 1)) % width)
    return walls


def straightest_yaw(points: np.ndarray, walls: list[np.ndarray]) -> float:
    def cost(yaw):
        total = 0.0
        for columns in walls:
            rotated = points[columns] @ rotation(yaw).T
            total += len(columns) * spreads(rotated).min() / np.median(np.linalg.norm(rotated, axis=1))
        return total

    return YAWS[np.argmin([cost(yaw) for yaw in YAWS])]


def plan_corners(points: np.ndarray, azimuth: np.ndarray, walls: list[np.ndarray], yaw: float) -> np.ndarray | None:
    """Plan corners (n, 2), camera frame, of the Manhattan walls through ``walls``' points (None: one direction)."""
    to_axes = rotation(yaw)
    placed = []  # [axis held constant, its value, columns]
    for columns in walls:
        rotated = points[columns] @ to_axes.T
        axis = int(np.argmin(spreads(rotated)))
        placed.append([axis, float(np.median(rotated[:, axis])), columns])
    merged = True
    while merged and len(placed) > 1:
        merged = False
        for i in range(len(placed)):
            a, b = placed[i], placed[(i + 1) % len(placed)]
            if a[0] == b[0] and abs(a[1] - b[1]) < MERGE_FRACTION * max(abs(a[1]), abs(b[1])):
                columns = np.concatenate([a[2], b[2]])
                placed[i] = [a[0], float(np.median((points[columns] @ to_axes.T)[:, a[0]])), columns]
                del placed[(i + 1) % len(placed)]
                merged = True
                break
    if len({axis for axis, _, _ in placed}) < 2:
        return None
    corners = []
    for i in range(len(placed)):
        a, b = placed[i], placed[(i + 1) % len(placed)]
        if a[0] != b[0]:
            corner = np.zeros(2)
            corner[a[0]], corner[b[0]] = a[1], b[1]
            corners.append(corner)
            continue
        # parallel walls: the nearer one ends at the shared corner's ray, a wall along that ray joins the other
        nearer = a if abs(a[1]) < abs(b[1]) else b
        ray_azimuth = azimuth[a[2][-1]] if nearer is a else azimuth[b[2][0]]
        ray = to_axes @ np.array([np.cos(ray_azimuth), np.sin(ray_azimuth)])
        across = nearer[1] / ray[nearer[0]] * ray[1 - nearer[0]]
        for axis, value, _ in (a, b):
            corner = np.zeros(2)
            corner[axis], corner[1 - axis] = value, across
            corners.append(corner)
    return np.asarray(corners) @ to_axes


def plan_layout(ceiling_v, floor_v, corner_prob, cam: ncjax.NonCentralPanorama) -> LayoutCorners | None:
    """The plan layout of one central panorama's rows (module docstring), at camera height 1."""
    width, height = cam.width, cam.height
    columns = np.arange(width, dtype=np.float64)
    azimuth, ceiling_elevation = pixel_angles(width, height, np.stack([columns, ceiling_v], -1))
    _, floor_elevation = pixel_angles(width, height, np.stack([columns, floor_v], -1))
    seen = (ceiling_elevation > 0.03) & (floor_elevation < -0.03)
    ceiling_height = np.median(np.tan(ceiling_elevation[seen]) / np.tan(-floor_elevation[seen]))
    distance = 1.0 / np.tan(np.clip(-floor_elevation, 0.03, None))
    points = distance[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], -1)
    found, mask, _, _ = configured_corners(jnp.asarray(corner_prob), NETWORK_PIPELINE_CONFIG)
    corners = np.round(np.asarray(found)[np.asarray(mask)]).astype(int) % width
    if len(corners) < 2:
        return None
    walls = wall_columns(np.sort(corners), width)
    plan = plan_corners(points, azimuth, walls, straightest_yaw(points, walls))
    if plan is None:
        return None
    ceiling = np.concatenate([plan, np.full((len(plan), 1), ceiling_height)], 1)
    floor = np.concatenate([plan, np.full((len(plan), 1), -1.0)], 1)
    return corners_from_3d(ceiling, floor, cam, format="ncjax", units="camera heights")


def rows_explained(corners: LayoutCorners, ceiling_v, floor_v, threshold: float) -> float:
    """Fraction of the network's ceiling and floor rows within ``threshold`` px of the layout's boundaries."""
    classes = surface_classes(room_geometry(corners, metric=False), corners.width, corners.height)
    ceiling = np.sum(classes == 0, axis=0) - 0.5
    floor = corners.height - np.sum(classes == 2, axis=0) - 0.5
    return 0.5 * (np.mean(np.abs(ceiling - ceiling_v) < threshold) + np.mean(np.abs(floor - floor_v) < threshold))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    args = parser.parse_args(argv)
    model = default_model()
    threshold = NETWORK_PIPELINE_CONFIG.ransac.inlier_threshold
    scores = {"pipeline": [], "plan": [], "more rows explained": [], "better of the two": []}
    print("| image | pipeline (rows explained) | plan (rows explained) |")
    print("| --- | --- | --- |")
    with tempfile.TemporaryDirectory() as work:
        for image_path, cam, label, (ceiling_v, floor_v, corner_prob) in labelled_rows(args.data, model):
            written = written_layout(central_layout(ceiling_v, floor_v, corner_prob, cam), cam, pathlib.Path(work))
            pipeline = corners_iou(written, label)
            pipeline_rows = rows_explained(written, ceiling_v, floor_v, threshold) if pipeline > 0 else 0.0
            corners = plan_layout(ceiling_v, floor_v, corner_prob, cam)
            plan = plan_rows = 0.0
            if corners is not None:
                plan = evaluate_corners(corners, label)["iou3d"]
                plan_rows = rows_explained(corners, ceiling_v, floor_v, threshold)
            scores["pipeline"].append(pipeline)
            scores["plan"].append(plan)
            scores["more rows explained"].append(plan if plan_rows > pipeline_rows else pipeline)
            scores["better of the two"].append(max(plan, pipeline))
            cells = f"{pipeline:.3f} ({pipeline_rows:.2f}) | {plan:.3f} ({plan_rows:.2f})"
            print(f"| {image_path.stem} | {cells} |", flush=True)
    print_mean_ious(scores)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
