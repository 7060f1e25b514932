"""Choose ``NETWORK_PIPELINE_CONFIG`` on tuning renders.

The pipeline's corner and occlusion settings for the shipped model.

Tuning set: Manhattan and Atlanta rooms rendered by ``ncjax synth`` with seeds 71
(Manhattan) and 72 (Atlanta), the same generator settings as the test renders of
``network_table.py`` (seeds 99 and 98) and none of the training seeds (11-14), so
the test renders are never used to choose the configuration. The shipped model's
boundaries (snapped, ``--views`` views) are computed once and cached in
``experiments/out/tune_<world>_<rooms>_views<V>_<model>_<hash>.npz``; each configuration then runs the
pipeline alone (``layout_of``, each room with its own world, or with ``--world auto``
every room with world auto, as ``ncjax reconstruct`` runs: to choose ``manhattan_margin``). ``--model``
runs another model's boundaries through the same configurations (cached under its
file's name and content hash), to compare a new model with the shipped one before it replaces it.

Per configuration and world, as ``network_table.py`` scores it (a failure is a
layout that is not ok or has the wrong corner count): failures, mean and median
CE and 3D IoU of the other rooms, on the rooms without occlusion and on all
rooms, and the 3D IoU over all rooms with failures as 0 ("IoU all0"), which
rewards both more layouts and better ones: the configuration is chosen by it,
and "returned, IoU all rooms": the ok layouts whatever their corner count, and
their 3D IoU over all rooms with no layout as 0.
Then the failures by cause: a layout status other than OK, or too few or too
many corners. Last, the scale test (``max_height_uncertainty``): on the layouts
of the configuration without it, how many ok layouts each threshold would fail
and how far off they were (a failure rate cannot choose it: it only adds failures).

    uv run python experiments/tune_network_pipeline.py                  # 256 rooms per world
    uv run python experiments/tune_network_pipeline.py --rooms 16 --configs current
    uv run python experiments/tune_network_pipeline.py --configs current --model my_model.safetensors
    uv run python experiments/tune_network_pipeline.py --world auto                     # the margins
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.network.predict import DEFAULT_VIEWS
from ncjax.pipeline.run import layout_of
from ncjax.pipeline.types import Rows
from ncjax.pipeline.uncertainty import room_height_sigma
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import (
    OUT,
    TUNING_SEEDS,
    failure_causes,
    layout_scores,
    model_suffix,
    network_config,
    network_setting,
    scores_summary,
    tuning_boundaries,
)

# the corner detection (threshold, NMS half-width in columns) and occlusion test (jump in px) settings compared,
# each replacing those of NETWORK_PIPELINE_CONFIG (the rest, e.g. the adjustment's row weights, as it is)
NO_SCALE_TEST = "nms 4, occlusion 8, threshold 0.4, no scale test"
CONFIGS = {
    "pipeline defaults": {"corner_threshold": 0.3, "nms_radius": 2.0, "occlusion_threshold": 4.0},
    "nms 2, occlusion 6": {"corner_threshold": 0.3, "nms_radius": 2.0, "occlusion_threshold": 6.0},
    "nms 3": {"corner_threshold": 0.3, "nms_radius": 3.0, "occlusion_threshold": 6.0},
    "nms 4": {"corner_threshold": 0.3, "nms_radius": 4.0, "occlusion_threshold": 6.0},
    "nms 4, occlusion 8": {"corner_threshold": 0.3, "nms_radius": 4.0, "occlusion_threshold": 8.0},
    "nms 4, occlusion 8, threshold 0.4": {"corner_threshold": 0.4, "nms_radius": 4.0, "occlusion_threshold": 8.0},
    "nms 3, occlusion 8, threshold 0.4": {"corner_threshold": 0.4, "nms_radius": 3.0, "occlusion_threshold": 8.0},
    # the ceiling and floor rows weighted alike in the joint solvers and the adjustment (the paper's weighting)
    "nms 4, occlusion 8, threshold 0.4, equal row weights": {
        "corner_threshold": 0.4,
        "nms_radius": 4.0,
        "occlusion_threshold": 8.0,
        "min_boundary_noise": 1e9,
    },
    # a Manhattan labelling whose corner types weigh as much as the walls' directions
    # (the default 0.02: the directions decide)
    "nms 4, occlusion 8, threshold 0.4, turn weight 0.5": {
        "corner_threshold": 0.4,
        "nms_radius": 4.0,
        "occlusion_threshold": 8.0,
        "turn_weight": 0.5,
    },
    # Atlanta: no wall inserted where a corner's walls meet far from its peak, or other offsets
    **{
        f"nms 4, occlusion 8, threshold 0.4, corner offset {offset:g}": {
            "corner_threshold": 0.4,
            "nms_radius": 4.0,
            "occlusion_threshold": 8.0,
            "max_corner_offset": offset,
        }
        for offset in (16.0, 64.0, 1e6)
    },
    # no layout fails for an uncertain scale: the scale test's thresholds are compared on its layouts
    NO_SCALE_TEST: {
        "corner_threshold": 0.4,
        "nms_radius": 4.0,
        "occlusion_threshold": 8.0,
        "max_height_uncertainty": math.inf,
    },
}
# world auto (--world auto, where they are the default configurations): the Atlanta layout kept only where it
# explains this much more of the rows (PipelineConfig.manhattan_margin)
MARGIN_CONFIGS = {
    f"margin {margin:g}": {
        "corner_threshold": 0.4,
        "nms_radius": 4.0,
        "occlusion_threshold": 8.0,
        "manhattan_margin": margin,
    }
    for margin in (0.0, 0.05, 0.1, 0.15, 0.2, 0.3)
}
# relative standard deviations of the room height compared as PipelineConfig.max_height_uncertainty
SCALE_TEST_THRESHOLDS = (0.04, 0.06, 0.08, 0.1, 0.15, 0.2, math.inf)


def row_errors(data: dict) -> str:
    """The network's rows against the true ones, per boundary: mean / median |error| (px) and the share within 1 px."""
    parts = []
    for name, predicted, true in zip(
        ("ceiling", "floor"), (data["ceiling_v"], data["floor_v"]), data["true_rows"], strict=False
    ):
        error = np.abs(predicted - true)  # a missing row (NaN) counts as not within 1 px
        parts.append(
            f"{name} {np.nanmean(error):.2f} / {np.nanmedian(error):.2f} px, {100 * np.mean(error < 1):.0f}% within "
            "1 px"
        )
    return "; ".join(parts)


