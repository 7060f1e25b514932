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

Solved by a fixed number of Levenberg-Marquardt iterations
(:func:`adjust_layout`). Each boundary row depends on four parameters only
(its wall's angle and distance and one height) and each corner on four (two
walls), so the normal equations are assembled from per-column 2 x 4 and
per-corner 1 x 4 Jacobians (forward mode) instead of a dense
``(2W + K) x P`` Jacobian and its QR. Gauge: none while ``rc > 0`` (scale is
observable, the heights and distances are absolute); the Manhattan
parametrisation has one yaw for all walls, the Atlanta one an angle per wall.
Differentiable by unrolling the iterations.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
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


def boundary_residuals(
    angle: Float[ArrayLike, ""],
    distance: Float[ArrayLike, ""],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    cam: NonCentralPanorama,
    column: Float[ArrayLike, ""],
    ceiling_v: Float[ArrayLike, ""],
    floor_v: Float[ArrayLike, ""],
) -> Float[Array, " 2"]:
    """Ceiling and floor row errors (pixels) of one column on its wall, the wall given by its angle."""
    direction = jnp.stack([jnp.cos(angle), jnp.sin(angle)])
    ceiling, floor, _ = wall_boundary_rows(cam, direction, distance, ceiling_height, floor_height, column)
    return jnp.stack([ceiling - ceiling_v, floor - floor_v])


def corner_residual(
    angles: Float[Array, " 2"],
    distances: Float[Array, " 2"],
    cam: NonCentralPanorama,
    corner_column: Float[ArrayLike, ""],
) -> Float[Array, ""]:
    """Column error (pixels) of the corner where wall ``(angles[0], distances[0])`` meets the next wall."""
    directions = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)
    point, _ = wall_planes_meet(directions[0], distances[0], directions[1], distances[1])
    corner_u, _ = angles_to_pixel(cam, jnp.arctan2(point[1], point[0]), 0.0)
    return wrap_columns(corner_u - corner_column, cam.width)


def _residual_terms(
    angles: Float[Array, " K"],
    distances: Float[Array, " K"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
) -> tuple[Float[Array, "W 2"], Float[Array, " K"]]:
    """Unweighted, unmasked row errors per column and column errors per corner (wall ``k`` at ``angles[k]``)."""
    wall = jnp.maximum(observations.column_wall, 0)
    columns = jnp.arange(cam.width, dtype=distances.dtype)
    rows = jax.vmap(boundary_residuals, in_axes=(0, 0, None, None, None, 0, 0, 0))(
        angles[wall], distances[wall], ceiling_height, floor_height, cam, columns, observations.ceiling_v, observations.floor_v
    )
    previous = previous_walls(observations.wall_mask)
    corners = jax.vmap(corner_residual, in_axes=(0, 0, None, 0))(
        jnp.stack([angles[previous], angles], -1),
        jnp.stack([distances[previous], distances], -1),
        cam,
        observations.corner_columns,
    )
    return rows, corners


def _used(observations: BoundaryObservations) -> tuple[Bool[Array, "W 2"], Bool[Array, " K"]]:
    """Which residual terms enter the fit."""
    rows = jnp.stack([observations.ceiling_used, observations.floor_used], -1)
    return rows, observations.corner_used & observations.wall_mask


def layout_residuals(
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    corner_weight: float,
) -> Float[Array, " residuals"]:
    """Row errors of the ceiling and floor boundaries and weighted corner column errors (pixels).

    Returns:
        ``2 W + K`` residuals: the ``W`` ceiling rows, the ``W`` floor rows, the corners; 0 where unused.
    """
    angles = jnp.arctan2(directions[:, 1], directions[:, 0])
    rows, corners = _residual_terms(angles, distances, ceiling_height, floor_height, cam, observations)
    rows_used, corners_used = _used(observations)
    rows = jnp.where(rows_used, rows, 0.0)
    return jnp.concatenate([rows[:, 0], rows[:, 1], jnp.where(corners_used, corner_weight * corners, 0.0)])


def manhattan_directions(yaw: Float[Array, ""], labels: Int[Array, " K"]) -> Float[Array, "K 2"]:
    """Unit directions ``yaw + label * pi / 2``."""
    angle = yaw + labels * (math.pi / 2)
    return jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)


