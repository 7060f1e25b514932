"""Throughput of the single-wall solver and wall time of the noise sweep.

    uv run python benchmarks/bench_solvers.py [--rays 64] [--batch 4096]

Prints wall solves per second (batched with jit(vmap), float32 and float64)
for walls of ``--rays`` ceiling and ``--rays`` floor rays, and the time of
the small noise sweep. Never asserted in tests.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import ncjax  # noqa: E402
from ncjax import _exact_rooms  # noqa: E402


def wall_batch(key, batch, rays, dtype):
    """Exact rays of wall 0 of random rectangles, ``rays`` columns per line."""

    def one(k):
        cam = ncjax.NonCentralPanorama(1024, 512, rc=0.5)
        corners = _exact_rooms.rectangle_room(k, cam.rc)
        ceiling_v, floor_v, index = _exact_rooms.exact_boundaries(cam, corners, 1.0, -1.4)
        columns = jnp.nonzero(index == 0, size=rays, fill_value=0)[0]
        ceiling_rays, floor_rays = _exact_rooms.boundary_rays(cam, ceiling_v, floor_v)
        mask = jnp.arange(rays) < jnp.sum(index == 0)
        return ceiling_rays[columns].astype(dtype), floor_rays[columns].astype(dtype), mask

    return jax.jit(jax.vmap(one))(jax.random.split(key, batch))


def solves_per_second(batch, rays, dtype, repeats=5):
    ceiling, floor, mask = wall_batch(jax.random.PRNGKey(0), batch, rays, dtype)
    solve = jax.jit(jax.vmap(ncjax.solve_wall))
    jax.block_until_ready(solve(ceiling, floor, mask, mask))
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(solve(ceiling, floor, mask, mask))
        best = min(best, time.perf_counter() - start)
    return batch / best


def svd_only_per_second(batch, rays, dtype, repeats=5):
    """The LAPACK SVD of the (2 rays, 7) matrices alone: the solver's floor."""
    a = jax.random.normal(jax.random.PRNGKey(1), (batch, 2 * rays, 7), dtype)
    svd = jax.jit(jax.vmap(lambda m: jnp.linalg.svd(m, full_matrices=False)[2]))
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
            print(f"{jnp.dtype(dtype).name}: {rate:,.0f} wall solves/s ({args.rays}+{args.rays} rays); SVD alone {floor:,.0f}/s")
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
