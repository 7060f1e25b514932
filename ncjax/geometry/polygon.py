"""Closed polygons in fixed-capacity slots: the first ``M`` slots of a mask hold the corners in loop order.

Rooms, their furniture and the recovered layouts all use these helpers, so that the loop's neighbours,
its edges and its area are computed one way.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .plucker import cross_2d


def perpendicular(v: Float[Array, "*batch 2"]) -> Float[Array, "*batch 2"]:
    """``v`` turned by +90 degrees: ``(-v_y, v_x)``."""
    return jnp.stack([-v[..., 1], v[..., 0]], -1)


def next_index(mask: Bool[Array, " K"]) -> Int[Array, " K"]:
    """Index of the next corner in the loop of the ``M`` valid slots; the empty slots point to corner 0."""
    index = jnp.arange(mask.shape[0])
    return jnp.where(index + 1 < jnp.sum(mask), index + 1, 0)


def previous_index(mask: Bool[Array, " K"]) -> Int[Array, " K"]:
    """Index of the previous corner in the loop of the ``M`` valid slots; the empty slots point to slot ``k - 1``."""
    index = jnp.arange(mask.shape[0])
    return jnp.where(index > 0, index - 1, jnp.sum(mask) - 1)


def previous_in_loop(mask: Bool[Array, " K"]) -> Int[Array, " K"]:
    """``(k - 1) mod M`` for every slot ``k``: the previous wall of a closed loop of ``M`` walls (M >= 1 assumed).

    Unlike :func:`previous_index`, the empty slots also point inside the loop, so gathering with it never reads
    an empty slot.
    """
    count = jnp.maximum(jnp.sum(mask), 1)
    return (jnp.arange(mask.shape[0]) - 1) % count


def polygon_edges(corners: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Float[Array, "K 2 2"]:
    """The walls of a polygon as segments (start, end); masked slots are repeated corners."""
    return jnp.stack([corners, corners[next_index(mask)]], 1)


def polygon_area(corners: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Float[Array, ""]:
    """Signed area (positive for counter-clockwise), shoelace formula."""
    following = corners[next_index(mask)]
    return 0.5 * jnp.sum(jnp.where(mask, cross_2d(corners, following), 0.0))


def segments_cross(p: Array, q: Array, a: Array, b: Array) -> Array:
    """Proper crossing of segments pq and ab (shared endpoints do not count)."""
    d1, d2 = cross_2d(q - p, a - p), cross_2d(q - p, b - p)
    d3, d4 = cross_2d(b - a, p - a), cross_2d(b - a, q - a)
    return (d1 * d2 < 0) & (d3 * d4 < 0)


def is_simple(corners: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Bool[Array, ""]:
    """Whether no two walls of the polygon cross (:func:`segments_cross`)."""
    edges = polygon_edges(corners, mask)
    crosses = segments_cross(edges[:, None, 0], edges[:, None, 1], edges[None, :, 0], edges[None, :, 1])
    return ~jnp.any(crosses & mask[:, None] & mask[None, :])


def point_in_polygon(point: Float[Array, 2], corners: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Bool[Array, ""]:
    """Whether ``point`` lies inside the polygon (crossing-number test)."""
    edges = polygon_edges(corners, mask)
    a, b = edges[:, 0], edges[:, 1]
    straddles = (a[:, 1] > point[1]) != (b[:, 1] > point[1])
    safe_dy = jnp.where(straddles, b[:, 1] - a[:, 1], 1.0)
    x_cross = a[:, 0] + (point[1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / safe_dy
    return jnp.sum(straddles & (x_cross > point[0]) & mask) % 2 == 1
