"""How well the layouts explain the network's rows on renders: where ``LOW_CONFIDENCE`` starts.

A layout's explained fraction (:attr:`ncjax.Layout.explained_fraction`) is the share of the usable
ceiling and floor rows it reprojects within the inlier threshold. On renders like the training images
the network's rows describe one room and the fraction is high; on a photograph unlike them (clutter,
doorways, textures) the rows wander and it drops. ``NETWORK_PIPELINE_CONFIG.min_explained_fraction``
flags the layouts below it. This script prints, on the tuning renders (seeds 71 and 72, the shipped
model, 4 views, world auto, the network's configuration without the flag), the fraction's quantiles,
the share of layouts each candidate threshold would flag and their up-to-scale 3D IoU against the rest.
The real side is ``benchmarks/central_layouts.py --data DIR``, which prints each photograph's status
and explained fraction and the mean 3D IoU per status.

    uv run python experiments/confidence.py [--rooms 64]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.pipeline.run import layout_from_evidence
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

sys.path.insert(0, str(Path(__file__).parent))
from network_table import scores
from tune_network_pipeline import tuning_boundaries

THRESHOLDS = (0.5, 0.6, 0.7, 0.75, 0.8)


def explained_and_iou(data: dict, config: ncjax.PipelineConfig) -> tuple[np.ndarray, np.ndarray]:
    """Per render: the layout's explained fraction and its up-to-scale 3D IoU (NaN without a layout)."""
    width = data["ceiling_v"].shape[1]

    def one(ceiling_v, floor_v, corner_prob, rc, key):
        cam = ncjax.NonCentralPanorama(width, width // 2, rc=rc)
        return layout_from_evidence(ceiling_v, floor_v, corner_prob, cam, key, "auto", config)

    keys = jax.random.split(jax.random.key(0), len(data["rc"]))
    layouts = jax.device_get(
        jax.jit(jax.vmap(one))(data["ceiling_v"], data["floor_v"], data["corner_prob"], data["rc"], keys)
    )
    per_room = scores([jax.tree.map(lambda x: x[i], layouts) for i in range(len(data["rc"]))], data["truth"])
    iou = np.array([room.get("iou3d_up_to_scale", np.nan) for room in per_room])
    return np.asarray(layouts.explained_fraction), iou


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=64, help="tuning renders per world")
    parser.add_argument("--out", type=Path, default=Path("experiments/out"))
    args = parser.parse_args(argv)
    config = dataclasses.replace(NETWORK_PIPELINE_CONFIG, min_explained_fraction=0.0)
    explained, iou = [], []
    for world in ("manhattan", "atlanta"):
        data = tuning_boundaries(world, args.rooms, 4, args.out)
        e, i = explained_and_iou(data, config)
        explained.append(e)
        iou.append(i)
    explained, iou = np.concatenate(explained), np.concatenate(iou)
    quantiles = np.quantile(explained, [0.0, 0.01, 0.05, 0.5])
    print(
        f"tuning renders ({len(explained)}), explained fraction: min {quantiles[0]:.3f}, 1% {quantiles[1]:.3f}, "
        f"5% {quantiles[2]:.3f}, median {quantiles[3]:.3f}"
    )
    print("| threshold | flagged | their 3D IoU (up to scale) | the others' |")
    print("| --- | --- | --- | --- |")
    for threshold in THRESHOLDS:
        low = explained < threshold
        flagged = f"{np.nanmean(iou[low]):.3f}" if low.any() else "-"
        print(f"| {threshold} | {low.sum()} ({100 * low.mean():.1f}%) | {flagged} | {np.nanmean(iou[~low]):.3f} |")
    print(f"in use: min_explained_fraction = {NETWORK_PIPELINE_CONFIG.min_explained_fraction}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