def manhattan_yaw(directions: Float[Array, "K 2"], labels: Int[Array, " K"], wall_mask: Bool[Array, " K"]) -> Float[Array, ""]:
    """The yaw (modulo pi) that best fits directions labelled ``u`` (0) and ``u_perp`` (1)."""
    angle = jnp.arctan2(directions[:, 1], directions[:, 0]) - labels * (math.pi / 2)
    weight = wall_mask.astype(directions.dtype)
    return 0.5 * jnp.arctan2(jnp.sum(weight * jnp.sin(2 * angle)), jnp.sum(weight * jnp.cos(2 * angle)))


def _value_and_jacobian(fn, x: Float[Array, " m"]) -> tuple[Array, Array]:
    """``fn(x)`` and its Jacobian by forward mode, one pass for the ``m`` (few) inputs."""
    tangents = jnp.eye(x.shape[0], dtype=x.dtype)
    value, jacobian = jax.vmap(lambda t: jax.jvp(fn, (x,), (t,)), out_axes=(None, -1))(tangents)
    return value, jacobian


def _scatter_normal_equations(
    jacobians: Float[Array, "n r m"], residuals: Float[Array, "n r"], index: Int[Array, "n m"], size: int
) -> tuple[Float[Array, "P P"], Float[Array, " P"]]:
    """``J^T J`` and ``J^T r`` of a sparse ``J`` whose term group ``i`` depends on parameters ``index[i]`` only.

    Repeated indices within a group (one yaw for both walls of a Manhattan
    corner) add up, as the chain rule wants.
    """
    normal = jnp.einsum("nri,nrj->nij", jacobians, jacobians)
    gradient = jnp.einsum("nri,nr->ni", jacobians, residuals)
    matrix = jnp.zeros((size, size), residuals.dtype).at[index[:, :, None], index[:, None, :]].add(normal)
    return matrix, jnp.zeros(size, residuals.dtype).at[index].add(gradient)


def _damped_step(
    matrix: Float[Array, "P P"], gradient: Float[Array, " P"], damping: Float[Array, ""]
) -> Float[Array, " P"]:
    """Levenberg-Marquardt step ``-(H + damping diag(H))^-1 g``, Jacobi-scaled for float32.

    Parameters no term constrains (empty wall slots: their Jacobian columns
    are exactly zero) do not move; the scaling keeps far walls, whose rows
    barely move with the distance, from looking unconstrained.
    """
    diagonal = jnp.diagonal(matrix)
    free = diagonal > 0
    scale = jnp.where(free, 1.0 / jnp.sqrt(jnp.where(free, diagonal, 1.0)), 0.0)
    scaled = scale[:, None] * matrix * scale[None, :] + jnp.diag(jnp.where(free, damping, 1.0))
    return -scale * jnp.linalg.solve(scaled, scale * gradient)


