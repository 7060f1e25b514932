"""How well the layouts explain the network's rows on renders: where ``LOW_CONFIDENCE`` starts.

A layout's explained fraction (:attr:`ncjax.Layout.explained_fraction`) is the share of the usable
ceiling and floor rows it reprojects within the inlier threshold. On renders like the training images
the network's rows describe one room and the fraction is high; on a photograph unlike them (clutter,
doorways, textures) the rows wander and it drops. ``NETWORK_PIPELINE_CONFIG.checks.min_explained_fraction``
flags the layouts below it. This script prints, on the tuning renders (seeds 71 and 72, the shipped
model, 4 views, world auto, the network's configuration without the flag), the fraction's quantiles,
the share of layouts each candidate threshold would flag and their up-to-scale 3D IoU against the rest.
The real side is ``benchmarks/central_layouts.py --data DIR``, which prints each photograph's status
and explained fraction and the mean 3D IoU per status.

Then where ``SCALE_CONFLICT`` starts: a non-central layout whose geometry cannot fix its scale
(``UNCERTAIN_SCALE``) takes it from the height prior (``ncjax reconstruct``'s default camera height, 1.6 m;
the renders' cameras stand 1.0-1.8 m high), and is flagged where the height its parallax measured lies
more than ``max_scale_conflict`` standard deviations from the prior's
(:func:`ncjax.pipeline.prior.scale_conflict`). The script prints that distance's quantiles over every
render whose geometry measured a height (how often rows of one room reach it), each candidate
threshold's flags among the renders that fall back to the prior, and their layouts' 3D IoU.

Last, where the corner range check starts (``checks.max_corner_range_ratio``: a layout with a corner farther than
that many times the 95th percentile of its rows' ranges is ``DEGENERATE_LAYOUT``): per candidate ratio, the tuning
renders' layouts it alone fails, and their 3D IoU without it.

    uv run python experiments/confidence.py [--rooms 64]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.io.export import status_has_geometry
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior, scale_conflict
from ncjax.pipeline.run import layout_of
from ncjax.pipeline.types import LayoutStatus, Rows
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import layout_scores, tuning_boundaries

THRESHOLDS = (0.5, 0.6, 0.7, 0.75, 0.8)
CONFLICT_THRESHOLDS = (2.0, 2.5, 3.0, 4.0)
RANGE_RATIOS = (1.5, 2.0, 3.0)


def _layouts(data: dict, config: ncjax.PipelineConfig) -> ncjax.Layout:
    """The renders' layouts (world auto, no prior), ``config`` traced: one compilation for every setting."""
    width = data["ceiling_v"].shape[1]

    @jax.jit
    def run(rows, rc, keys, config):
        def one(ceiling_v, floor_v, corner_prob, rc, key):
            cam = ncjax.NonCentralPanorama(width, width // 2, rc=rc)
            return layout_of(Rows(ceiling_v, floor_v, corner_prob), cam, None, key, config, "auto")

        return jax.vmap(one)(*rows, rc, keys)

    keys = jax.random.split(jax.random.key(0), len(data["rc"]))
    rows = (data["ceiling_v"], data["floor_v"], data["corner_prob"])
    return jax.device_get(run(rows, data["rc"], keys, config))


def explained_and_iou(data: dict, layouts: ncjax.Layout) -> tuple[np.ndarray, np.ndarray]:
    """Per render: its layout's explained fraction and up-to-scale 3D IoU (NaN without a layout)."""
    per_room = layout_scores([jax.tree.map(lambda x: x[i], layouts) for i in range(len(data["rc"]))], data["truth"])
    iou = np.array([room.get("iou3d_up_to_scale", np.nan) for room in per_room])
    return np.asarray(layouts.explained_fraction), iou


def conflicts_and_ious(data: dict, config: ncjax.PipelineConfig) -> dict[str, np.ndarray]:
    """Per render: the geometry's status, its scale conflict with the default camera-height prior, and the
    metric and up-to-scale 3D IoU of the prior's layout (NaN without one)."""
    width = data["ceiling_v"].shape[1]
    cam = ncjax.NonCentralPanorama(width, width // 2, rc=jax.numpy.asarray(data["rc"]))
    rows = (data["ceiling_v"], data["floor_v"], data["corner_prob"])
    prior = HeightPrior("camera_height", np.full(len(data["rc"]), DEFAULT_CAMERA_HEIGHT))
    geometry = ncjax.layout_from_boundaries(*rows, cam, "auto", config)
    from_prior = ncjax.layout_from_boundaries(*rows, cam, "auto", config, prior=prior)
    conflict = np.asarray(jax.vmap(scale_conflict)(geometry, prior))
    per_room = layout_scores(
        [jax.tree.map(lambda x, i=i: x[i], from_prior) for i in range(len(data["rc"]))], data["truth"]
    )
    return {
        "status": np.asarray(geometry.status),
        "prior_ok": np.asarray(from_prior.ok),
        "measured": np.vectorize(status_has_geometry)(np.asarray(geometry.ok), np.asarray(geometry.status)),
        "conflict": conflict,
        "iou": np.array([room.get("iou3d", np.nan) for room in per_room]),
        "iou_up_to_scale": np.array([room.get("iou3d_up_to_scale", np.nan) for room in per_room]),
    }


def corner_range_failures(data: dict, config: ncjax.PipelineConfig, without: np.ndarray) -> np.ndarray:
    """Per :data:`RANGE_RATIOS` ratio and render: whether the corner range check alone fails its layout
    (``without``: the statuses without the check)."""
    failed = []
    for ratio in RANGE_RATIOS:
        status = _layouts(data, config.replace(checks={"max_corner_range_ratio": ratio})).status
        failed.append((status == LayoutStatus.DEGENERATE_LAYOUT) & (without != LayoutStatus.DEGENERATE_LAYOUT))
    return np.asarray(failed)


def mean_ious(found: dict[str, np.ndarray], mask: np.ndarray) -> str:
    """The mean metric / up-to-scale 3D IoU of the renders in ``mask``, as text ("-" for none)."""
    if not mask.any():
        return "-"
    return f"{np.nanmean(found['iou'][mask]):.3f} / {np.nanmean(found['iou_up_to_scale'][mask]):.3f}"


def print_conflicts(found: dict[str, np.ndarray], config: ncjax.PipelineConfig) -> None:
    """The scale conflict's quantiles, and per candidate ``max_scale_conflict`` the fallbacks it would flag."""
    measured, conflict = found["measured"], found["conflict"]
    quantiles = np.quantile(conflict[measured], [0.5, 0.9, 0.99, 1.0])
    print(
        f"renders whose geometry measured a height ({measured.sum()}), distance to the {DEFAULT_CAMERA_HEIGHT} m "
        f"prior in sigmas: median {quantiles[0]:.2f}, 90% {quantiles[1]:.2f}, 99% {quantiles[2]:.2f}, "
        f"max {quantiles[3]:.2f}"
    )
    # the layouts the flag can reach: an UNCERTAIN_SCALE geometry replaced by an OK layout at the prior's scale
    fallback = (found["status"] == LayoutStatus.UNCERTAIN_SCALE) & found["prior_ok"]
    print(f"UNCERTAIN_SCALE, written OK at the prior's scale: {fallback.sum()} renders, sigmas", end=" ")
    print(", ".join(f"{z:.2f}" for z in np.sort(conflict[fallback])))
    print("| max_scale_conflict | flagged of those | their 3D IoU, metric / up to scale | the others' | of all |")
    print("| --- | --- | --- | --- | --- |")
    for threshold in CONFLICT_THRESHOLDS:
        flagged = fallback & (conflict > threshold)
        share = np.mean(conflict[measured] > threshold)
        print(
            f"| {threshold} | {flagged.sum()} | {mean_ious(found, flagged)} | {mean_ious(found, fallback & ~flagged)} "
            f"| {100 * share:.1f}% |"
        )
    print(f"in use: max_scale_conflict = {config.prior.max_scale_conflict}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=64, help="tuning renders per world")
    parser.add_argument("--out", type=Path, default=Path("experiments/out"))
    args = parser.parse_args(argv)
    config = NETWORK_PIPELINE_CONFIG.replace(checks={"min_explained_fraction": 0.0})
    explained, iou, found, range_failures = [], [], [], []
    for world in ("manhattan", "atlanta"):
        data = tuning_boundaries(world, args.rooms, 4, args.out)
        unchecked = _layouts(data, config.replace(checks={"max_corner_range_ratio": np.inf}))
        e, i = explained_and_iou(data, unchecked)
        explained.append(e)
        iou.append(i)
        found.append(conflicts_and_ious(data, NETWORK_PIPELINE_CONFIG))
        range_failures.append(corner_range_failures(data, config, np.asarray(unchecked.status)))
    explained, iou = np.concatenate(explained), np.concatenate(iou)
    found = {key: np.concatenate([part[key] for part in found]) for key in found[0]}
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
    print(f"in use: min_explained_fraction = {NETWORK_PIPELINE_CONFIG.checks.min_explained_fraction}")
    print_conflicts(found, NETWORK_PIPELINE_CONFIG)
    failures = np.concatenate(range_failures, axis=1)
    print(f"layouts that fail only by the corner range check (DEGENERATE_LAYOUT), of {failures.shape[1]}:")
    print("| max_corner_range_ratio | failed | their 3D IoU without it (up to scale) |")
    print("| --- | --- | --- |")
    for ratio, failed in zip(RANGE_RATIOS, failures, strict=True):
        their = f"{np.nanmean(iou[failed]):.3f}" if failed.any() else "-"
        print(f"| {ratio} | {failed.sum()} | {their} |")
    print(f"in use: max_corner_range_ratio = {NETWORK_PIPELINE_CONFIG.checks.max_corner_range_ratio}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
