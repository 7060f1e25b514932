"""A vertical wall at known ceiling and floor heights (a height prior's; not in the paper): a plan line fit."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry.fastmath import arctan2
from ..geometry.plucker import closest_point_to_origin, cross_2d
from .wall import Wall, distinct_azimuths, make_wall


def boundary_points_at(
    rays: Float[Array, "n 6"], height: Float[Array, ""]
) -> tuple[Float[Array, "n 2"], Bool[Array, " n"]]:
    """Where each ray meets the horizontal plane ``z = height``: plan points, and which rays reach it going forward.

    The ray's nearest point to the origin ``p0`` (:func:`ncjax.geometry.closest_point_to_origin`) moves along its
    direction ``xi`` to ``p0 + s xi`` with ``s = (height - p0_z) / xi_z``; the ray leaves its optical centre
    in the plane ``z = 0``, so it reaches the plane ahead of it when ``xi_z`` has the sign of ``height``.
    """
    direction = rays[:, :3]
    nearest = closest_point_to_origin(rays)
    ahead = direction[:, 2] * height > 0
    step = (height - nearest[:, 2]) / jnp.where(ahead, direction[:, 2], 1.0)
    return nearest[:, :2] + step[:, None] * direction[:, :2], ahead


def solve_wall_at_heights(
    ceiling_rays: Float[Array, "n 6"],
    floor_rays: Float[Array, "n 6"],
    ceiling_mask: Bool[Array, " n"],
    floor_mask: Bool[Array, " n"],
    ceiling_height: Float[Array, ""],
    floor_height: Float[Array, ""],
) -> Wall:
    """One vertical wall at known ceiling and floor heights (a height prior's): the plan line through its rays'
    points at those heights.

    Not in the paper, whose walls carry their own heights. With the heights fixed, each used ceiling (floor) ray
    is one plan point (:func:`boundary_points_at`), and the wall is the line of least weighted squared distances
    to them: through their weighted mean, along the main axis of their scatter (closed form of a symmetric
    2 x 2 eigenvector). Each point is weighted by the inverse square of ``(r^2 + h^2) / |h|``, how far a row
    error of one radian moves a point at range ``r`` from the axis along a central ray (a height prior's
    virtual rig sees the central panorama's points): far points fix the wall less. Two simplifications: the
    whole move counts, not only its part across the wall, and ceiling and floor rows count alike (the joint
    solvers and the adjustment weight them by their noise).

    Returns:
        The :class:`Wall` (canonical orientation); ``ok`` is False when the used points lie in fewer than 2
        columns (azimuths: a line through the axis), or the heights do not put the camera between ceiling and
        floor.
    """
    ceiling_points, ceiling_ahead = boundary_points_at(ceiling_rays, ceiling_height)
    floor_points, floor_ahead = boundary_points_at(floor_rays, floor_height)
    points = jnp.concatenate([ceiling_points, floor_points])
    used = jnp.concatenate([ceiling_mask & ceiling_ahead, floor_mask & floor_ahead])
    used &= jnp.all(jnp.isfinite(points), -1)
    heights = jnp.concatenate(
        [jnp.full(ceiling_points.shape[0], ceiling_height), jnp.full(floor_points.shape[0], floor_height)]
    )
    spread = (jnp.sum(points**2, -1) + heights**2) / jnp.abs(heights)
    weight = jnp.where(used, 1.0 / jnp.where(used, spread, 1.0) ** 2, 0.0)
    points = jnp.where(used[:, None], points, 0.0)
    total = jnp.sum(weight)
    mean = jnp.sum(weight[:, None] * points, 0) / jnp.where(total > 0, total, 1.0)
    centred = points - mean
    scatter = jnp.einsum("n,ni,nj->ij", weight, centred, centred)
    # the fast arctan2 has a zero gradient at (0, 0), where too few points leave the scatter
    angle = 0.5 * arctan2(2.0 * scatter[0, 1], scatter[0, 0] - scatter[1, 1])
    direction = jnp.stack([jnp.cos(angle), jnp.sin(angle)])
    distance = cross_2d(direction, mean)
    columns = distinct_azimuths(jnp.concatenate([ceiling_rays, floor_rays]), used)
    ok = (columns >= 2) & (ceiling_height > 0) & (floor_height < 0)
    return make_wall(direction, distance, ceiling_height, floor_height, ok)
