"""Central vs non-central panoramas of the same rooms (the paper's Table fairComparison, from rows).

Each room is seen from one position by two cameras: a central panorama
(``rc = 0``, the scale from a camera-height prior, as HorizonNet) and the
paper's non-central one (``rc`` 0.3-1 m, the scale from the geometry). Both run
through the same pipeline (:func:`ncjax.layout_from_boundaries`, each room in
its own world) on the exact rows of the room (``ncjax.synth.room_labels``), with
Gaussian noise of sigma pixels added, 1024 x 512.

Two scale cases, as the paper's table:

* "metric": the layouts as returned. The central camera is given the TRUE
  camera height (the paper's "Metric" HorizonNet row); ``--camera-height H``
  gives it a fixed one instead (HorizonNet's habit, 1.6 m).
* "no-scale": each layout scaled so that its camera height is the true one
  (the scale error removed), the paper's "No-scale" rows.

Ground truth as in ``experiments/pipeline_table.py``: the true room for
Manhattan, the visible layout for Atlanta. A room fails when its layout is not
ok or its corner count is wrong; CE and IoU are means over the other rooms.

    uv run python experiments/central_table.py            # 30 rooms per world, sigma 0 and 1 px
    uv run python experiments/central_table.py --small    # quick check
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # busy-waiting BLAS threads stall on a shared machine

import jax
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.pipeline.prior import HeightPrior, scale_layout

from common import noisy_rows  # the same row noise as the non-central tables

OUT = Path(__file__).parent / "out"
WIDTH, HEIGHT = 1024, 512
CAPACITY = 32


@functools.cache
def room_generator(world: str, occlusion: str):
    config = ncjax.RoomConfig(world=world, occlusion=occlusion, capacity=CAPACITY, room_tries=4, camera_tries=128)

    def generate(keys):
        rooms = jax.vmap(lambda k: ncjax.synth.random_room(k, config))(keys)
        central = dataclasses.replace(rooms, rc=0.0 * rooms.rc)
        label = jax.vmap(lambda r: ncjax.synth.room_labels(r, r.camera(WIDTH, HEIGHT)))
        return rooms, label(rooms), label(central)

    return jax.jit(generate)


@functools.cache
def pipeline(world: str, central: bool):
    config = ncjax.PipelineConfig(capacity=CAPACITY)

    def run(ceiling_v, floor_v, corner_prob, rc, camera_height):
        cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=rc)
        prior = HeightPrior("camera_height", camera_height) if central else None
        return ncjax.layout_from_boundaries(ceiling_v, floor_v, corner_prob, cam, world, config, prior=prior)

    return run


def scores(layouts, truths, camera_heights):
    """Per room: (failed, metric CE, metric IoU, no-scale CE, no-scale IoU)."""
    rows = []
    for i in range(camera_heights.shape[0]):
        layout = jax.tree.map(lambda x: np.asarray(x[i]), layouts)
        truth = jax.tree.map(lambda x: np.asarray(x[i]), truths)
        if not layout.ok:
            rows.append((True, math.nan, math.nan, math.nan, math.nan))
            continue
        metric = metrics.evaluate_layout(layout, truth)
        rescaled = scale_layout(layout, camera_heights[i] / -float(layout.floor_height))
        no_scale = metrics.evaluate_layout(jax.tree.map(np.asarray, rescaled), truth)
        bad = not math.isfinite(metric["ce"])
        rows.append(
            (bad, *(math.nan if bad else x for x in (metric["ce"], metric["iou3d"], no_scale["ce"], no_scale["iou3d"])))
        )
    return np.array(rows, float)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=30, help="rooms per world")
    parser.add_argument("--sigmas", default="0,1", help="row noise in pixels, comma list")
    parser.add_argument("--occlusion", default="none", choices=("none", "any", "required"))
    parser.add_argument(
        "--camera-height", type=float, help="the central camera's prior (default: each room's true height)"
    )
    parser.add_argument("--small", action="store_true", help="3 Manhattan rooms, sigma 0 (quick check)")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    worlds, count, sigmas = ("manhattan", "atlanta"), args.rooms, [float(s) for s in args.sigmas.split(",")]
    if args.small:
        worlds, count, sigmas = ("manhattan",), 3, [0.0]
    start = time.time()
    table = []
    plan = [(w, s, c) for w in worlds for s in sigmas for c in (True, False)]
    for world, sigma, central in tqdm(plan, desc="rows"):
        rooms, labels, central_labels = room_generator(world, args.occlusion)(
            jax.random.split(jax.random.key(21), count)
        )
        seen = central_labels if central else labels
        ceiling_v, floor_v = noisy_rows(seen, sigma, 21)
        true_height = -np.asarray(rooms.floor_height)
        prior = np.full(count, args.camera_height, np.float32) if args.camera_height else true_height
        rc = np.zeros(count, np.float32) if central else np.asarray(rooms.rc)
        layouts = pipeline(world, central)(ceiling_v, floor_v, seen.corner_target, rc, prior)
        truth = rooms if world == "manhattan" else seen
        per_room = scores(layouts, truth, true_height)
        ok = per_room[:, 0] == 0
        means = [np.nanmean(per_room[:, j]) if ok.any() else math.nan for j in range(1, 5)]
        camera = "central, camera-height prior" if central else "non-central, rc 0.3-1 m"
        table.append((world, camera, sigma, count, *means, 100 * (~ok).mean()))
    lines = [
        "| world | camera | sigma (px) | rooms | metric CE (m) | metric 3D IoU (%) | no-scale CE (m) "
        "| no-scale 3D IoU (%) | failed (%) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for world, camera, sigma, n, ce, iou, ce_ns, iou_ns, failed in table:
        lines.append(
            f"| {world} | {camera} | {sigma:.1f} | {n} | {ce:.4f} | {100 * iou:.2f} | {ce_ns:.4f} "
            f"| {100 * iou_ns:.2f} | {failed:.1f} |"
        )
    text = "\n".join(lines)
    print(text)
    prior_text = f"{args.camera_height} m" if args.camera_height else "the true camera height"
    print(f"central prior: {prior_text}; occlusion {args.occlusion}; total time {time.time() - start:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / ("central_table_small.md" if args.small else "central_table.md")).write_text(text + "\n")
    return table


if __name__ == "__main__":
    main()
