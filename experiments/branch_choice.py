"""Would ``world="auto"`` choose better between its two branches by how well each layout agrees with the rows?

On real photographs the layouts lose to the raw rows they come from (experiments/RESULTS.md, "Real
photographs"). ``world="auto"`` keeps the branch whose status is more usable, then the one that reprojects more
rows within the inlier threshold (:func:`ncjax.pipeline.run.choose_manhattan`); the Atlanta branch's free angles
let it follow the rows' noise, so it explains more rows with walls that are no better. This experiment scores,
per labelled panorama (``*.jpg``/``*.png`` with its label_cor ``<stem>.txt``), the Manhattan and the Atlanta
layout of the central pipeline (the shipped model's rows, 4 views, edge snap, no gravity alignment, camera height
1.6 m, ``NETWORK_PIPELINE_CONFIG``), each layout's agreement with the rows themselves (the up-to-scale 3D IoU of the
layout against the prism of its rows, :func:`~ncjax.evaluation.panorama_labels.raw_prediction_room`) and its 3D
IoU against the label; then the mean 3D IoU of auto's choice, of the branch that agrees better with the rows
(among those written with a geometry), of the branch chosen by the same agreement column by column (the form traced
code could compute: per column, the range of the layout's first wall against the row's, which for plans star-shaped
about the camera gives the same areas) and of the better of the two by the label.

With ``--single-views`` it also lays out the rows of each of the 8 views the 4-view average is made of (the
panorama rolled by a quarter turn at a time, each also mirrored, read by the network alone and mapped back): both
branches of all 9 row sets are candidates, and it scores the candidate that agrees best with the others (the
medoid by up-to-scale 3D IoU: a layout-level ensemble, where the 4-view average is a row-level one), their mean and
the best of them by the label.

    uv run python experiments/branch_choice.py --data DIR [--single-views]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.evaluation import layout_metrics
from ncjax.evaluation.panorama_labels import pixel_angles, raw_prediction_room, wall_distances
from ncjax.io.export import status_has_geometry
from ncjax.io.images import read_panorama_file
from ncjax.network.predict import default_model
from ncjax.pipeline.assemble import finish_layout
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior, rescale_to_prior
from ncjax.pipeline.run import fit_walls, prior_config
from ncjax.pipeline.types import Rows
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import central_layout, corners_iou, labelled_rows, print_mean_ious, single_view_rows, written_layout

BRANCHES = ("manhattan", "atlanta")


def branch_layouts(rows: Rows, cam: ncjax.NonCentralPanorama) -> list[ncjax.Layout]:
    """The Manhattan and the Atlanta layout ``world="auto"`` chooses between, at the default camera height."""
    prior = HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT)
    walls = fit_walls(rows, cam, prior, jax.random.key(0), NETWORK_PIPELINE_CONFIG, "auto")
    config = prior_config(NETWORK_PIPELINE_CONFIG, walls.prior_room_height)
    branches = [jax.tree.map(lambda x, i=i: x[i], walls.branches) for i in range(len(BRANCHES))]
    return [rescale_to_prior(finish_layout(walls.evidence, branch, config), prior) for branch in branches]


def layout_corners(layout: ncjax.Layout) -> dict | None:
    """A layout's corners for :mod:`ncjax.evaluation.layout_metrics` (None without a geometry)."""
    if not status_has_geometry(bool(layout.ok), int(layout.status)):
        return None
    mask = np.asarray(layout.mask)
    return {name: np.asarray(getattr(layout, name))[mask] for name in ("ceiling_corners", "floor_corners")}


def agreement(layout: ncjax.Layout, raw: dict) -> float:
    """Up-to-scale 3D IoU of a layout against its rows' prism (-1 without a layout)."""
    corners = layout_corners(layout)
    return -1.0 if corners is None else float(layout_metrics.iou_3d(corners, raw, up_to_scale=True))


