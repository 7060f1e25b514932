"""Latency and throughput of the geometric pipeline (``ncjax.layout_from_boundaries``) on this machine.

Exact boundaries (or with ``--sigma`` px of noise) of random rooms at 1024 x 512; one panorama (after
compilation; median of ``--repeats``) and batches of 64 and 256 (one call,
``jax.jit(jax.vmap(...))`` inside), for the Manhattan, Atlanta and auto
branches, each room with its own camera. Rooms run with
``PipelineConfig.compact_capacity`` slots first; those that need more are
rerun with all of them, and the batch lines say how many were.
Wall-clock and CPU (``time.process_time``) times are printed side by side:
on a shared machine the wall time is noisy, the CPU time much less so.

OpenBLAS (the LAPACK behind jaxlib's CPU linear algebra) is limited to one
thread before JAX loads it: its worker threads busy-wait, and on a machine
whose cores are taken by another job a small QR or SVD then waits for a
descheduled worker (we measured 6 s instead of 20 ms for the final
adjustment). Set ``OPENBLAS_NUM_THREADS`` yourself to compare.

    uv run python benchmarks/bench_pipeline.py [--repeats 11] [--batches 64 256] [--worlds manhattan atlanta auto]
        [--adjustment-stride 2] [--compact-capacity 16] [--chunk-size 32] [--sigma 0]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax
import jax.numpy as jnp

import ncjax
from ncjax.pipeline.config import WORLDS, PipelineConfig

WIDTH, HEIGHT = 1024, 512


def inputs(world: str, count: int, sigma: float = 0.0):
    """Labels of ``count`` random rooms (Atlanta rooms for ``world="auto"``: both branches are taken).

    ``sigma`` (pixels) adds white noise to the boundary rows: on exact rows the
    final adjustment converges in a step or two, on noisy ones it runs to
    ``PipelineConfig.adjustment_steps`` more often.
    """
    config = ncjax.RoomConfig(
        world="atlanta" if world == "auto" else world, occlusion="any", room_tries=2, camera_tries=64
    )
    rooms = jax.jit(jax.vmap(lambda k: ncjax.synth.random_room(k, config)))(jax.random.split(jax.random.key(3), count))
    labels = jax.jit(jax.vmap(lambda r: ncjax.synth.room_labels(r, r.camera(WIDTH, HEIGHT))))(rooms)
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(rooms)
    ceiling_key, floor_key = jax.random.split(jax.random.key(4))
    ceiling_v = labels.ceiling_v + sigma * jax.random.normal(ceiling_key, labels.ceiling_v.shape)
    floor_v = labels.floor_v + sigma * jax.random.normal(floor_key, labels.floor_v.shape)
    return ceiling_v, floor_v, labels.corner_target, cams


def timed(fn) -> tuple[float, float]:
    """Wall-clock and CPU seconds of one blocking call."""
    wall, cpu = time.perf_counter(), time.process_time()
    jax.block_until_ready(fn())
    return time.perf_counter() - wall, time.process_time() - cpu


def median_time(fn, repeats: int) -> tuple[float, float]:
    """Median wall-clock and CPU seconds over ``repeats`` calls."""
    times = [timed(fn) for _ in range(repeats)]
    return statistics.median(t[0] for t in times), statistics.median(t[1] for t in times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=11)
    parser.add_argument("--batches", type=int, nargs="*", default=[64, 256])
    parser.add_argument("--worlds", nargs="*", default=list(WORLDS), choices=WORLDS)
    defaults = PipelineConfig()
    parser.add_argument(
        "--adjustment-stride",
        type=int,
        default=defaults.adjustment.stride,
        help="adjustment.stride: the final adjustment fits every n-th column",
    )
    parser.add_argument(
        "--compact-capacity",
        type=int,
        default=defaults.compact_capacity,
        help="compact_capacity (0: every room with all the slots)",
    )
    parser.add_argument(
        "--chunk-size",
        type=int,
        default=defaults.chunk_size,
        help="chunk_size: panoramas per vmap inside a batch (0: all)",
    )
    parser.add_argument(
        "--outlier-rate",
        type=float,
        default=defaults.ransac.outlier_rate,
        help="ransac.outlier_rate: RANSAC's epsilon, which sets its number of random hypotheses",
    )
    parser.add_argument(
        "--strata",
        type=int,
        default=defaults.ransac.strata,
        help="ransac.strata: RANSAC's fixed stratified samples instead of random ones (0: random)",
    )
    parser.add_argument("--sigma", type=float, default=0.0, help="white noise on the boundary rows, pixels")
    args = parser.parse_args(argv)
    config = PipelineConfig(compact_capacity=args.compact_capacity, chunk_size=args.chunk_size).replace(
        adjustment={"stride": args.adjustment_stride},
        ransac={"outlier_rate": args.outlier_rate, "strata": args.strata},
    )
    print(
        f"devices: {jax.devices()}, XLA_FLAGS={os.environ.get('XLA_FLAGS')}, "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, load average {os.getloadavg()[0]:.2f}, "
        f"row noise {args.sigma} px"
    )
    for world in args.worlds:
        ceiling, floor, prob, cams = inputs(world, max(args.batches + [args.repeats]), args.sigma)

        # each room's own arrays, sliced before the clock starts: the latency is that of the call alone
        rooms = jax.block_until_ready(
            [(ceiling[i], floor[i], prob[i], jax.tree.map(lambda x: x[i], cams)) for i in range(args.repeats)]
        )

        def single(i):
            return ncjax.layout_from_boundaries(*rooms[i], world=world, config=config)

        compile_wall, compile_cpu = timed(lambda: single(0))
        for i in range(args.repeats):
            single(i)  # compiles the full-capacity program if a room needs it
        # a different room per repeat: the iteration counts depend on the data
        times = [timed(lambda i=i: single(i)) for i in range(args.repeats)]
        wall, cpu = statistics.median(t[0] for t in times), statistics.median(t[1] for t in times)
        print(
            f"{world}: compile {compile_wall:.1f} s (cpu {compile_cpu:.1f} s), "
            f"latency {1e3 * wall:.1f} ms per panorama (cpu {1e3 * cpu:.1f} ms), median of {args.repeats} rooms"
        )
        for size in args.batches:
            data = (ceiling[:size], floor[:size], prob[:size], jax.tree.map(lambda x: x[:size], cams))

            def batched(data=data):
                return ncjax.layout_from_boundaries(*data, world=world, config=config)

            layouts = jax.block_until_ready(batched())
            # the rooms rerun with all the slots (more walls than compact_capacity)
            reruns = int(jnp.sum(jnp.sum(layouts.mask, -1) > config.compact_capacity))
            wall, cpu = median_time(batched, max(1, args.repeats // 4))
            print(
                f"{world}: batch {size}: {size / wall:.0f} panoramas/s ({1e3 * wall / size:.2f} ms each, "
                f"cpu {1e3 * cpu / size:.2f} ms each; ok {float(jnp.mean(layouts.ok)):.2f}, "
                f"{reruns} rerun with {config.capacity} slots)"
            )
    print(f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
