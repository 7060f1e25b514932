"""End-to-end speed of ``ncjax.reconstruct_batch`` (network + geometry), split into its two blocks.

Images: the shipped demo panorama (512 x 1024) repeated. For each batch size:
the whole jitted call, the network alone (resize + forward + rows), the rows'
snap to the image's edges alone and the geometry alone (``layout_from_boundaries``
on the snapped rows), after compilation, median of ``--repeats`` runs; latency
per image and images per second.

    uv run python benchmarks/bench_reconstruct.py [--batches 1 8] [--world manhattan] [--repeats 3] [--views 4]
        [--model NAME]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # see README, Development

import jax
import numpy as np

import ncjax
from ncjax.cli.demo import DEMO_DIR
from ncjax.io.images import read_panorama
from ncjax.network.predict import DEFAULT_VIEWS, _predict, default_model
from ncjax.reconstruction import reconstruct_batch


def timed(function, repeats: int) -> tuple[float, float]:
    """(compile + first run, median of the next ``repeats`` runs), seconds."""
    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return first, statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--world", default="manhattan", choices=("manhattan", "atlanta", "auto"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--views", type=int, default=DEFAULT_VIEWS, help="network views averaged (1 or even)")
    parser.add_argument("--model", help="weights (.safetensors) or a shipped model's name; default: the default model")
    args = parser.parse_args(argv)
    name = next(p for p in os.listdir(DEMO_DIR) if p.endswith(".png"))
    image = read_panorama(DEMO_DIR / name)
    rc = ncjax.synth.dataset.rc_from_name(name)
    model = ncjax.load_model(args.model) if args.model else default_model()
    model.eval()
    height, width = image.shape[:2]
    print(
        f"{jax.devices()[0]}, {os.cpu_count()} CPUs, world {args.world}, image {width} x {height}, {args.views} "
        "network view(s)"
    )
    print(
        "| batch | end to end: compile (s) | per call (s) | images/s | network per call (s) | edge snap per call (s) "
        "| geometry per call (s) |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    snap = jax.jit(jax.vmap(ncjax.network.snap_to_edges))
    for batch in args.batches:
        images = np.repeat(image[None], batch, axis=0)
        radii = np.full(batch, rc, np.float32)
        compile_time, total = timed(
            lambda: reconstruct_batch(images, radii, args.world, model=model, views=args.views), args.repeats
        )
        _, network = timed(lambda: _predict(model, images, views=args.views, edge_snap=None), args.repeats)
        ceiling_v, floor_v, corner_prob = _predict(model, images, views=args.views, edge_snap=None)
        _, snapping = timed(lambda: snap(images, ceiling_v, floor_v), args.repeats)
        ceiling_v, floor_v = snap(images, ceiling_v, floor_v)
        cam = ncjax.NonCentralPanorama(width, height, rc=rc)
        _, geometry = timed(
            lambda: ncjax.layout_from_boundaries(ceiling_v, floor_v, corner_prob, cam, world=args.world), args.repeats
        )
        print(
            f"| {batch} | {compile_time:.1f} | {total:.3f} | {batch / total:.2f} | {network:.3f} | {snapping:.3f} | "
            f"{geometry:.3f} |"
        )


if __name__ == "__main__":
    main()
