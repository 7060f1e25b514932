"""Cost per element of XLA's CPU elementary functions, and of ncjax's float32 arctangent.

    uv run python benchmarks/bench_elementary.py [--size 1048576] [--repeats 20]

One jitted call per function on ``--size`` float32 elements (best of
``--repeats``; XLA splits large loops over the cores, ``taskset -c 0`` for
one). XLA's CPU backend vectorises products, quotients, square roots and
``exp``, not ``atan2``, ``sin``, ``cos`` or ``tan``; ``ncjax.geometry.fastmath.arctan2``
is a polynomial that vectorises. Also prints its largest error against
numpy's float64 ``arctan2``. Never asserted in tests.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax
import jax.numpy as jnp
import numpy as np

from ncjax.geometry.fastmath import arctan2

FUNCTIONS = {
    "jnp.arctan2": jnp.arctan2,
    "ncjax.geometry.fastmath.arctan2": arctan2,
    "jnp.sin": lambda y, x: jnp.sin(y),
    "jnp.cos": lambda y, x: jnp.cos(y),
    "jnp.tan": lambda y, x: jnp.tan(y),
    "jnp.exp": lambda y, x: jnp.exp(y),
    "jnp.sqrt": lambda y, x: jnp.sqrt(jnp.abs(y)),
    "y / x": lambda y, x: y / x,
}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1 << 20)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    y, x = (jnp.asarray(rng.normal(size=args.size).astype(np.float32)) for _ in range(2))
    for name, fn in FUNCTIONS.items():
        compiled = jax.jit(fn)
        compiled(y, x).block_until_ready()
        best = np.inf
        for _ in range(args.repeats):
            start = time.perf_counter()
            compiled(y, x).block_until_ready()
            best = min(best, time.perf_counter() - start)
        print(f"{name:>24}: {best / args.size * 1e9:6.2f} ns per element")
    exact = np.arctan2(np.asarray(y, np.float64), np.asarray(x, np.float64))
    error = np.max(np.abs(np.asarray(jax.jit(arctan2)(y, x), np.float64) - exact))
    print(
        f"ncjax.geometry.fastmath.arctan2: largest error {error:.2e} rad (float32 spacing at pi: "
        f"{np.spacing(np.float32(np.pi)):.2e})"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
