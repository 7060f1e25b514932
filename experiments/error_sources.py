"""Where the end-to-end error comes from: the network's outputs swapped one by one for the truth.

On the test renders of ``network_table.py`` (128 Manhattan + 128 Atlanta rooms,
never seen in training), the full pipeline runs on five inputs:

* ``network``: the network's ceiling rows, floor rows and corner probability;
* ``true corners``: the network's rows, the exact corner target;
* ``true ceiling`` / ``true floor``: as ``true corners`` with one of the two
  boundaries exact as well;
* ``exact``: every input exact (the pipeline's own limit on these rooms).

The network's rows are snapped to the image's edges unless ``--no-edge-snap``, and
the pipeline runs with ``reconstruct``'s configuration (``NETWORK_PIPELINE_CONFIG``).

Per row: layout statuses, the failure rate of ``network_table.py`` (not ok, or a
corner count that differs from the ground truth), mean and median CE of the
other rooms, 3D IoU over the ok layouts and with failures as 0, the up-to-scale
3D IoU, and the scale error (median and 90th percentile of
``|log(room height / true room height)|`` over the ok layouts, and the median of the
signed log: below 0, the rooms come out too small). Then, for the network's
input, the mean 3D IoU of the ok layouts per bin of ``Layout.explained_fraction``. Last,
whether ``Layout.corner_covariance`` and ``Layout.height_covariance`` are calibrated: the
share of matched corners inside their 95% ellipse and of room heights within 1.96
standard deviations of the truth (95% if calibrated).

    uv run python experiments/error_sources.py                 # 128 rooms per world, 4 views
    uv run python experiments/error_sources.py --rooms 16 --views 1
    uv run python experiments/error_sources.py --branch auto   # world="auto", the reconstruct default
"""

from __future__ import annotations

import argparse
import collections
import math
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.cli.reconstruct import add_boundary_arguments
from ncjax.evaluation import layout_metrics as metrics
from ncjax.io.export import layout_height_sigma
from ncjax.network.checkpoint import load_model
from ncjax.network.predict import default_model
from ncjax.pipeline.types import LayoutStatus
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG
from ncjax.synth.dataset import list_samples, read_sample
from ncjax.synth.labels import corner_target

from common import BATCH, OUT, TEST_SEEDS, compiled, corner_calibration, ground_truth, test_renders

SOURCES = ("network", "true corners", "true ceiling", "true floor", "exact")
EXPLAINED_BINS = (0.6, 0.8, 0.9)  # Layout.explained_fraction bins of the quality check


def network_outputs(samples, views: int, model, edge_snap) -> dict[str, np.ndarray]:
    """The network's rows and corner probability, and the exact ones, of the samples."""
    predicted = []
    for start in tqdm(range(0, len(samples), BATCH), desc="network"):
        images = np.stack([s.image for s in samples[start : start + BATCH]])
        predicted.append(ncjax.predict_boundaries(images, model, views=views, edge_snap=edge_snap))
    ceiling_v, floor_v, corner_prob = (np.concatenate(parts) for parts in zip(*predicted, strict=False))
    width = samples[0].image.shape[1]
    return {
        "ceiling_v": ceiling_v,
        "floor_v": floor_v,
        "corner_prob": corner_prob,
        "true_ceiling_v": np.stack([s.metadata["ceiling_v"] for s in samples]).astype(np.float32),
        "true_floor_v": np.stack([s.metadata["floor_v"] for s in samples]).astype(np.float32),
        "true_corner_prob": np.stack(
            [
                np.asarray(
                    corner_target(
                        np.asarray(s.metadata["corner_u"], np.float32),
                        np.ones(len(s.metadata["corner_u"]), bool),
                        width,
                    )
                )
                for s in samples
            ]
        ).astype(np.float32),
    }


