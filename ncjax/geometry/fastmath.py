"""A float32 arctangent that vectorises on the CPU.

XLA's CPU backend does not vectorise ``atan2``: it costs about 25 ns per
element on one core of our machine, against 0.5 ns for the polynomial below
(``benchmarks/bench_elementary.py``). The pipeline takes an arctangent per
boundary row in every reprojection (:func:`ncjax.geometry.reprojection.boundary_rows_along`,
the final adjustment) and in every angular residual of the layout solvers
(:func:`ncjax.solvers.wall_fit.angular_residual`), millions per batch, so those call
:func:`arctan2` here.

Float64 inputs go to ``jnp.arctan2``: float64 callers (the accuracy tests,
finite differences) want its last bits. Float32 inputs get an odd
polynomial after the usual reductions (octant, then ``tan(pi/8)``), accurate
to about 2 ulp, with the exact derivative as its JVP.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

# atan(u) ~ u + u^3 P(u^2) on |u| <= tan(pi/8): least squares of the relative
# error on 4000 Chebyshev nodes (float64), 1.0 ulp in float32 there
_ATAN_COEFFICIENTS = (-0.33333316, 0.19998531, -0.14244486, 0.10600013, -0.06092337)
_TAN_PI_8 = math.tan(math.pi / 8)


def _arctan2_float32(y: Array, x: Array) -> Array:
    ax, ay = jnp.abs(x), jnp.abs(y)
    big, small = jnp.maximum(ax, ay), jnp.minimum(ax, ay)
    ratio = small / jnp.where(big > 0, big, 1.0)  # in [0, 1]: the first octant
    reduced = ratio > _TAN_PI_8
    u = jnp.where(reduced, (ratio - 1.0) / (ratio + 1.0), ratio)  # atan(r) = pi/4 + atan((r - 1) / (r + 1))
    z = u * u
    polynomial = _ATAN_COEFFICIENTS[-1]
    for coefficient in reversed(_ATAN_COEFFICIENTS[:-1]):
        polynomial = polynomial * z + coefficient
    angle = u + u * z * polynomial
    angle = jnp.where(reduced, angle + math.pi / 4, angle)
    angle = jnp.where(ay > ax, math.pi / 2 - angle, angle)
    angle = jnp.where(x < 0, math.pi - angle, angle)
    return jnp.where(y < 0, -angle, angle)


@jax.custom_jvp
def _fast_arctan2(y: Array, x: Array) -> Array:
    return _arctan2_float32(y, x)


@_fast_arctan2.defjvp
def _fast_arctan2_jvp(primals, tangents):
    y, x = primals
    dy, dx = tangents
    squared = x * x + y * y
    # 0 at the origin, where the angle is undefined (jnp.arctan2 gives NaN there)
    derivative = (x * dy - y * dx) / jnp.where(squared > 0, squared, 1.0)
    return _fast_arctan2(y, x), derivative


def arctan2(y: Float[ArrayLike, "*#batch"], x: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch"]:
    """``atan2(y, x)`` in ``(-pi, pi]``; a vectorising polynomial in float32, ``jnp.arctan2`` otherwise."""
    y, x = jnp.asarray(y), jnp.asarray(x)
    dtype = jnp.result_type(y, x)
    if dtype != jnp.float32:
        return jnp.arctan2(y, x)
    y, x = jnp.broadcast_arrays(y.astype(dtype), x.astype(dtype))
    return _fast_arctan2(y, x)
