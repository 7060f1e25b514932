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
(among those written with a geometry) and of the better of the two by the label.

    uv run python experiments/branch_choice.py --data DIR
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.evaluation import layout_metrics
from ncjax.evaluation.panorama_labels import raw_prediction_room
from ncjax.io.export import status_has_geometry
from ncjax.network.predict import default_model
from ncjax.pipeline.assemble import finish_layout
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior, rescale_to_prior
from ncjax.pipeline.run import fit_walls, prior_config
from ncjax.pipeline.types import Rows
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import central_layout, corners_iou, labelled_rows, written_layout

BRANCHES = ("manhattan", "atlanta")


def branch_layouts(rows: Rows, cam: ncjax.NonCentralPanorama) -> list[ncjax.Layout]:
    """The Manhattan and the Atlanta layout ``world="auto"`` chooses between, at the default camera height."""
    prior = HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT)
    walls = fit_walls(rows, cam, prior, jax.random.key(0), NETWORK_PIPELINE_CONFIG, "auto")
    config = prior_config(NETWORK_PIPELINE_CONFIG, walls.prior_room_height)
    branches = [jax.tree.map(lambda x, i=i: x[i], walls.branches) for i in range(len(BRANCHES))]
    return [rescale_to_prior(finish_layout(walls.evidence, branch, config), prior) for branch in branches]


def agreement(layout: ncjax.Layout, raw: dict) -> float:
    """Up-to-scale 3D IoU of a layout against its rows' prism (-1 without a layout)."""
    if not status_has_geometry(bool(layout.ok), int(layout.status)):
        return -1.0
    mask = np.asarray(layout.mask)
    corners = {name: np.asarray(getattr(layout, name))[mask] for name in ("ceiling_corners", "floor_corners")}
    return float(layout_metrics.iou_3d(corners, raw, up_to_scale=True))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of panoramas with label_cor .txt")
    args = parser.parse_args(argv)
    run = jax.jit(branch_layouts)
    chosen = {"auto": [], "agreement": [], "better by the label": []}
    print("| image | auto | " + " | ".join(f"{b}: 3D IoU (agreement)" for b in BRANCHES) + " |")
    print("| --- | --- | " + " | ".join("---" for _ in BRANCHES) + " |")
    for path, cam, label, (ceiling_v, floor_v, corner_prob) in labelled_rows(args.data, default_model()):
        rows = Rows(ceiling_v, floor_v, corner_prob)
        raw = raw_prediction_room(np.asarray(ceiling_v), np.asarray(floor_v), cam)
        layouts = [jax.device_get(layout) for layout in run(rows, cam)]
        with_files = _scored(layouts + [central_layout(ceiling_v, floor_v, corner_prob, cam)], cam, label)
        *ious, auto = with_files
        agreements = [agreement(layout, raw) for layout in layouts]
        chosen["auto"].append(auto)
        chosen["agreement"].append(ious[int(np.argmax(agreements))])
        chosen["better by the label"].append(max(ious))
        cells = " | ".join(f"{iou:.3f} ({agree:.3f})" for iou, agree in zip(ious, agreements, strict=True))
        print(f"| {path.stem} | {auto:.3f} | {cells} |", flush=True)
    print()
    for name, values in chosen.items():
        print(f"mean 3D IoU, {name}: {np.mean(values):.3f} ({len(values)} panoramas)")
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
