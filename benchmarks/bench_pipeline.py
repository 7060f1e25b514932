"""Latency and throughput of the geometric pipeline (``ncjax.layout_from_boundaries``) on this machine.

Exact boundaries of random rooms at 1024 x 512; one panorama (after
compilation) and batches of 64 and 256 under ``jax.jit(jax.vmap(...))``,
for the Manhattan and Atlanta branches.

    uv run python benchmarks/bench_pipeline.py [--repeats 5] [--batches 64 256]
"""

from __future__ import annotations

import argparse
import time

import jax

import ncjax
from ncjax._pipeline import PipelineConfig, layout_from_evidence

WIDTH, HEIGHT = 1024, 512


def inputs(world: str, count: int):
    config = ncjax.RoomConfig(world=world, occlusion="any", room_tries=2, camera_tries=64)
    rooms = jax.jit(jax.vmap(lambda k: ncjax.random_room(k, config)))(jax.random.split(jax.random.key(3), count))
    labels = jax.jit(jax.vmap(lambda r: ncjax.room_labels(r, r.camera(WIDTH, HEIGHT))))(rooms)
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(rooms)
    return labels.ceiling_v, labels.floor_v, labels.corner_target, cams


def best_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batches", type=int, nargs="*", default=[64, 256])
    args = parser.parse_args(argv)
    config = PipelineConfig()
    print(f"devices: {jax.devices()}")
    for world in ("manhattan", "atlanta"):
        ceiling, floor, prob, cams = inputs(world, max(args.batches + [1]))
        one = jax.jit(lambda c, f, p, cam: layout_from_evidence(c, f, p, cam, jax.random.key(0), world, config))
        cam0 = jax.tree.map(lambda x: x[0], cams)
        start = time.perf_counter()
        jax.block_until_ready(one(ceiling[0], floor[0], prob[0], cam0))
        compile_time = time.perf_counter() - start
        latency = best_time(lambda: one(ceiling[0], floor[0], prob[0], cam0), args.repeats)
        print(f"{world}: compile {compile_time:.1f} s, latency {1e3 * latency:.1f} ms per panorama")
        batched = jax.jit(
            jax.vmap(lambda c, f, p, cam, k: layout_from_evidence(c, f, p, cam, k, world, config))
        )
        for size in args.batches:
            keys = jax.random.split(jax.random.key(0), size)
            data = (ceiling[:size], floor[:size], prob[:size], jax.tree.map(lambda x: x[:size], cams), keys)
            jax.block_until_ready(batched(*data))
            seconds = best_time(lambda: batched(*data), max(1, args.repeats // 2))
            print(f"{world}: batch {size}: {size / seconds:.0f} panoramas/s ({1e3 * seconds / size:.1f} ms each)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
