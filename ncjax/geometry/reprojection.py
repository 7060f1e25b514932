"""Where a wall's ceiling and floor lines appear in the panorama, column by column.

The rays of column ``u`` leave the optical centre ``o = rc a`` (``a`` the unit
horizontal direction of the column's azimuth) in the vertical half-plane of
``a`` (paper eqs. forward and pluckerray). That half-plane meets the wall
plane ``e2 . p = d`` at horizontal range ``t = d / (e2 . a) - rc`` from
``o``; the wall's ceiling line is then seen at elevation ``atan2(h_c, t)``
and its floor line at ``atan2(h_f, t)``. This closed form is the forward
model of the RANSAC inlier test and of the final adjustment (reprojection
error in pixels, per column).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles
from .fastmath import arctan2


def column_directions(cam: NonCentralPanorama, column: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 2"]:
    """Unit horizontal direction ``a = (cos varphi, sin varphi)`` of each column's half-plane."""
    azimuth, _ = pixel_to_angles(cam, column, 0.0)
    return jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)


def range_along(
    cam: NonCentralPanorama,
    direction: Float[ArrayLike, "*#batch 2"],
    distance: Float[ArrayLike, "*#batch"],
    column_direction: Float[ArrayLike, "*#batch 2"],
) -> Float[Array, "*batch"]:
    """Horizontal range ``t`` from a column's optical centre to the wall plane.

    The column is given by the unit direction ``column_direction`` of its
    half-plane (:func:`column_directions`). ``inf`` where the half-plane is
    parallel to the wall; negative where the wall is behind the optical centre.
    """
    direction, column_direction = jnp.asarray(direction), jnp.asarray(column_direction)
    facing = direction[..., 0] * column_direction[..., 1] - direction[..., 1] * column_direction[..., 0]  # e2 . a
    hit = jnp.abs(facing) > 0
    return jnp.where(hit, distance / jnp.where(hit, facing, 1.0), jnp.inf) - cam.rc