def column_agreement(layout: ncjax.Layout, raw: dict, cam: ncjax.NonCentralPanorama) -> float:
    """:func:`agreement` column by column: the plans' areas as sums of squared ranges along the columns' azimuths
    (-1 without a layout)."""
    corners = layout_corners(layout)
    if corners is None:
        return -1.0
    scale = -1.0 / corners["floor_corners"][:, 2].mean()  # camera height 1, as the rows' prism
    azimuth, _ = pixel_angles(cam, np.arange(cam.width), np.zeros(cam.width))
    layout_range = wall_distances(corners["floor_corners"][:, :2] * scale, azimuth)
    layout_range = np.where(np.isfinite(layout_range), layout_range, 0.0)
    rows_range = np.linalg.norm(raw["floor_corners"][:, :2], axis=1)
    heights = [corners["ceiling_corners"][:, 2].mean() * scale + 1, raw["ceiling_corners"][0, 2] + 1]
    shared = np.sum(np.minimum(layout_range, rows_range) ** 2) * min(heights)
    volumes = np.sum(layout_range**2) * heights[0] + np.sum(rows_range**2) * heights[1]
    return float(shared / (volumes - shared))


def medoid(candidates: list[dict]) -> int:
    """Index of the layout with the largest summed up-to-scale 3D IoU with the others."""
    agreement_sums = np.zeros(len(candidates))
    for i, a in enumerate(candidates):
        for j in range(i + 1, len(candidates)):
            iou = layout_metrics.iou_3d(a, candidates[j], up_to_scale=True)
            agreement_sums[[i, j]] += iou
    return int(np.argmax(agreement_sums))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--single-views", action="store_true", help="also the medoid of the single views' layouts")
    args = parser.parse_args(argv)
    run = jax.jit(branch_layouts)
    model = default_model()
    chosen = {"auto": [], "agreement": [], "agreement column by column": [], "better by the label": []}
    if args.single_views:
        chosen |= {"medoid of the 9 row sets' 18 layouts": [], "their mean": [], "their best by the label": []}
    print("| image | auto | " + " | ".join(f"{b}: 3D IoU (agreement)" for b in BRANCHES) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in BRANCHES) + " |")
    for path, cam, label, (ceiling_v, floor_v, corner_prob) in labelled_rows(args.data, model):
        rows = Rows(ceiling_v, floor_v, corner_prob)
        raw = raw_prediction_room(np.asarray(ceiling_v), np.asarray(floor_v), cam)
        layouts = [jax.device_get(layout) for layout in run(rows, cam)]
        with_files = _scored(layouts + [central_layout(ceiling_v, floor_v, corner_prob, cam)], cam, label)
        *ious, auto = with_files
        agreements = [agreement(layout, raw) for layout in layouts]
        chosen["auto"].append(auto)
        chosen["agreement"].append(ious[int(np.argmax(agreements))])
        by_column = [column_agreement(layout, raw, cam) for layout in layouts]
        chosen["agreement column by column"].append(ious[int(np.argmax(by_column))])
        chosen["better by the label"].append(max(ious))
        cells = " | ".join(f"{iou:.3f} ({agree:.3f})" for iou, agree in zip(ious, agreements, strict=True))
        print(f"| {path.stem} | {auto:.3f} | {cells} |", flush=True)
        if args.single_views:
            image = read_panorama_file(path).image
            for view_rows in single_view_rows(image, model):
                view_layouts = [jax.device_get(layout) for layout in run(view_rows, cam)]
                layouts += view_layouts
                ious += _scored(view_layouts, cam, label)
            candidates = [(corners, iou) for layout, iou in zip(layouts, ious, strict=True)
                          if (corners := layout_corners(layout)) is not None]  # fmt: skip
            best = medoid([corners for corners, _ in candidates])
            chosen["medoid of the 9 row sets' 18 layouts"].append(candidates[best][1])
            chosen["their mean"].append(float(np.mean([iou for _, iou in candidates])))
            chosen["their best by the label"].append(max(iou for _, iou in candidates))
    print_mean_ious(chosen)
    return 0


def _scored(layouts: list[ncjax.Layout], cam: ncjax.NonCentralPanorama, label) -> list[float]:
    """Each layout's 3D IoU against the label, as ``benchmarks/central_layouts.py`` scores it (no layout: 0)."""
    scores = []
    for layout in layouts:
        with tempfile.TemporaryDirectory() as folder:
            scores.append(corners_iou(written_layout(layout, cam, Path(folder)), label))
    return scores


if __name__ == "__main__":
    raise SystemExit(main())