def adjust_layout(
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    ceiling_height: Float[ArrayLike, ""],
    floor_height: Float[ArrayLike, ""],
    labels: Int[Array, " K"] | None,
    corner_weight: float = 1.0,
    steps: int = 8,
) -> tuple[Float[Array, "K 2"], Float[Array, " K"], Float[Array, ""], Float[Array, ""], Bool[Array, ""]]:
    """Levenberg-Marquardt refinement of a layout (see the module docstring).

    A fixed number of iterations (no ``while_loop``: under ``vmap`` a batch
    would run until its slowest member converges): each solves the damped
    normal equations, assembled from the per-column and per-corner Jacobians
    (:func:`_scatter_normal_equations`), and keeps the step only if it lowers
    the cost (damping / 3, else damping x 10).

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
        steps: static number of iterations.

    Returns:
        ``(directions, distances, h_c, h_f, improved)``; the initial values are
        kept (``improved`` False) when no step lowered the cost.
    """
    capacity = distances.shape[0]
    dtype = distances.dtype
    if labels is None:
        angles = jnp.arctan2(directions[:, 1], directions[:, 0])
        offsets = jnp.zeros(capacity, dtype)
        angle_index = jnp.arange(capacity)
    else:
        yaw = manhattan_yaw(directions, labels, observations.wall_mask)
        aligned = jnp.sign(jnp.sum(manhattan_directions(yaw, labels) * directions, -1))
        distances = distances * jnp.where(aligned == 0, 1.0, aligned)
        angles = yaw[None]
        offsets = labels.astype(dtype) * (math.pi / 2)
        angle_index = jnp.zeros(capacity, jnp.int32)
    # parameters y = (angles (K, or the one yaw), distances (K), h_c, h_f)
    y0 = jnp.concatenate([angles, distances, jnp.stack([ceiling_height, floor_height]).astype(dtype)])
    size = y0.shape[0]
    distance_index = angles.shape[0] + jnp.arange(capacity)
    heights = jnp.array([size - 2, size - 1])
    wall = jnp.maximum(observations.column_wall, 0)
    previous = previous_walls(observations.wall_mask)
    column_index = jnp.concatenate(
        [jnp.stack([angle_index[wall], distance_index[wall]], -1), jnp.broadcast_to(heights, (wall.shape[0], 2))], -1
    )
    corner_index = jnp.stack([angle_index[previous], angle_index, distance_index[previous], distance_index], -1)
    columns = jnp.arange(cam.width, dtype=dtype)
    rows_used, corners_used = _used(observations)

    def column_terms(local, offset, column, ceiling_v, floor_v):
        return boundary_residuals(local[0] + offset, local[1], local[2], local[3], cam, column, ceiling_v, floor_v)

    def corner_terms(local, offset, corner_column):
        return corner_weight * corner_residual(local[0:2] + offset, local[2:4], cam, corner_column)

    def column_arguments(y):
        return y[column_index], offsets[wall], columns, observations.ceiling_v, observations.floor_v

    def corner_arguments(y):
        return y[corner_index], jnp.stack([offsets[previous], offsets], -1), observations.corner_columns

    def cost(y):
        rows = jax.vmap(column_terms)(*column_arguments(y))
        corners = jax.vmap(corner_terms)(*corner_arguments(y))
        return jnp.sum(jnp.where(rows_used, rows, 0.0) ** 2) + jnp.sum(jnp.where(corners_used, corners, 0.0) ** 2)

    def normal_equations(y):
        def linearise(fn, local, *data):
            return _value_and_jacobian(lambda x: fn(x, *data), local)

        rows, row_jacobians = jax.vmap(lambda l, *d: linearise(column_terms, l, *d))(*column_arguments(y))
        corners, corner_jacobians = jax.vmap(lambda l, *d: linearise(corner_terms, l, *d))(*corner_arguments(y))
        # double where: unused terms (empty slots, parallel walls) may have non-finite derivatives
        rows, row_jacobians = jnp.where(rows_used, rows, 0.0), jnp.where(rows_used[..., None], row_jacobians, 0.0)
        corners = jnp.where(corners_used, corners, 0.0)[:, None]
        corner_jacobians = jnp.where(corners_used[:, None], corner_jacobians, 0.0)[:, None, :]
        matrix_rows, gradient_rows = _scatter_normal_equations(row_jacobians, rows, column_index, size)
        matrix_corners, gradient_corners = _scatter_normal_equations(corner_jacobians, corners, corner_index, size)
        return matrix_rows + matrix_corners, gradient_rows + gradient_corners

    def iterate(_, state):
        y, current, damping = state
        candidate = y + _damped_step(*normal_equations(y), damping)
        candidate_cost = cost(candidate)
        better = candidate_cost < current  # False for NaN
        return (
            jnp.where(better, candidate, y),
            jnp.where(better, candidate_cost, current),
            jnp.where(better, damping / 3, damping * 10),
        )

    initial = cost(y0)
    y, final, _ = jax.lax.fori_loop(0, steps, iterate, (y0, initial, jnp.asarray(1e-3, dtype)))
    improved = jnp.isfinite(final) & (final < initial)
    angles, distances, heights = y[: angles.shape[0]], y[angles.shape[0] : -2], y[-2:]
    angles = angles[angle_index] + offsets
    return jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1), distances, heights[0], heights[1], improved