def boundary_rows_along(
    cam: NonCentralPanorama,
    direction: Float[ArrayLike, "*#batch 2"],
    distance: Float[ArrayLike, "*#batch"],
    ceiling_height: Float[ArrayLike, "*#batch"],
    floor_height: Float[ArrayLike, "*#batch"],
    column_direction: Float[ArrayLike, "*#batch 2"],
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"], Bool[Array, "*batch"]]:
    """:func:`wall_boundary_rows` of the column whose half-plane has the unit direction ``column_direction``.

    The rows depend on the column only through ``a`` (equirectangular rows
    are a function of the elevation alone), so a caller that evaluates the
    same columns many times (the final adjustment) computes ``a`` once.
    """
    t = range_along(cam, direction, distance, column_direction)
    seen = jnp.isfinite(t) & (t > 0)
    t = jnp.where(seen, t, 1e-3)
    _, ceiling_v = angles_to_pixel(cam, 0.0, arctan2(ceiling_height, t))
    _, floor_v = angles_to_pixel(cam, 0.0, arctan2(floor_height, t))
    return ceiling_v, floor_v, seen


def wall_boundary_rows(
    cam: NonCentralPanorama,
    direction: Float[ArrayLike, "*#batch 2"],
    distance: Float[ArrayLike, "*#batch"],
    ceiling_height: Float[ArrayLike, "*#batch"],
    floor_height: Float[ArrayLike, "*#batch"],
    column: Float[ArrayLike, "*#batch"],
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"], Bool[Array, "*batch"]]:
    """Rows at which a wall's ceiling and floor lines cross column ``column``.

    Args:
        cam: the camera.
        direction: unit wall direction ``u``.
        distance: signed distance ``d`` along ``e2 = (-uy, ux)``.
        ceiling_height: ``h_c``.
        floor_height: ``h_f``.
        column: column coordinates (pixel-centre convention).

    Returns:
        ``(ceiling_v, floor_v, seen)``; where ``seen`` is False (wall behind or
        parallel to the column's half-plane) the rows are those of a wall at
        1 mm, finite with finite gradients.
    """
    return boundary_rows_along(cam, direction, distance, ceiling_height, floor_height, column_directions(cam, column))


def boundary_points(
    cam: NonCentralPanorama,
    column: Float[ArrayLike, "*#batch"],
    row: Float[ArrayLike, "*#batch"],
    height: Float[ArrayLike, "*#batch"],
) -> tuple[Float[Array, "*batch 2"], Bool[Array, "*batch"]]:
    """Plan-view point of a boundary pixel whose 3D point lies at a known height (inverse of the above).

    The pixel's ray rises at elevation ``phi`` from ``rc a``; it reaches
    ``z = height`` at range ``t = height / tan(phi)``, i.e. at ``(rc + t) a``.

    Returns:
        ``(point, ok)``; ``ok`` is False where the ray never reaches that height.
    """
    azimuth, elevation = pixel_to_angles(cam, column, row)
    slope = jnp.tan(elevation)
    ok = (slope * height > 0) & jnp.isfinite(slope)
    t = height / jnp.where(ok, slope, 1.0)
    radius = jnp.where(ok, cam.rc + t, 0.0)
    return jnp.stack([radius * jnp.cos(azimuth), radius * jnp.sin(azimuth)], -1), ok


def boundary_ranges(
    cam: NonCentralPanorama, rows: Float[Array, " W"], height: Float[ArrayLike, ""]
) -> tuple[Float[Array, " W"], Float[Array, " W"]]:
    """Azimuth and range from the axis of each column's boundary point at ``height`` (:func:`boundary_points`).

    The column's ray leaves ``rc (cos varphi, sin varphi, 0)`` at elevation ``phi`` and meets ``z = height`` at
    horizontal range ``height / tan(phi)`` from that centre (paper eq. pluckerray): ``rc + height / tan(phi)`` from
    the axis; NaN where the ray never reaches that height (a row at or beyond the horizon, or a NaN row).
    """
    columns = jnp.arange(rows.shape[0], dtype=rows.dtype)
    azimuth, _ = pixel_to_angles(cam, columns, rows)
    points, reached = boundary_points(cam, columns, rows, height)
    # the point's coordinate along its own azimuth: its range, with a gradient also where it is not reached
    along = points[..., 0] * jnp.cos(azimuth) + points[..., 1] * jnp.sin(azimuth)
    return azimuth, jnp.where(reached, along, jnp.nan)


def fit_plan_lines(
    points: Float[Array, "n 2"], weights: Float[Array, " n"], segments: Int[Array, " n"], num_segments: int
) -> tuple[Float[Array, "S 2"], Float[Array, " S"]]:
    """Total-least-squares lines through weighted plan points, one per segment: ``(directions, distances)``.

    Each point belongs to segment ``segments[i]`` (``num_segments`` static; an
    index outside ``[0, S)`` drops the point). The direction is the principal
    axis of the segment's weighted scatter (closed form for 2 x 2);
    ``distance = e2 . centroid`` with ``e2 = (-uy, ux)``. Sums per segment, so
    the cost is one pass over the points whatever ``S``.
    """
    total = jax.ops.segment_sum(weights, segments, num_segments)
    total = jnp.maximum(total, jnp.finfo(points.dtype).tiny)
    centroid = jax.ops.segment_sum(weights[:, None] * points, segments, num_segments) / total[:, None]
    centred = points - centroid[jnp.clip(segments, 0, num_segments - 1)]
    moments = jnp.stack([centred[:, 0] ** 2, centred[:, 1] ** 2, centred[:, 0] * centred[:, 1]], -1)
    sxx, syy, sxy = jax.ops.segment_sum(weights[:, None] * moments, segments, num_segments).T
    # no spread (an empty or one-point wall): any direction; the double where keeps the gradient of atan2(0, 0) finite
    spread = (sxy != 0) | (sxx != syy)
    angle = 0.5 * jnp.arctan2(jnp.where(spread, 2 * sxy, 0.0), jnp.where(spread, sxx - syy, 1.0))
    directions = jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)
    return directions, directions[:, 0] * centroid[:, 1] - directions[:, 1] * centroid[:, 0]


def fit_plan_line(
    points: Float[Array, "n 2"], weights: Float[Array, " n"]
) -> tuple[Float[Array, " 2"], Float[Array, ""]]:
    """:func:`fit_plan_lines` of one line through all the points."""
    directions, distances = fit_plan_lines(points, weights, jnp.zeros(points.shape[0], jnp.int32), 1)
    return directions[0], distances[0]
