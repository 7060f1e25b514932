"""Throughput of the single-wall solver and wall time of the noise sweep.

    uv run python benchmarks/bench_solvers.py [--rays 64] [--batch 4096]

Prints wall solves per second (batched with jit(vmap), float32 and float64)
for walls of ``--rays`` ceiling and ``--rays`` floor rays (the batch split over one
single-threaded XLA device per core), and the time of
the small noise sweep. Never asserted in tests.
"""

from __future__ import annotations

import argparse
import os
import time

# jaxlib's LAPACK kernels split their batch over XLA's CPU thread pool and wait for it; with
# one busy device per pool thread that wait never ends (seen in gdb: both devices in
# CholeskyFactorizationKernel -> ParallelBatchMap -> BlockingCounter::Wait). XLA sizes the
# pool from NPROC when it is set: twice the cores leaves threads free for those kernels.
os.environ.setdefault("NPROC", str(2 * os.cpu_count()))
# one single-threaded XLA device per core; the batch is split over them
os.environ.setdefault(
    "XLA_FLAGS", f"--xla_cpu_multi_thread_eigen=false --xla_force_host_platform_device_count={os.cpu_count()}"
)

import jax
import jax.numpy as jnp
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

import ncjax

CONFIG = ncjax.RoomConfig(world="manhattan", max_walls=6, capacity=12, occlusion="none")


def wall_batch(key, batch, rays, dtype):
    """Exact rays of the widest wall of random rooms (``ncjax.synth.random_room``), ``rays`` columns per line."""

    def one(k):
        room = ncjax.synth.random_room(k, CONFIG)
        cam = ncjax.NonCentralPanorama(1024, 512, rc=room.rc)
        labels = ncjax.synth.room_labels(room, cam)
        counts = jnp.sum(labels.wall_index[:, None] == jnp.arange(CONFIG.capacity), 0)
        index = jnp.nonzero(labels.wall_index == jnp.argmax(counts), size=1024, fill_value=0)[0]
        columns = index[jnp.round(jnp.linspace(0.0, 1.0, rays) * (jnp.max(counts) - 1)).astype(jnp.int32)]
        u = columns.astype(jnp.float32)
        ceiling_rays = ncjax.geometry.pixel_to_ray(cam, u, labels.ceiling_v[columns])
        floor_rays = ncjax.geometry.pixel_to_ray(cam, u, labels.floor_v[columns])
        return ceiling_rays.astype(dtype), floor_rays.astype(dtype), jnp.ones(rays, bool)

    return jax.jit(jax.vmap(one))(jax.random.split(key, batch))


def split_over_devices(*arrays):
    """The arrays with their leading (batch) axis split over all devices: ``jit`` then runs one share per core."""
    mesh = jax.make_mesh(
        (len(jax.devices()),), ("batch",), devices=jax.devices(), axis_types=(jax.sharding.AxisType.Auto,)
    )
    return jax.device_put(arrays, NamedSharding(mesh, P("batch")))


def solves_per_second(batch, rays, dtype, repeats=5):
    ceiling, floor, mask = split_over_devices(*wall_batch(jax.random.PRNGKey(0), batch, rays, dtype))
    solve = jax.jit(jax.vmap(ncjax.solvers.solve_wall))
    jax.block_until_ready(solve(ceiling, floor, mask, mask))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(solve(ceiling, floor, mask, mask))
        best = min(best, time.perf_counter() - start)
    return batch / best


def svd_only_per_second(batch, rays, dtype, repeats=5):
    """The null space of the (2 rays, 7) matrices alone (Gram-Schmidt reduction + 7 x 7 Jacobi SVD).

    The solver's floor."""
    (a,) = split_over_devices(jax.random.normal(jax.random.PRNGKey(1), (batch, 2 * rays, 7), dtype))
    svd = jax.jit(jax.vmap(lambda m: ncjax.geometry.null_space(m, 2)))
    jax.block_until_ready(svd(a))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(svd(a))
        best = min(best, time.perf_counter() - start)
    return batch / best


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rays", type=int, default=64)
    parser.add_argument("--batch", type=int, default=4096)
    parser.add_argument("--sweep", action="store_true", help="also time the small noise sweep")
    args = parser.parse_args()
    print(f"devices: {jax.devices()}, XLA_FLAGS={os.environ.get('XLA_FLAGS')}")
    for dtype, enable in ((jnp.float32, False), (jnp.float64, True)):
        with jax.enable_x64(enable):
            rate = solves_per_second(args.batch, args.rays, dtype)
            floor = svd_only_per_second(args.batch, args.rays, dtype)
            print(
                f"{jnp.dtype(dtype).name}: {rate:,.0f} wall solves/s ({args.rays}+{args.rays} rays); null space "
                f"alone {floor:,.0f}/s"
            )
    if args.sweep:
        import importlib.util
        from pathlib import Path

        path = Path(__file__).parents[1] / "experiments" / "noise_sweep.py"
        spec = importlib.util.spec_from_file_location("noise_sweep", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        start = time.perf_counter()
        module.main(["--small", "--out", "/tmp/ncjax_bench_sweep"])
        print(f"small noise sweep (incl. compilation): {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
