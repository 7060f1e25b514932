"""How far a panorama's boundaries are from one flat, level floor and ceiling (no Flax, no optax).

A room's floor and ceiling are flat and level, so a panorama's column sees its wall's foot and top at the same
distance: ``tan(ceiling elevation) / tan(-floor elevation)`` is the room's ``h_c / h_f`` in every column whose rows
lie on the wall, central or not (a column's rays leave one optical centre at one azimuth, docs/design.md). Rows that
run through a doorway into the next room's floor, onto a counter or along a ceiling fan break it.
:func:`flatness_loss` is what the test-time adaptation (:mod:`ncjax.network.adapt`) minimises, and
:func:`row_flatness` the same of an image's rows, which decides whether a panorama is adapted
(:class:`~ncjax.network.config.AdaptConfig`'s ``min_loss``).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..geometry.camera import row_to_elevation

_LEVEL = 1e-3  # radians kept between a boundary and the horizon or a pole, where tan is 0 or infinite


def huber_loss(x: Float[Array, "*batch"], delta: float) -> Float[Array, "*batch"]:
    """Huber's loss: ``x^2 / 2`` within ``delta`` of 0, then growing as ``delta (|x| - delta / 2)``."""
    magnitude = jnp.abs(x)
    return jnp.where(magnitude <= delta, 0.5 * x**2, delta * (magnitude - 0.5 * delta))


def flatness_loss(
    ceiling_elevation: Float[Array, " W"], floor_elevation: Float[Array, " W"], huber: float
) -> Float[Array, ""]:
    """The Huber loss of each column's ``log(tan(ceiling elevation) / tan(-floor elevation))`` about their median
    (held fixed): 0 when every column's rows see one flat, level floor and ceiling, whatever the room's shape.

    Args:
        ceiling_elevation, floor_elevation: (W,) radians, one panorama's boundaries (central or not).
        huber: the loss's threshold, in the log ratio.
    """
    ceiling = jnp.clip(ceiling_elevation, _LEVEL, jnp.pi / 2 - _LEVEL)
    floor = jnp.clip(-floor_elevation, _LEVEL, jnp.pi / 2 - _LEVEL)
    log_ratio = jnp.log(jnp.tan(ceiling)) - jnp.log(jnp.tan(floor))
    centre = jax.lax.stop_gradient(jnp.median(log_ratio))
    return jnp.mean(huber_loss(log_ratio - centre, huber))


@functools.partial(jax.jit, static_argnames=("height", "huber"))
def row_flatness(
    ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"], height: int, huber: float
) -> Float[Array, ""]:
    """:func:`flatness_loss` of one panorama's boundary rows (sub-pixel rows of an image ``height`` rows high)."""
    return flatness_loss(row_to_elevation(ceiling_v, height), row_to_elevation(floor_v, height), huber)
