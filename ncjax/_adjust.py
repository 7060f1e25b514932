"""Final least-squares adjustment of the layout (paper Section 4.4, last step).

Minimises, over the wall directions, distances and the two heights,

* the reprojection error of the boundary pixels: per used column, the row of
  its wall's ceiling (floor) line minus the observed row, in pixels
  (:func:`ncjax._reprojection.wall_boundary_rows`), and
* a soft penalty on corners leaving the vertical planes of their corner rays:
  all rays of one panorama column lie in the vertical half-plane of its
  azimuth, so the penalty is the corner's column minus the detected corner
  column, in pixels, times ``corner_weight``. This is what pins walls that
  no column sees (those inserted for occlusions).

Solved with ``optimistix.least_squares`` (Levenberg-Marquardt, ``throw=False``)
and differentiable through the implicit-function theorem (optimistix's
default ``ImplicitAdjoint``). Gauge: none while ``rc > 0`` (scale is
observable, the heights and distances are absolute); the Manhattan
parametrisation has one yaw for all walls, the Atlanta one an angle per wall.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._camera import NonCentralPanorama, angles_to_pixel
from ._plucker import wall_planes_meet
from ._reprojection import wall_boundary_rows


class BoundaryObservations(eqx.Module):
    """The data the final adjustment fits (all fields traced; ``K`` wall slots).

    Attributes:
        ceiling_v: observed ceiling rows per column (W,).
        floor_v: observed floor rows per column (W,).
        ceiling_used: columns whose ceiling row enters the fit (RANSAC inliers).
        floor_used: columns whose floor row enters the fit.
        column_wall: the wall (slot) each column sees, -1 for none.
        corner_columns: per wall slot, the detected column of its start corner.
        corner_used: whether that corner is penalised (it is seen in the image).
        wall_mask: which slots hold walls; they are the first ``M`` slots.
    """

    ceiling_v: Float[Array, " W"]
    floor_v: Float[Array, " W"]
    ceiling_used: Bool[Array, " W"]
    floor_used: Bool[Array, " W"]
    column_wall: Int[Array, " W"]
    corner_columns: Float[Array, " K"]
    corner_used: Bool[Array, " K"]
    wall_mask: Bool[Array, " K"]


def previous_walls(wall_mask: Bool[Array, " K"]) -> Int[Array, " K"]:
    """Index of the previous wall in a closed loop of the first ``M`` slots: ``(k - 1) mod M``."""
    count = jnp.maximum(jnp.sum(wall_mask), 1)
    return (jnp.arange(wall_mask.shape[0]) - 1) % count


def loop_corners(
    directions: Float[Array, "K 2"], distances: Float[Array, " K"], wall_mask: Bool[Array, " K"]
) -> tuple[Float[Array, "K 2"], Bool[Array, " K"]]:
    """Corner ``k`` (start of wall ``k``) where wall ``k - 1`` meets wall ``k``, in the plane.

    Returns:
        ``(points, ok)``; ``ok`` is False for present walls parallel to their predecessor.
    """
    previous = previous_walls(wall_mask)
    points, ok = wall_planes_meet(directions[previous], distances[previous], directions, distances)
    return points, ok | ~wall_mask


def wrap_columns(offset: Float[Array, "*batch"], width: int) -> Float[Array, "*batch"]:
    """A column difference wrapped to ``[-W/2, W/2)``."""
    return (offset + width / 2) % width - width / 2


def layout_residuals(
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    corner_weight: float,
) -> Float[Array, " residuals"]:
    """Row errors of the ceiling and floor boundaries and weighted corner column errors (pixels)."""
    wall = jnp.maximum(observations.column_wall, 0)
    columns = jnp.arange(cam.width, dtype=distances.dtype)
    ceiling, floor, _ = wall_boundary_rows(
        cam, directions[wall], distances[wall], ceiling_height, floor_height, columns
    )
    ceiling_error = jnp.where(observations.ceiling_used, ceiling - observations.ceiling_v, 0.0)
    floor_error = jnp.where(observations.floor_used, floor - observations.floor_v, 0.0)
    points, _ = loop_corners(directions, distances, observations.wall_mask)
    corner_u, _ = angles_to_pixel(cam, jnp.arctan2(points[:, 1], points[:, 0]), 0.0)
    corner_error = wrap_columns(corner_u - observations.corner_columns, cam.width)
    corner_error = jnp.where(observations.corner_used & observations.wall_mask, corner_weight * corner_error, 0.0)
    return jnp.concatenate([ceiling_error, floor_error, corner_error])


def manhattan_directions(yaw: Float[Array, ""], labels: Int[Array, " K"]) -> Float[Array, "K 2"]:
    """Unit directions ``yaw + label * pi / 2``."""
    angle = yaw + labels * (math.pi / 2)
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)


def manhattan_yaw(directions: Float[Array, "K 2"], labels: Int[Array, " K"], wall_mask: Bool[Array, " K"]) -> Float[Array, ""]:
    """The yaw (modulo pi) that best fits directions labelled ``u`` (0) and ``u_perp`` (1)."""
    angle = jnp.arctan2(directions[:, 1], directions[:, 0]) - labels * (math.pi / 2)
    weight = wall_mask.astype(directions.dtype)
    return 0.5 * jnp.arctan2(jnp.sum(weight * jnp.sin(2 * angle)), jnp.sum(weight * jnp.cos(2 * angle)))


def adjust_layout(
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    labels: Int[Array, " K"] | None,
    corner_weight: float = 1.0,
    max_steps: int = 32,
    tolerance: float = 1e-6,
) -> tuple[Float[Array, "K 2"], Float[Array, " K"], Float[Array, ""], Float[Array, ""], Bool[Array, ""]]:
    """Levenberg-Marquardt refinement of a layout (see the module docstring).

    Args:
        cam: the camera.
        observations: boundaries, used columns and corners.
        directions: initial unit wall directions (K, 2).
        distances: initial signed distances (K,).
        ceiling_height: initial ``h_c``.
        floor_height: initial ``h_f``.
        labels: Manhattan labels (0: ``u``, 1: ``u_perp``) to keep the walls
            exactly Manhattan with one yaw; None (static) for free directions (Atlanta).
        corner_weight: static weight of the corner-plane penalty.
        max_steps: static iteration cap.
        tolerance: static relative and absolute tolerance.

    Returns:
        ``(directions, distances, h_c, h_f, improved)``; the initial values are
        kept (``improved`` False) when the result is not finite or does not
        lower the cost (an unconverged but better iterate is kept).
    """

    if labels is None:
        def unpack(y):
            angle, d, h = y
            return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1), d, h

        y0 = (jnp.arctan2(directions[:, 1], directions[:, 0]), distances, jnp.stack([ceiling_height, floor_height]))
    else:
        yaw = manhattan_yaw(directions, labels, observations.wall_mask)
        parametrised = manhattan_directions(yaw, labels)
        aligned = jnp.sign(jnp.sum(parametrised * directions, -1))

        def unpack(y):
            yaw, d, h = y
            return manhattan_directions(yaw, labels), d, h

        y0 = (yaw, distances * jnp.where(aligned == 0, 1.0, aligned), jnp.stack([ceiling_height, floor_height]))

    absent = ~observations.wall_mask

    def residuals(y, args):
        u, d, h = unpack(y)
        # pin the parameters of empty slots so that the Jacobian has full column rank
        # (the implicit adjoint solves with it); zero at the solution, so the fit is unchanged
        pins = [jnp.where(absent, d - y0[1], 0.0)]
        if labels is None:
            pins.append(jnp.where(absent, y[0] - y0[0], 0.0))
        return jnp.concatenate([layout_residuals(u, d, h[0], h[1], cam, observations, corner_weight), *pins])

    def cost(y):
        r = residuals(y, None)
        return jnp.sum(r * r)

    solution = optx.least_squares(
        residuals,
        optx.LevenbergMarquardt(rtol=tolerance, atol=tolerance),
        y0,
        max_steps=max_steps,
        throw=False,
    )
    final_cost = cost(solution.value)
    improved = jnp.isfinite(final_cost) & (final_cost <= cost(y0))
    y = jax.tree.map(lambda new, old: jnp.where(improved, new, old), solution.value, y0)
    u, d, h = unpack(y)
    return u, d, h[0], h[1], improved
