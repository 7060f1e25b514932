"""Table netcorExp (the network) and the "Network predictions" tables (pipeExp, comparison) on fixed test renders.

Test set: Manhattan and Atlanta rooms rendered by ``ncjax synth`` at 512 x 1024
with seeds 99 (Manhattan) and 98 (Atlanta); the shipped models were trained on
seeds 11-14, 21-22 and 31-33, so none of these rooms, scenes or images was seen in training.
They are rendered once into ``experiments/out/test_renders_<world>/`` and reused.

1. Table netcorExp: boundary pixel error (PE, in pixels of a 1024-wide image)
   mean and std over images, corner precision / recall / accuracy / IoU with
   the probability and the ``0.96**d`` target binarised at 0.5
   (:mod:`ncjax.evaluation.network_metrics`).
2. Table pipeExp, "Network predictions": the network's boundaries through the
   paper's "Solvers" route and through the full pipeline
   (``ncjax.reconstruct_batch``), CE and 3D IoU, Manhattan and Atlanta, on the
   rooms without occlusion (as the paper) and on all rooms.
3. Table comparison, ncjax rows: 3D IoU, up-to-scale 3D IoU, CEN, CE.

Ground truth: for Manhattan the true room (the pipeline recovers the hidden
wall at an occlusion), for Atlanta the visible layout (its inserted walls lie
in the corner rays' planes). A layout that is not ok, or whose corner count
differs from the ground truth, is a failure: CE and CEN are averaged over the
other rooms, IoU over all rooms with failures counted as 0 ("IoU, all") and
over the successes.

CE needs the corner counts to match, but 3D IoU does not: a layout that merges
a jog of a few centimetres into one wall is still a usable room. A fourth
table ("every layout returned") therefore scores every ok layout whatever its
corner count: the share of rooms that get one, its 3D IoU, and the IoU over
all rooms with 0 where no layout was returned. Its last columns also score the
layouts flagged UNCERTAIN_SCALE, whose geometry ``ncjax reconstruct`` writes
with the flag: their share and 3D IoU, and the IoU over all rooms with them.

    uv run python experiments/network_table.py                # 128 rooms per world
    uv run python experiments/network_table.py --small        # 8 rooms per world
    uv run python experiments/network_table.py --network-only --model FILE   # a model's test-render row (minutes)
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.cli.reconstruct import add_boundary_arguments
from ncjax.network.checkpoint import load_model
from ncjax.network.predict import DEFAULT_VIEWS, default_model
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG
from ncjax.synth.dataset import list_samples, read_sample
from ncjax.training.data import evaluate_arrays, load_split

from common import (
    OUT,
    TEST_SEEDS,
    compiled,
    failure_causes,
    ground_truth,
    layout_scores,
    layouts_of,
    scores_summary,
    test_renders,
    used_row_errors,
)

PAPER = {
    "netcorExp": {
        "precision": 0.934,
        "recall": 0.962,
        "accuracy": 0.986,
        "iou": 0.901,
        "pe_mean": 1.167,
        "pe_std": 0.490,
    },
    "pipeExp": {
        ("solvers", "manhattan"): (0.5569, 81.7364),
        ("solvers", "atlanta"): (1.2860, 42.6701),
        ("pipeline", "manhattan"): (0.2109, 86.8104),
        ("pipeline", "atlanta"): (0.4811, 76.0218),
    },
    "comparison": {"manhattan": (93.87, 86.16, 0.78, 0.223), "atlanta": (90.46, 76.02, 1.5, 0.481)},
}


def solver_layouts(samples, boundaries, world: str):
    """The paper's "Solvers" route on the network's boundaries."""
    width, height = samples[0].image.shape[1], samples[0].image.shape[0]
    rows = [np.stack(parts) for parts in zip(*boundaries, strict=False)]
    radii = np.array([s.rc for s in samples], np.float32)
    cams = jax.vmap(lambda rc: ncjax.NonCentralPanorama(width, height, rc=rc))(radii)
    keys = jax.random.split(jax.random.key(0), len(samples))
    result = jax.device_get(compiled("solvers", world)(*rows, cams, keys))
    return [jax.tree.map(lambda x: x[i], result) for i in range(len(samples))]


# bins of the narrowest wall's width, in columns of a 1024-wide panorama (16 columns: 5.6 degrees)
WIDTH_BINS = ((0, 16), (16, 32), (32, math.inf))


def narrowest_wall(sample) -> float:
    """The angular width of the room's narrowest visible wall, in columns of a 1024-wide panorama."""
    width = sample.image.shape[1]
    corners = np.sort(np.asarray(sample.metadata["corner_u"], np.float64) % width)
    gaps = np.diff(np.concatenate([corners, corners[:1] + width]))
    return float(gaps.min() * 1024 / width)


