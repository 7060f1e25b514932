"""Plücker line toolkit (paper Section 3.1, eq. side).

A line is ``L = (l, lbar)`` with direction ``l`` and moment ``lbar = p x l`` for
any point ``p`` on it. Functions are written for one line (shape ``(6,)``) and
broadcast over leading dimensions; all of them are jit/vmap/grad safe.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float


def _as_float(x: ArrayLike) -> Array:
    return jnp.asarray(x, dtype=jnp.result_type(float))


def cross_2d(a: Array, b: Array) -> Array:
    """z component of the cross product of 2D vectors (last axis)."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def safe_sqrt(squared: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
    """Square root of a non-negative array whose gradient is 0 (not NaN) at 0."""
    positive = squared > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0)


def safe_norm(x: Float[ArrayLike, "*#batch n"], axis: int = -1) -> Float[Array, "*batch"]:
    """Euclidean norm whose gradient is 0 (not NaN) at the zero vector."""
    x = _as_float(x)
    return safe_sqrt(jnp.sum(x * x, axis=axis))


def side(a: Float[ArrayLike, "*#batch 6"], b: Float[ArrayLike, "*#batch 6"]) -> Float[Array, "*batch"]:
    """The side operator ``side(A, B) = a . bbar + abar . b`` (paper eq. side).

    Zero iff the two lines are coplanar (they meet, possibly at infinity).
    """
    a, b = _as_float(a), _as_float(b)
    return jnp.sum(a[..., :3] * b[..., 3:], -1) + jnp.sum(a[..., 3:] * b[..., :3], -1)


def plucker_constraint(line: Float[ArrayLike, "*#batch 6"]) -> Float[Array, "*batch"]:
    """The Klein-quadric constraint ``l . lbar`` (zero for every real line)."""
    line = _as_float(line)
    return jnp.sum(line[..., :3] * line[..., 3:], -1)


def normalize_line(line: Float[ArrayLike, "*#batch 6"]) -> Float[Array, "*batch 6"]:
    """Scale a line so its direction has unit norm (the moment is then metric)."""
    line = _as_float(line)
    return line / safe_norm(line[..., :3])[..., None]


def line_from_point_direction(
    point: Float[ArrayLike, "*#batch 3"], direction: Float[ArrayLike, "*#batch 3"]
) -> Float[Array, "*batch 6"]:
    """The line through ``point`` with ``direction`` (normalised to unit length)."""
    point, direction = jnp.broadcast_arrays(_as_float(point), _as_float(direction))
    unit = direction / safe_norm(direction)[..., None]
    return jnp.concatenate([unit, jnp.cross(point, unit)], -1)


def line_through_points(p: Float[ArrayLike, "*#batch 3"], q: Float[ArrayLike, "*#batch 3"]) -> Float[Array, "*batch 6"]:
    """The line through two distinct points, direction ``(q - p) / |q - p|``."""
    p, q = _as_float(p), _as_float(q)
    return line_from_point_direction(p, q - p)


def closest_point_to_origin(line: Float[ArrayLike, "*#batch 6"]) -> Float[Array, "*batch 3"]:
    """The point of the line nearest the origin, ``l x lbar / |l|^2``."""
    line = _as_float(line)
    direction, moment = line[..., :3], line[..., 3:]
    return jnp.cross(direction, moment) / jnp.sum(direction * direction, -1)[..., None]