def inputs_of(outputs: dict[str, np.ndarray], source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ceiling = outputs["true_ceiling_v" if source in ("true ceiling", "exact") else "ceiling_v"]
    floor = outputs["true_floor_v" if source in ("true floor", "exact") else "floor_v"]
    corners = outputs["corner_prob" if source == "network" else "true_corner_prob"]
    return ceiling, floor, corners


def row(samples, layouts, truths) -> dict:
    statuses = collections.Counter()
    ce, iou_ok, iou_all, iou_u2s, scale = [], [], [], [], []
    by_explained = collections.defaultdict(list)  # 3D IoU of the ok layouts per explained-fraction bin
    in_ellipse, corner_sigma, corner_miss, height_within = [], [], [], []  # calibration of Layout's covariances
    for index, truth in enumerate(truths):
        layout = jax.tree.map(lambda x: np.asarray(x[index]), layouts)
        statuses[LayoutStatus(int(layout.status)).name] += 1
        if not bool(layout.ok):
            iou_all.append(0.0)
            continue
        result = metrics.evaluate_layout(layout, truth)
        true_height = truth["ceiling_corners"][0][2] - truth["floor_corners"][0][2]
        height = float(layout.ceiling_height) - float(layout.floor_height)
        scale.append(math.log(height / true_height))
        height_within.append(abs(height - true_height) <= 1.96 * layout_height_sigma(layout))
        _, shift = metrics.corner_error(layout, truth)
        if shift is not None:
            inside, sigma, miss = corner_calibration(layout, truth, shift)
            in_ellipse.extend(inside)
            corner_sigma.extend(sigma)
            corner_miss.extend(miss)
        iou_ok.append(result["iou3d"])
        by_explained[np.searchsorted(EXPLAINED_BINS, float(layout.explained_fraction), side="right")].append(
            result["iou3d"]
        )
        iou_u2s.append(result["iou3d_up_to_scale"])
        iou_all.append(result["iou3d"])
        if math.isfinite(result["ce"]):
            ce.append(result["ce"])
    return {
        "statuses": dict(statuses),
        "failed": 100.0 * (1 - len(ce) / len(truths)),
        "ce_mean": float(np.mean(ce)) if ce else math.nan,
        "ce_median": float(np.median(ce)) if ce else math.nan,
        "iou_ok": 100 * float(np.mean(iou_ok)) if iou_ok else math.nan,
        "iou_all": 100 * float(np.mean(iou_all)),
        "iou_u2s": 100 * float(np.mean(iou_u2s)) if iou_u2s else math.nan,
        "scale_median": float(np.median(np.abs(scale))) if scale else math.nan,
        "scale_p90": float(np.quantile(np.abs(scale), 0.9)) if scale else math.nan,
        "scale_bias": float(np.median(scale)) if scale else math.nan,
        "in_ellipse": 100 * float(np.mean(in_ellipse)) if in_ellipse else math.nan,
        "sigma_median": float(np.median(corner_sigma)) if corner_sigma else math.nan,
        "miss_median": float(np.median(corner_miss)) if corner_miss else math.nan,
        "height_within": 100 * float(np.mean(height_within)) if height_within else math.nan,
        "rank_correlation": rank_correlation(corner_sigma, corner_miss),
        "iou_by_explained": ", ".join(
            f"{_bin_name(b)}: {100 * np.mean(by_explained[b]):.1f}% ({len(by_explained[b])})"
            for b in sorted(by_explained)
        ),
    }


def rank_correlation(x, y) -> float:
    """Spearman's rank correlation (ties broken by order): does a larger sigma go with a larger error?"""
    if len(x) < 3:
        return math.nan
    ranks = [np.argsort(np.argsort(np.asarray(v, np.float64))) for v in (x, y)]
    return float(np.corrcoef(*ranks)[0, 1])


def _bin_name(index: int) -> str:
    edges = [0.0, *EXPLAINED_BINS, 1.0]
    return f"{edges[index]:.1f}-{edges[index + 1]:.1f}"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=128, help="test renders per world (those of network_table.py)")
    add_boundary_arguments(parser)
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--model", help="weights (.safetensors); default: the shipped model")
    parser.add_argument(
        "--branch",
        choices=("own", "auto"),
        default="own",
        help="pipeline world: each test set's own (default) or auto (ncjax reconstruct's default)",
    )
    args = parser.parse_args(argv)
    start = time.time()
    lines = [
        f"Network output averaged over {args.views} view(s); {args.rooms} rooms per world; pipeline world: "
        f"{args.branch}; "
        f"rows snapped to the image's edges: {args.edge_snap is not None}.",
        "",
        "| world | input | ok | failed (%) | CE mean (m) | CE median (m) | 3D IoU ok (%) | 3D IoU all (%) | "
        "up-to-scale IoU (%) | scale error median / p90 | signed scale error median |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    quality, calibration = [], []
    for world in TEST_SEEDS:
        folder = str(test_renders(world, args.rooms, args.out))
        samples = [read_sample(folder, name) for name in list_samples(folder)]
        truths = [ground_truth(s, world) for s in samples]
        outputs = network_outputs(
            samples, args.views, load_model(args.model) if args.model else default_model(), args.edge_snap
        )
        height, width = samples[0].image.shape[:2]
        cams = jax.vmap(lambda rc: ncjax.NonCentralPanorama(width, height, rc=rc))(
            np.array([s.rc for s in samples], np.float32)
        )
        keys = jax.random.split(jax.random.key(0), len(samples))
        branch = world if args.branch == "own" else "auto"
        for source in tqdm(SOURCES, desc=f"pipeline {world}"):
            layouts = jax.device_get(
                compiled("pipeline", branch, NETWORK_PIPELINE_CONFIG)(*inputs_of(outputs, source), cams, keys)
            )
            r = row(samples, layouts, truths)
            lines.append(
                f"| {world} | {source} | {r['statuses'].get('OK', 0)} / {len(samples)} | {r['failed']:.1f} | "
                f"{r['ce_mean']:.3f} | "
                f"{r['ce_median']:.3f} | {r['iou_ok']:.1f} | {r['iou_all']:.1f} | {r['iou_u2s']:.1f} | "
                f"{r['scale_median']:.3f} / {r['scale_p90']:.3f} | {r['scale_bias']:+.3f} |"
            )
            calibration.append(
                f"| {world} | {source} | {r['in_ellipse']:.1f} | {r['sigma_median']:.3f} | {r['miss_median']:.3f} | "
                f"{r['rank_correlation']:.2f} | {r['height_within']:.1f} |"
            )
            if source == "network":
                quality.append(
                    f"- {world}: 3D IoU of the ok layouts by explained fraction (rooms): {r['iou_by_explained']}"
                )
    table = "\n".join(
        lines
        + ["", "Is `Layout.explained_fraction` a quality indicator? Network input:", *quality]
        + [
            "",
            "Are the layouts' covariances calibrated? (rooms with the true corner count; 95% expected)",
            "",
            "| world | input | corners in their 95% ellipse (%) | corner sigma median (m) | corner error median (m) | "
            "rank correlation sigma / error | room heights within 1.96 sigma (%) |",
            "| --- | --- | --- | --- | --- | --- | --- |",
            *calibration,
        ]
    )
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"error_sources_views{args.views}_{args.branch}{'' if args.edge_snap else '_no_snap'}.md").write_text(
        table + "\n"
    )


if __name__ == "__main__":
    main()