def pipeline_scores(data: dict, world: str, config: ncjax.PipelineConfig) -> list[dict]:
    width = data["ceiling_v"].shape[1]

    def one(ceiling_v, floor_v, corner_prob, rc, key):
        cam = ncjax.NonCentralPanorama(width, width // 2, rc=rc)
        return layout_of(Rows(ceiling_v, floor_v, corner_prob), cam, None, key, config, world)

    keys = jax.random.split(jax.random.key(0), len(data["rc"]))
    layouts = jax.device_get(
        jax.jit(jax.vmap(one))(data["ceiling_v"], data["floor_v"], data["corner_prob"], data["rc"], keys)
    )
    per_room = layout_scores([jax.tree.map(lambda x: x[i], layouts) for i in range(len(data["rc"]))], data["truth"])
    relative_sigma = np.asarray(room_height_sigma(layouts.height_covariance)) / (
        layouts.ceiling_height - layouts.floor_height
    )
    return [
        room | {"relative_height_sigma": float(sigma)} for room, sigma in zip(per_room, relative_sigma, strict=False)
    ]


def plot_scale_test(per_room: dict[str, list[dict]], path: Path, threshold: float) -> None:
    """Corner error against the relative room-height sigma of the ok layouts, per world, with the shipped threshold."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, len(per_room), figsize=(5.5 * len(per_room), 4.5), squeeze=False)
    for ax, (world, rooms) in zip(axes[0], per_room.items(), strict=False):
        good = [r for r in rooms if not r["failed"]]
        # infinite sigma (a wall the rows leave free) drawn at the right edge
        sigma = np.array(
            [1.0 if math.isnan(r["relative_height_sigma"]) else min(r["relative_height_sigma"], 1.0) for r in good]
        )
        ce = np.array([r["ce"] for r in good])
        ax.scatter(sigma, ce, s=12, alpha=0.6, c=np.where(sigma > threshold, "tab:red", "tab:blue"))
        ax.axvline(
            threshold, color="black", linestyle="--", linewidth=1, label=f"max_height_uncertainty = {threshold:g}"
        )
        ax.axhline(0.3, color="0.6", linewidth=1, label="CE 0.3 m")
        ax.set(
            xscale="log",
            yscale="log",
            xlabel="room height sigma / room height (1: infinite)",
            ylabel="corner error (m)",
            title=f"{world}: {len(good)} ok layouts, tuning renders",
        )
        ax.legend(fontsize=8, loc="upper left")
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def scale_test_table(per_room: dict[str, list[dict]]) -> list[str]:
    """Per threshold of the relative height sigma: how many ok layouts it fails and how wrong they were.

    Args:
        per_room: world -> the per-room scores of a configuration without the scale test.
    """
    lines = [
        "",
        "Scale test (`max_height_uncertainty`) on the layouts of the configuration without it, per world: "
        "the ok layouts it would fail (% of all rooms), their CE median (m) and the share of them with CE > 0.3 m; "
        "then the CE mean / median (m) of the layouts it keeps.",
        "",
        "| threshold | world | failed by the test (%) | their CE median | CE > 0.3 m (%) | kept: CE mean / median |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for threshold in SCALE_TEST_THRESHOLDS:
        for world, rooms in per_room.items():
            good = [r for r in rooms if not r["failed"]]
            ce = np.array([r["ce"] for r in good])
            flagged = np.array([not r["relative_height_sigma"] <= threshold for r in good])
            share = 100 * np.mean(ce[flagged] > 0.3) if flagged.any() else math.nan
            lines.append(
                f"| {threshold:g} | {world} | {100 * flagged.sum() / len(rooms):.1f} | "
                f"{np.median(ce[flagged]) if flagged.any() else math.nan:.3f} | {share:.0f} | "
                f"{ce[~flagged].mean():.3f} / {np.median(ce[~flagged]):.3f} |"
            )
    return lines


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=256, help="tuning renders per world")
    parser.add_argument("--views", type=int, default=DEFAULT_VIEWS)
    parser.add_argument(
        "--configs",
        nargs="+",
        choices=[*CONFIGS, *MARGIN_CONFIGS, "current"],
        help="configurations to compare ('current': NETWORK_PIPELINE_CONFIG; default: all, or with --world auto the "
        "margins)",
    )
    parser.add_argument("--model", type=Path, help="weights (.safetensors) to run instead of the shipped model")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--world", choices=("own", "auto"), default="own", help="each room's own world (default), or auto for all"
    )
    args = parser.parse_args(argv)
    if args.configs is None:
        args.configs = [*(CONFIGS if args.world == "own" else MARGIN_CONFIGS), "current"]
    if args.model is not None and not args.model.is_file():
        parser.error(f"--model: no such file: {args.model}")
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    data = {world: tuning_boundaries(world, args.rooms, args.views, args.out, args.model) for world in TUNING_SEEDS}
    model = "the shipped model" if args.model is None else f"model {args.model.name}"
    suffix = model_suffix(args.model)  # names this run's table and plot
    lines = [
        f"Tuning renders: {args.rooms} per world (seeds {TUNING_SEEDS}), {model}, {args.views} view(s), snapped rows, "
        f"world: {'each room its own' if args.world == 'own' else 'auto'}.",
        "",
        *(f"- rows, {world}: {row_errors(data[world])}" for world in TUNING_SEEDS),
        "",
        "| configuration | world | no occlusion: failed (%) / CE mean / median (m) / 3D IoU (%) | all: failed (%) / "
        "CE (m) / 3D IoU (%) "
        "| IoU all0 (%) | returned (%), IoU all rooms (%) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    causes = ["", "Failures by cause, all rooms (% of the rooms):", ""]
    record, unscaled = {}, {}
    for name in tqdm(args.configs, desc="configurations"):
        kwargs = (
            {key: network_setting(key) for key in CONFIGS["pipeline defaults"]}
            if name == "current"
            else (CONFIGS | MARGIN_CONFIGS)[name]
        )
        config = network_config(**kwargs)
        for world in TUNING_SEEDS:
            per_room = pipeline_scores(data[world], world if args.world == "own" else "auto", config)
            clear = [r for r, keep in zip(per_room, data[world]["clear"], strict=False) if keep]
            s_clear, s_all = scores_summary(clear), scores_summary(per_room)
            median = np.median([r["ce"] for r in clear if not r["failed"]] or [np.nan])
            record[(name, world)] = s_all
            lines.append(
                f"| {name} {kwargs} | {world} | {s_clear['failed']:.1f} / {s_clear['ce']:.3f} / {median:.3f} / "
                f"{s_clear['iou3d']:.1f} | "
                f"{s_all['failed']:.1f} / {s_all['ce']:.3f} / {s_all['iou3d']:.1f} | {s_all['iou3d_all']:.1f} | "
                f"{s_all['returned']:.1f}, {s_all['iou3d_all_returned']:.1f} |"
            )
            causes.append(f"- {name}, {world}: {failure_causes(per_room)}")
            if name == NO_SCALE_TEST:
                unscaled[world] = per_room
    table = "\n".join(lines + causes + (scale_test_table(unscaled) if unscaled else []))
    mode = "" if args.world == "own" else "_auto"
    if unscaled:
        path = args.out / f"scale_test{mode}{suffix}.png"
        plot_scale_test(unscaled, path, NETWORK_PIPELINE_CONFIG.checks.max_height_uncertainty)
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    (args.out / f"tune_network_pipeline_{args.rooms}{mode}{suffix}.md").write_text(table + "\n")
    return record


if __name__ == "__main__":
    main()