def by_narrowest_wall(per_room: list[dict], narrowest: np.ndarray) -> list[dict]:
    """Per bin of WIDTH_BINS: the summary of the rooms whose narrowest wall falls in it."""
    out = []
    for low, high in WIDTH_BINS:
        keep = (narrowest >= low) & (narrowest < high)
        rooms = [r for r, k in zip(per_room, keep, strict=False) if k]
        out.append(
            {
                "low": low,
                "high": high if math.isfinite(high) else None,
                **(scores_summary(rooms) if rooms else {"rooms": 0}),
            }
        )
    return out


def network_lines(model, evaluated: list[tuple[str, dict]], view_counts: list[int], record: dict) -> list[str]:
    """Table netcorExp: a row per test set and view count, each also put in ``record``; the paper's row last."""
    lines = [
        "### Table netcorExp (network)",
        "",
        "| test set | views | images | precision | recall | accuracy | IoU | PE mean (px) | PE std (px) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, data in evaluated:
        for views in view_counts:
            row = evaluate_arrays(model, data, views=views)
            record[f"network_{name}" + ("" if views == 1 else f"_views{views}")] = row
            lines.append(
                f"| {name} | {views} | {len(data['image'])} | {row['precision']:.3f} | {row['recall']:.3f} | "
                f"{row['accuracy']:.3f} | {row['iou']:.3f} | {row['pe_mean']:.3f} | {row['pe_std']:.3f} |"
            )
    p = PAPER["netcorExp"]
    lines.append(
        f"| paper (its test set) | 1 | 499 | {p['precision']} | {p['recall']} | {p['accuracy']} | {p['iou']} | "
        f"{p['pe_mean']} | {p['pe_std']} |"
    )
    return lines


def miscounted_layouts(per_room: list[dict]) -> str:
    """How good the returned layouts with too few or too many corners are: count and 3D IoU mean / median (%)."""
    parts = []
    for name, sign in (("too few corners", -1), ("too many corners", 1)):
        iou = [r["iou3d"] for r in per_room if r["returned"] and np.sign(r["corners"] - r["true_corners"]) == sign]
        parts.append(
            f"{name} {len(iou)} rooms"
            + (f", 3D IoU {100 * np.mean(iou):.1f} / {100 * np.median(iou):.1f}%" if iou else "")
        )
    return "; ".join(parts)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=128, help="test renders per world")
    parser.add_argument("--small", action="store_true", help="8 rooms per world")
    parser.add_argument("--model", help="weights (.safetensors); default: the shipped model")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--corner-threshold", type=float, default=NETWORK_PIPELINE_CONFIG.corners.threshold)
    parser.add_argument(
        "--nms-radius", type=float, default=NETWORK_PIPELINE_CONFIG.corners.nms_radius, help="columns at 1024"
    )
    parser.add_argument(
        "--occlusion-threshold", type=float, default=NETWORK_PIPELINE_CONFIG.occlusion.threshold, help="pixels"
    )
    parser.add_argument("--skip-network", action="store_true", help="only the layout tables")
    parser.add_argument(
        "--network-only",
        action="store_true",
        help="only Table netcorExp's row of all rooms at --views views, printed (the model card's test-render row)",
    )
    add_boundary_arguments(parser)
    args = parser.parse_args(argv)
    config = NETWORK_PIPELINE_CONFIG.replace(
        corners={"threshold": args.corner_threshold, "nms_radius": args.nms_radius},
        occlusion={"threshold": args.occlusion_threshold},
    )
    count = 8 if args.small else args.rooms
    model = load_model(args.model) if args.model else default_model()
    start = time.time()
    lines, record = [], {"rooms_per_world": count}

    arrays = {}
    for world in TEST_SEEDS:
        folder = str(test_renders(world, count, args.out))
        arrays[world] = load_split(folder, "all", model.config.input_height, model.config.input_width)
    pooled = {key: np.concatenate([a[key] for a in arrays.values()]) for key in arrays["manhattan"]}
    if args.network_only:
        evaluated, view_counts = [("all", pooled)], [args.views]
    else:
        evaluated = [] if args.skip_network else [*arrays.items(), ("all", pooled)]
        view_counts = sorted({1, args.views})
    lines += network_lines(model, evaluated, view_counts, record)
    if args.network_only:
        print("\n".join(lines))
        return record

    lines += [
        "",
        "### Table pipeExp, network predictions",
        "",
        f"Network output averaged over {args.views} view(s); rows snapped to the image's edges: "
        f"{args.edge_snap is not None}.",
        "",
        "| method | world | rooms | occluded rooms | failed (%) | CE mean / median (m) | 3D IoU ok (%) | 3D IoU all "
        "(%) | paper CE / IoU |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    comparison, row_errors, causes, widths, miscounts = {}, {}, {}, {}, {}
    for world in TEST_SEEDS:
        folder = str(args.out / f"test_renders_{world}_{count}")
        samples = [read_sample(folder, name) for name in list_samples(folder)]
        truths = [ground_truth(s, world) for s in samples]
        clear = np.array([not any(s.metadata["corner_is_occlusion"]) for s in samples])
        layouts, boundaries = layouts_of(samples, world, model, config, args.views, args.edge_snap)
        results = {
            "pipeline": layout_scores(layouts, truths),
            "solvers": layout_scores(solver_layouts(samples, boundaries, world), truths),
        }
        for method, per_room in results.items():
            for subset, keep in (("no occlusion", clear), ("all", np.ones_like(clear))):
                s = scores_summary([r for r, k in zip(per_room, keep, strict=False) if k])
                record[f"{method}_{world}_{subset}"] = s
                paper = PAPER["pipeExp"][(method, world)] if subset == "no occlusion" else ("", "")
                lines.append(
                    f"| {method} | {world} | {s['rooms']} | {subset} | {s['failed']:.1f} | {s['ce']:.3f} / "
                    f"{s['ce_median']:.3f} | "
                    f"{s['iou3d']:.1f} | {s['iou3d_all']:.1f} | {paper[0]} / {paper[1]} |"
                )
        comparison[world] = scores_summary(results["pipeline"])
        record[f"pipeline_{world}_per_room"] = [
            {
                key: float(r[key]) if isinstance(r[key], (float, np.floating)) else r[key]
                for key in (
                    "returned",
                    "written",
                    "failed",
                    "status",
                    "corners",
                    "true_corners",
                    "ce",
                    "iou3d",
                    "height_error",
                )
                if key in r
            }
            | {"occluded": not bool(keep)}
            for r, keep in zip(results["pipeline"], clear, strict=False)
        ]
        causes[world] = failure_causes(results["pipeline"])
        miscounts[world] = miscounted_layouts(results["pipeline"])
        narrowest = np.array([narrowest_wall(s) for s in samples])
        widths[world] = by_narrowest_wall(
            [r for r, k in zip(results["pipeline"], clear, strict=False) if k], narrowest[clear]
        )
        row_errors[world] = used_row_errors(samples, boundaries)
    lines += ["", "Pipeline failures by cause, all rooms (% of the rooms):", ""]
    lines += [f"- {world}: {text}" for world, text in causes.items()]
    record["failure_causes"] = causes
    record["pipeline_by_narrowest_wall"] = widths
    lines += [
        "",
        "Pipeline by the room's narrowest wall (columns of a 1024-wide panorama), rooms without occlusion:",
        "",
        "| world | narrowest wall (columns) | rooms | failed (%) | CE mean / median (m) | 3D IoU ok (%) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for world, bins in widths.items():
        for b in bins:
            span = f">= {b['low']:g}" if b["high"] is None else f"{b['low']:g}-{b['high']:g}"
            lines.append(
                f"| {world} | {span} | {b['rooms']} | "
                + (
                    f"{b['failed']:.1f} | {b['ce']:.3f} / {b['ce_median']:.3f} | {b['iou3d']:.1f} |"
                    if b["rooms"]
                    else "- | - | - |"
                )
            )
    lines += [
        "",
        "### Table comparison, ncjax rows (pipeline, all test rooms)",
        "",
        "| world | 3D IoU u2s (%) | 3D IoU (%) | CEN (% of diagonal) | CE (m) | failed (%) | paper: u2s / IoU / CEN "
        "/ CE |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for world, s in comparison.items():
        p = PAPER["comparison"][world]
        lines.append(
            f"| {world} | {s['iou3d_u2s']:.1f} | {s['iou3d']:.1f} | {s['cen']:.2f} | {s['ce']:.3f} | "
            f"{s['failed']:.1f} | "
            f"{p[0]} / {p[1]} / {p[2]} / {p[3]} |"
        )
    lines += [
        "",
        "### Every layout returned (pipeline, any corner count)",
        "",
        "Scores every ok layout, also those whose corner count differs from the ground truth (CE is undefined "
        'for them); no layout (a status other than OK) counts 0 in "3D IoU all rooms". The last two columns '
        "also score the layouts flagged UNCERTAIN_SCALE (not ok, but `ncjax reconstruct` writes their geometry "
        "with the flag and the height's sigma).",
        "",
        "| world | rooms | layout returned (%) | with the true corner count (%) | 3D IoU mean / median of the "
        "returned (%) | "
        "3D IoU all rooms (%) | flagged uncertain scale (%), their 3D IoU (%) | 3D IoU all rooms, flagged included "
        "(%) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for world, s in comparison.items():
        lines.append(
            f"| {world} | {s['rooms']} | {s['returned']:.1f} | {100 - s['failed']:.1f} | "
            f"{s['iou3d_returned']:.1f} / {s['iou3d_returned_median']:.1f} | {s['iou3d_all_returned']:.1f} | "
            f"{s['flagged']:.1f}, {s['iou3d_flagged']:.1f} | {s['iou3d_all_written']:.1f} |"
        )
    lines += ["", "Returned layouts with another corner count than the ground truth:", ""]
    lines += [f"- {world}: {text}" for world, text in miscounts.items()]
    lines += [
        "",
        "### The boundary rows the geometry used (full-size image pixels)",
        "",
        "| world | ceiling mean / median (px) | ceiling within 1 px | floor mean / median (px) | floor within 1 px |",
        "| --- | --- | --- | --- | --- |",
    ]
    for world, e in row_errors.items():
        record[f"rows_{world}"] = e
        lines.append(
            f"| {world} | {e['ceiling_mean']:.2f} / {e['ceiling_median']:.2f} | {100 * e['ceiling_within_1px']:.0f}% | "
            f"{e['floor_mean']:.2f} / {e['floor_median']:.2f} | {100 * e['floor_within_1px']:.0f}% |"
        )
    table = "\n".join(lines)
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    suffix = (
        ("_small" if args.small else "")
        + ("" if args.edge_snap else "_no_snap")
        + ("" if args.views == DEFAULT_VIEWS else f"_views{args.views}")
        + (
            ""
            if config == NETWORK_PIPELINE_CONFIG
            else f"_t{args.corner_threshold}_r{args.nms_radius}_o{args.occlusion_threshold}"
        )
    )
    record["pipeline_config"] = {
        "corner_threshold": args.corner_threshold,
        "nms_radius": args.nms_radius,
        "occlusion_threshold": args.occlusion_threshold,
    }
    record["views"] = args.views
    (args.out / f"network_table{suffix}.md").write_text(table + "\n")
    (args.out / f"network_table{suffix}.json").write_text(json.dumps(record, indent=1) + "\n")
    return record


if __name__ == "__main__":
    main()