def point_at(line: Float[ArrayLike, "*#batch 6"], t: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 3"]:
    """``closest_point_to_origin(L) + t * l / |l|``: points along a line by arc length."""
    line = _as_float(line)
    direction = line[..., :3] / safe_norm(line[..., :3])[..., None]
    return closest_point_to_origin(line) + _as_float(t)[..., None] * direction


def closest_points(
    a: Float[ArrayLike, "*#batch 6"], b: Float[ArrayLike, "*#batch 6"]
) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"], Float[Array, "*batch"]]:
    """Closest points of two lines and their Euclidean distance.

    This is the "Euclidean metric distance in E^3" between a 3D line and a
    projecting ray that the paper uses to place corners (Section 4.4, after
    [bermudez2017exploiting]). For parallel lines the closest point on ``a`` is
    its point nearest the origin and the one on ``b`` its foot from there.

    Returns:
        ``(point_on_a, point_on_b, distance)``.
    """
    a, b = _as_float(a), _as_float(b)
    pa, pb = closest_point_to_origin(a), closest_point_to_origin(b)
    da = a[..., :3] / safe_norm(a[..., :3])[..., None]
    db = b[..., :3] / safe_norm(b[..., :3])[..., None]
    offset = pb - pa
    cosine = jnp.sum(da * db, -1)
    denominator = 1.0 - cosine**2
    parallel = denominator < 1e-12
    safe_denominator = jnp.where(parallel, 1.0, denominator)
    oa, ob = jnp.sum(offset * da, -1), jnp.sum(offset * db, -1)
    ta = jnp.where(parallel, 0.0, (oa - cosine * ob) / safe_denominator)
    tb = jnp.where(parallel, -ob, (cosine * oa - ob) / safe_denominator)
    on_a = pa + ta[..., None] * da
    on_b = pb + tb[..., None] * db
    return on_a, on_b, safe_norm(on_a - on_b)


def intersect_coplanar_lines(
    a: Float[ArrayLike, "*#batch 6"], b: Float[ArrayLike, "*#batch 6"]
) -> Float[Array, "*batch 3"]:
    """Meeting point of two coplanar, non-parallel lines.

    Computed as the midpoint of the closest points, which is exact for coplanar
    lines and the least-squares answer for slightly skew ones (noisy data).
    """
    on_a, on_b, _ = closest_points(a, b)
    return 0.5 * (on_a + on_b)


def rotation_z(angle: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 3 3"]:
    """Rotation matrix about the z axis by ``angle`` (counter-clockwise seen from +z)."""
    angle = _as_float(angle)
    c, s = jnp.cos(angle), jnp.sin(angle)
    zero, one = jnp.zeros_like(angle), jnp.ones_like(angle)
    return jnp.stack([jnp.stack([c, -s, zero], -1), jnp.stack([s, c, zero], -1), jnp.stack([zero, zero, one], -1)], -2)


def rotate_line_z(line: Float[ArrayLike, "*#batch 6"], angle: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 6"]:
    """Rotate a line about the z axis through the origin (direction and moment both rotate)."""
    line = _as_float(line)
    rotation = rotation_z(angle)
    direction = jnp.einsum("...ij,...j->...i", rotation, line[..., :3])
    moment = jnp.einsum("...ij,...j->...i", rotation, line[..., 3:])
    return jnp.concatenate([direction, moment], -1)


def translate_line(
    line: Float[ArrayLike, "*#batch 6"], offset: Float[ArrayLike, "*#batch 3"]
) -> Float[Array, "*batch 6"]:
    """Translate a line by ``offset``: the moment becomes ``lbar + offset x l``."""
    line, offset = _as_float(line), _as_float(offset)
    direction = line[..., :3]
    moment = line[..., 3:] + jnp.cross(offset, direction)
    return jnp.concatenate(jnp.broadcast_arrays(direction, moment), -1)


def horizontal_wall_line(
    direction: Float[ArrayLike, "*#batch 2"], distance: Float[ArrayLike, "*#batch"], height: Float[ArrayLike, "*#batch"]
) -> Float[Array, "*batch 6"]:
    """The horizontal line at ``height`` in the vertical wall plane (docs/design.md section 3).

    With unit ``u = (ux, uy)``, ``e2 = (-uy, ux, 0)`` and ``d`` the signed
    distance of the plane from the axis along ``e2``, the line is
    ``(ux, uy, 0, -h uy, h ux, -d)`` (moment ``h e2 - d e3``; paper
    eqs. side_l_xi and side_m_chi).
    """
    direction = _as_float(direction)
    distance, height = _as_float(distance), _as_float(height)
    ux, uy = direction[..., 0], direction[..., 1]
    ux, uy, distance, height = jnp.broadcast_arrays(ux, uy, distance, height)
    return jnp.stack([ux, uy, jnp.zeros_like(ux), -height * uy, height * ux, -distance], -1)


def wall_planes_meet(
    direction_a: Float[ArrayLike, "*#batch 2"],
    distance_a: Float[ArrayLike, "*#batch"],
    direction_b: Float[ArrayLike, "*#batch 2"],
    distance_b: Float[ArrayLike, "*#batch"],
) -> tuple[Float[Array, "*batch 2"], Bool[Array, "*batch"]]:
    """Horizontal position of the vertical edge where two wall planes meet.

    Solves ``e2_a . p = d_a``, ``e2_b . p = d_b`` (``e2 = (-uy, ux)``) by
    Cramer's rule: the same point as :func:`intersect_coplanar_lines` on the
    walls' ceiling or floor lines, without the third coordinate.

    Returns:
        ``(point, ok)``; ``ok`` is False (and the point 0) when the walls are
        parallel to within ``1e-6`` rad.
    """
    direction_a, direction_b = _as_float(direction_a), _as_float(direction_b)
    distance_a, distance_b = _as_float(distance_a), _as_float(distance_b)
    det = cross_2d(direction_a, direction_b)
    ok = jnp.abs(det) > 1e-6 * safe_norm(direction_a) * safe_norm(direction_b)
    safe_det = jnp.where(ok, det, 1.0)
    x = (distance_a * direction_b[..., 0] - direction_a[..., 0] * distance_b) / safe_det
    y = (distance_a * direction_b[..., 1] - direction_a[..., 1] * distance_b) / safe_det
    return jnp.where(ok[..., None], jnp.stack([x, y], -1), 0.0), ok
