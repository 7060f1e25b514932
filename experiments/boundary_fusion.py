"""Does each column's better boundary give better floor rows, and can the rows tell which it is?

In every column ``tan(phi_ceiling) / tan(phi_floor) = h_c / h_f`` (experiments/RESULTS.md, "The floor check against
the ceiling"), so a column's wall distance can be read twice: off its floor row, and off its ceiling row through
the panorama's median ratio (the pipeline's floor check). On photographs the two fail in different columns: floor
rows run through doorways into the next room, ceiling rows follow fans and headers. Per labelled panorama
(``*.jpg``/``*.png`` with its label_cor ``<stem>.txt``; the shipped model, 4 views, edge snap) this scores the floor
rows a per-column choice between the two gives (mean error, px of a 512-row image) and the raw 3D IoU of their prism
(``benchmarks/real_panoramas.py``'s, up to scale), for each chooser:

- ``floor``: the network's floor row (the benchmark's figure);
- ``ceiling``: the row the ceiling implies wherever it implies one (the floor check at threshold 0);
- ``nearer``: the nearer wall of the two (a doorway's floor row lies beyond the wall);
- ``steadier``: the boundary whose 8 single views (:func:`common.single_view_rows`) spread less in log distance;
- ``weighted``: the two log distances averaged with the inverse of those spreads squared;
- ``straighter``: per wall (the columns between two of the pipeline's corner peaks), the boundary whose point lies
  nearer the line RANSAC fits in the floor plan through both boundaries' points (inliers within ``--tolerance``
  of the wall's median distance), then refined by total least squares;
- ``nearer oracle``: the ceiling's distance where it is both nearer than the floor's and nearer the label (what
  a perfect detector of the columns whose floor row sees beyond the wall could reach);
- ``oracle``: the boundary nearer the label (the ceiling to what a chooser could reach).

With ``--layouts`` it also lays out the ``straighter`` rows with the central pipeline (``NETWORK_PIPELINE_CONFIG``,
its floor check off, as the choice already made it; camera height 1.6 m, no gravity alignment) and scores them as
``benchmarks/central_layouts.py`` does, beside the network's rows with the check on.

    uv run python experiments/boundary_fusion.py --data DIR [--tolerance 0.03] [--layouts]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

import ncjax
from ncjax.evaluation.panorama_labels import (
    central_camera,
    elevation_rows,
    labelled_image_paths,
    load_panorama,
    pixel_angles,
    read_labelled_image,
)
from ncjax.evaluation.panorama_scores import predicted_corners, raw_layout_ious, row_error
from ncjax.io.formats_read import read_layout
from ncjax.io.layout_corners import LayoutCorners
from ncjax.network.predict import default_model
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import central_layout, corners_iou, single_view_rows, written_layout

CHOOSERS = ("floor", "ceiling", "nearer", "steadier", "weighted", "straighter", "nearer oracle", "oracle")
MIN_ELEVATION = 1e-3  # radians: a boundary this near the horizon fixes no distance
RANSAC_ITERATIONS = 300


def row_distances(cam, ceiling_v, floor_v, ratio=None):
    """Per column the wall distance (camera height 1) the floor row gives and the one the ceiling row gives through
    ``ratio`` (``h_c / h_f``; default the panorama's median); NaN where a ceiling row is not above the horizon."""
    columns = np.arange(len(floor_v))
    _, floor_elevation = pixel_angles(cam, columns, floor_v)
    _, ceiling_elevation = pixel_angles(cam, columns, ceiling_v)
    if ratio is None:
        usable = (ceiling_elevation > MIN_ELEVATION) & (floor_elevation < -MIN_ELEVATION)
        ratio = float(np.median(np.tan(ceiling_elevation[usable]) / np.tan(-floor_elevation[usable])))
    from_floor = 1.0 / np.tan(np.maximum(-floor_elevation, MIN_ELEVATION))
    above = ceiling_elevation > MIN_ELEVATION
    from_ceiling = np.where(above, ratio / np.tan(np.maximum(ceiling_elevation, MIN_ELEVATION)), np.nan)
    return from_floor, from_ceiling, ratio


def fitted_line(points: np.ndarray, tolerance: float, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """The plan line ``normal . p = offset`` with most points within ``tolerance`` (RANSAC on point pairs), refit to
    those points by total least squares."""
    best, most = (np.array([1.0, 0.0]), 0.0), -1
    for _ in range(RANSAC_ITERATIONS):
        i, j = rng.choice(len(points), 2, replace=False)
        direction = points[j] - points[i]
        length = np.linalg.norm(direction)
        if length < 1e-9:
            continue
        normal = np.array([-direction[1], direction[0]]) / length
        count = np.sum(np.abs(points @ normal - normal @ points[i]) < tolerance)
        if count > most:
            best, most = (normal, normal @ points[i]), count
    normal, offset = best
    inliers = points[np.abs(points @ normal - offset) < tolerance]
    centre = inliers.mean(axis=0)
    normal = np.linalg.svd(inliers - centre)[2][-1]
    return normal, float(normal @ centre)


def straighter(cam, from_floor, from_ceiling, corner_columns, tolerance: float) -> np.ndarray:
    """Per column the distance of the boundary that lies nearer its wall's line (``straighter`` above)."""
    width = len(from_floor)
    azimuth, _ = pixel_angles(cam, np.arange(width), np.zeros(width))
    heading = np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    walls = np.searchsorted(np.sort(corner_columns), np.arange(width)) % max(len(corner_columns), 1)
    rng = np.random.default_rng(0)
    chosen = from_floor.copy()
    for wall in np.unique(walls):
        columns = np.flatnonzero(walls == wall)
        if len(columns) < 6:
            continue
        floor_points = from_floor[columns, None] * heading[columns]
        ceiling_points = from_ceiling[columns, None] * heading[columns]
        seen = np.isfinite(from_ceiling[columns])
        normal, offset = fitted_line(
            np.concatenate([floor_points, ceiling_points[seen]]),
            tolerance * float(np.median(from_floor[columns])),
            rng,
        )
        floor_off = np.abs(floor_points @ normal - offset)
        ceiling_off = np.where(seen, np.abs(np.nan_to_num(ceiling_points) @ normal - offset), np.inf)
        chosen[columns] = np.where(ceiling_off < floor_off, from_ceiling[columns], from_floor[columns])
    return chosen


def chosen_distances(cam, ceiling_v, floor_v, corner_prob, views, label_floor_v, tolerance) -> dict[str, np.ndarray]:
    """Each chooser's per-column wall distance."""
    from_floor, from_ceiling, ratio = row_distances(cam, ceiling_v, floor_v)
    either = np.where(np.isfinite(from_ceiling), from_ceiling, from_floor)
    single = [row_distances(cam, np.asarray(v.ceiling), np.asarray(v.floor), ratio) for v in views]
    floor_spread = np.std([np.log(f) for f, _, _ in single], axis=0)
    ceiling_spread = np.std([np.log(c) for _, c, _ in single], axis=0)  # NaN where a view sees no ceiling row
    steadier = np.where(np.isfinite(from_ceiling) & (ceiling_spread < floor_spread), from_ceiling, from_floor)
    floor_weight, ceiling_weight = 1 / (floor_spread**2 + 1e-4), 1 / (ceiling_spread**2 + 1e-4)
    weighted = np.exp(
        (floor_weight * np.log(from_floor) + ceiling_weight * np.log(either)) / (floor_weight + ceiling_weight)
    )
    label_distance, _, _ = row_distances(cam, ceiling_v, label_floor_v, ratio)
    ceiling_nearer_label = np.abs(np.log(either / label_distance)) < np.abs(np.log(from_floor / label_distance))
    corners = predicted_corners(corner_prob, NETWORK_PIPELINE_CONFIG)
    return {
        "floor": from_floor,
        "ceiling": either,
        "nearer": np.minimum(from_floor, either),
        "steadier": steadier,
        "weighted": np.where(np.isfinite(weighted), weighted, from_floor),
        "straighter": straighter(cam, from_floor, from_ceiling, corners, tolerance),
        "nearer oracle": np.where(ceiling_nearer_label & (either < from_floor), either, from_floor),
        "oracle": np.where(ceiling_nearer_label, either, from_floor),
    }


def layout_iou(ceiling_v, floor_v, corner_prob, cam, label: LayoutCorners, config) -> float:
    """3D IoU of the central pipeline's written layout of these rows (no layout, or one no label_cor can hold: 0)."""
    layout = central_layout(ceiling_v, floor_v, corner_prob, cam, config)
    with tempfile.TemporaryDirectory() as folder:
        try:
            return corners_iou(written_layout(layout, cam, Path(folder)), label)
        except ValueError:  # a corner at the camera: no label_cor holds it
            return 0.0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--tolerance", type=float, default=0.03, help="straighter: inliers, share of the distance")
    parser.add_argument("--layouts", action="store_true", help="also the central layouts of the straighter rows")
    args = parser.parse_args(argv)
    model = default_model()
    pairs = labelled_image_paths(args.data)
    panoramas = [load_panorama(*pair) for pair in pairs]
    check_off = dataclasses.replace(
        NETWORK_PIPELINE_CONFIG,
        floor_check=dataclasses.replace(NETWORK_PIPELINE_CONFIG.floor_check, threshold=float("inf")),
    )
    errors, ious, layouts = ({name: [] for name in CHOOSERS} for _ in range(3))
    for panorama, (_, label_path) in zip(panoramas, pairs, strict=True):
        image = read_labelled_image(panorama.image_path)
        ceiling_v, floor_v, corner_prob = (np.asarray(r, np.float64) for r in ncjax.predict_boundaries(image, model))
        cam = central_camera(panorama.width, panorama.height)
        views = single_view_rows(image, model)
        distances = chosen_distances(cam, ceiling_v, floor_v, corner_prob, views, panorama.floor_v, args.tolerance)
        cells = []
        for name, distance in distances.items():
            rows = elevation_rows(cam, -np.arctan(1.0 / distance))
            errors[name].append(row_error(rows, panorama.floor_v))
            ious[name].append(raw_layout_ious(panorama, ceiling_v, rows)[1])
            cells.append(f"{errors[name][-1]:.1f} / {ious[name][-1]:.3f}")
            if args.layouts and name in ("floor", "straighter"):
                label = read_layout(label_path, panorama.width, panorama.height)
                config = NETWORK_PIPELINE_CONFIG if name == "floor" else check_off
                layouts[name].append(layout_iou(ceiling_v, rows, corner_prob, cam, label, config))
        print(f"| {panorama.name} | " + " | ".join(cells) + " |", flush=True)
    closed = np.array(["closed" in panorama.tags for panorama in panoramas])
    print(f"\nper chooser over {len(panoramas)} panoramas: floor error px (closed rooms), raw 3D IoU (closed rooms), "
          "images whose raw IoU is better / worse than the floor rows'")  # fmt: skip
    reference = np.array(ious["floor"])
    for name in CHOOSERS:
        error, iou = np.array(errors[name]), np.array(ious[name])
        better, worse = int(np.sum(iou > reference + 1e-9)), int(np.sum(iou < reference - 1e-9))
        print(
            f"{name:14s} {error.mean():5.1f} ({error[closed].mean():5.1f})  {np.nanmean(iou):.3f} "
            f"({np.nanmean(iou[closed]):.3f})  {better} / {worse}"
        )
    if args.layouts:
        base, other = np.array(layouts["floor"]), np.array(layouts["straighter"])
        print(
            f"central layouts, 3D IoU: the network's rows {base.mean():.3f}, the straighter rows {other.mean():.3f} "
            f"(better on {int(np.sum(other > base + 1e-6))}, worse on {int(np.sum(other < base - 1e-6))})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
