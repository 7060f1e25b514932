"""Walls sharing ceiling and floor heights: linear initial solve and maximum-likelihood refinement.

Every solver of paper Sections 4.1-4.3 fits walls ``(u_k, d_k)`` sharing
``h_c`` and ``h_f``, with the wall directions either known (Atlanta, eqs.
genx/geny) or all given by ONE yaw ``t`` (``u = (cos t, sin t)``: a single
wall, or the Manhattan walls ``u`` / ``u_perp``). This module holds the two
stages they share.

1. :func:`linear_walls` -- the DLT-like linear solve: the rows are split into
   the columns of the few shared unknowns ``B`` (``(1, h_c, h_f)`` or
   ``(u, v, w)``) and one distance column per wall; the distances are
   eliminated in closed form (each touches only its own wall's rows), and
   the shared unknowns are the null vector of the projected rows (an SVD
   with 3 or 6 columns instead of 3 + K or 6 + K).

2. :func:`refine_walls` -- Gauss-Newton on the ANGULAR residuals
   (:func:`angular_residual`): the elevation of the observed boundary ray minus
   the elevation at which the wall model predicts it, in the ray's own
   column. With Gaussian noise on the boundary rows (the network's output,
   and the paper's noise model in Section 5.3) this least squares is the
   maximum-likelihood fit of the 4 + K degrees of freedom. The algebraic
   linear solutions weigh far rays more and, for the paper's two-vector
   null space, mix in a second singular vector that is pure noise (with
   ``rc > 0`` the noise-free null space of eqs. manx/many is ONE-dimensional),
   which is why they are several times less accurate under noise (see
   experiments/RESULTS.md). On exact data both stages are exact.

Both stages (and :func:`search_scale`) take optional per-row weights, the
factors of the rows' residuals: the pipeline weighs down a boundary noisier
than the other (:func:`ncjax.pipeline.adjust.boundary_weights`).

The Gauss-Newton step uses the structure of the problem: each residual
depends on ``t``, one height and one distance, so the normal equations are
assembled with per-wall sums and solved through the 3 x 3 Schur complement
of the (diagonal) distance block.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry.fastmath import arctan2
from ..geometry.linalg import divide_if_significant, inverse_or_zero, scaled_null_space
from ..geometry.plucker import safe_norm


def rotate_2d(vector: Float[Array, "*batch 2"], angle: Float[Array, "*#batch"]) -> Float[Array, "*batch 2"]:
    """Counter-clockwise rotation of 2D vectors by ``angle``."""
    c, s = jnp.cos(angle)[..., None], jnp.sin(angle)[..., None]
    x, y = vector[..., 0:1], vector[..., 1:2]
    return jnp.concatenate([c * x - s * y, s * x + c * y], -1)


# --------------------------------------------------------------------------
# Linear initial solve
# --------------------------------------------------------------------------


def linear_walls(
    shared: Float[Array, "m n"],
    distance: Float[Array, " m"],
    row_wall: Int[Array, " m"],
    num_walls: int,
    row_weights: Float[Array, " m"] | None = None,
) -> tuple[Float[Array, " n"], Float[Array, " K"]]:
    """Least-squares null vector of ``[shared | distance columns]`` with the distances eliminated.

    The matrix has row ``i`` equal to ``shared[i]`` in the shared unknowns and
    ``distance[i]`` in the column of its wall (``row_wall[i]``). After unit
    rows, each wall's distance column is projected out of its own rows
    (``B_k - a_k (a_k^T B_k) / (a_k^T a_k)``: the distances minimise each
    wall's rows in closed form); the shared unknowns ``x`` are the
    least-squares null vector of the projected rows (:func:`scaled_null_space`,
    an SVD of ``m x n`` instead of ``m x (n + K)``; the scale is fixed on the
    shared unknowns, ``|x| = 1`` after column equilibration), and
    ``d_k = -(a_k^T B_k x) / (a_k^T a_k)``. The projection never forms
    ``B^T B``, so float32 keeps its accuracy; the per-wall sums are segment
    sums, so the cost does not grow with ``K``.

    Args:
        shared: coefficients of the shared unknowns, one row per ray.
        distance: coefficient of the row's wall distance.
        row_wall: the row's wall, -1 for unused rows (they count as zero rows).
        num_walls: static ``K``.
        row_weights: factor of each unit row (default 1), e.g. to weigh down a noisier boundary.

    Returns:
        ``(x, d)``: shared unknowns and distances (0 for walls without rows), one homogeneous scale.
    """
    used = row_wall >= 0
    row_scale = jnp.where(used, inverse_or_zero(safe_norm(jnp.concatenate([shared, distance[:, None]], -1))), 0.0)
    row_scale = row_scale * _ones_if_none(row_weights, row_wall, shared.dtype)
    shared = shared * row_scale[:, None]
    distance = distance * row_scale
    segment = _segments(row_wall, num_walls)
    inverse = inverse_or_zero(_wall_sums(distance * distance, segment, num_walls))  # 1 / (a_k^T a_k)
    coupling = inverse[:, None] * _wall_sums(distance[:, None] * shared, segment, num_walls)  # (K, n)
    projected = shared - distance[:, None] * _per_row(coupling, segment)
    x = scaled_null_space(projected, 1)[:, 0]
    return x, -(coupling @ x)


def _ones_if_none(row_weights: Float[Array, " m"] | None, row_wall: Int[Array, " m"], dtype) -> Float[Array, " m"]:
    return jnp.ones(row_wall.shape, dtype) if row_weights is None else row_weights


def _segments(row_wall: Int[Array, " m"], num_walls: int) -> Int[Array, " m"]:
    """Segment ids of the rows: their wall, ``num_walls`` for unused rows."""
    return jnp.where(row_wall >= 0, row_wall, num_walls)


def _wall_sums(values: Float[Array, "m ..."], segment: Int[Array, " m"], num_walls: int) -> Float[Array, "K ..."]:
    """Per-wall sums of per-row values (unused rows dropped)."""
    return jax.ops.segment_sum(values, segment, num_walls + 1)[:num_walls]


def _per_row(per_wall: Float[Array, "K ..."], segment: Int[Array, " m"]) -> Float[Array, "m ..."]:
    """Each row's wall's value (zero for unused rows)."""
    return jnp.concatenate([per_wall, jnp.zeros_like(per_wall[:1])])[segment]


def heights_of(vector: Float[Array, " n"]) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]]:
    """``(|u|, h_c, h_f)`` of ``W = (u, v, w, ...)`` by least squares ``v ~ h_c u``, ``w ~ h_f u``."""
    u, v, w = vector[0:2], vector[2:4], vector[4:6]
    norm = safe_norm(u)
    squared = jnp.where(norm > 0, norm * norm, 1.0)
    return norm, jnp.dot(u, v) / squared, jnp.dot(u, w) / squared


def yaw_parameters(vector: Float[Array, " n"]) -> tuple[Float[Array, " P"], Bool[Array, ""]]:
    """``(t, h_c, h_f, d_1..)`` of a linear solution ``W = (u, v, w, d_1..)``, and whether ``u != 0``.

    ``t`` is the angle of ``u``, heights by :func:`heights_of`, distances ``d_k / |u|``.
    """
    norm, h_c, h_f = heights_of(vector)
    ok = norm > 0
    yaw = jnp.arctan2(vector[1], jnp.where(ok, vector[0], 1.0))
    distances = vector[6:] / jnp.where(ok, norm, 1.0)
    return jnp.concatenate([jnp.stack([yaw, h_c, h_f]), distances]), ok


# --------------------------------------------------------------------------
# Maximum-likelihood refinement
# --------------------------------------------------------------------------


def column_geometry(rays: Float[Array, "m 6"]) -> tuple[Float[Array, "m 2"], Float[Array, " m"], Float[Array, "m 2"]]:
    """Per ray: horizontal unit azimuth ``a``, radius ``rc`` of its optical centre, and ``(cos phi, sin phi)``.

    A panorama ray (docs/design.md section 2) is ``xi = (cos phi a, sin phi)`` from
    the optical centre ``rc a``, so ``xibar = rc sin phi (a_y, -a_x, 0)``.
    ``rc`` is read where ``|sin phi|`` is not tiny (boundary rays never look
    at the horizon: the wall would be at infinity), 0 elsewhere.
    """
    cos_phi = safe_norm(rays[:, 0:2])
    sin_phi = rays[:, 2]
    a = rays[:, 0:2] * inverse_or_zero(cos_phi)[:, None]
    readable = jnp.abs(sin_phi) > jnp.sqrt(jnp.finfo(rays.dtype).eps)
    moment = rays[:, 3] * a[:, 1] - rays[:, 4] * a[:, 0]
    rc = jnp.where(readable, moment / jnp.where(readable, sin_phi, 1.0), 0.0)
    return a, rc, jnp.stack([cos_phi, sin_phi], -1)


class FitRows(NamedTuple):
    """The rows a wall fit uses (traced; ``m`` rows: each column's ceiling and floor boundary rays).

    Attributes:
        rays: the rays, one per row.
        base_directions: per row, its wall's direction at yaw 0.
        row_wall: per row, its wall (-1: the row is unused).
        is_floor: per row, floor (True) or ceiling ray.
        weights: factor of each row's residual, or None (1): the inverse of its noise gives the
            maximum-likelihood fit of rows of unequal independent noise (the pipeline uses its square,
            :func:`ncjax.pipeline.adjust.boundary_weights`).
    """

    rays: Float[Array, "m 6"]
    base_directions: Float[Array, "m 2"]
    row_wall: Int[Array, " m"]
    is_floor: Bool[Array, " m"]
    weights: Float[Array, " m"] | None = None

    def every(self, stride: int) -> FitRows:
        """Every ``stride``-th row."""
        return jax.tree.map(lambda x: x[::stride], self)


def angular_residual(
    line: tuple[Float[Array, ""], Float[Array, ""], Float[Array, ""]],
    base_direction: Float[Array, 2],
    ray: tuple[Float[Array, 2], Float[Array, ""], Float[Array, 2]],
) -> Float[Array, ""]:
    """Elevation error (radians) of one boundary ray against the wall line ``line = (yaw, h, d)``.

    ``ray``: its :func:`column_geometry` ``(azimuth, rc, observed)``.

    With ``u = rotate(base_direction, yaw)``, ``e2 = (-uy, ux)``, the column's
    vertical half-plane from the optical centre ``c = rc a`` meets the wall at
    horizontal distance ``s = g / q`` (``q = e2 . a``, ``g = d - e2 . c``), so the
    boundary is predicted in the in-plane direction ``(s, h)``; the residual is
    its signed angle to the observed ``(cos phi, sin phi)``. ``(g q, h q^2)`` is
    used for ``(s, h)``: the same direction without a division.
    """
    (yaw, height, distance), (azimuth, rc, observed) = line, ray
    u = rotate_2d(base_direction, yaw)
    q = jnp.dot(jnp.stack([-u[1], u[0]]), azimuth)
    g = distance - rc * q
    predicted = jnp.stack([g * q, height * q * q])
    cross = observed[0] * predicted[1] - observed[1] * predicted[0]
    dot = jnp.dot(observed, predicted)
    defined = (cross != 0) | (dot != 0)
    return jnp.where(defined, arctan2(cross, jnp.where(defined, dot, 1.0)), 0.0)


def _row_arguments(params, geometry, rows: FitRows):
    """The per-row arguments of :func:`angular_residual`, and which rows are used."""
    used = rows.row_wall >= 0
    heights = jnp.where(rows.is_floor, params[2], params[1])
    distances = params[3:][jnp.maximum(rows.row_wall, 0)]
    line = (jnp.broadcast_to(params[0], heights.shape), heights, distances)
    return (line, rows.base_directions, geometry), used


def residuals_of(params: Float[Array, " P"], geometry: tuple[Array, Array, Array], rows: FitRows) -> Float[Array, " m"]:
    """:func:`angular_residual` of every row times its weight (default 1; 0 for unused rows, ``row_wall`` -1);
    ``geometry``: the rows' :func:`column_geometry`."""
    arguments, used = _row_arguments(params, geometry, rows)
    weights = _ones_if_none(rows.weights, rows.row_wall, params.dtype)
    return jnp.where(used, weights * jax.vmap(angular_residual)(*arguments), 0.0)


def gauss_newton_step(
    params: Float[Array, " P"], geometry: tuple[Array, Array, Array], rows: FitRows, refine_yaw: bool
) -> tuple[Float[Array, ""], Float[Array, " P"]]:
    """The cost at ``params`` and the Gauss-Newton step from there, on the angular residuals of all used rows.

    ``params = (t, h_c, h_f, d_1..d_K)``. Rows with ``row_wall`` -1 are
    unused; each residual is multiplied by its row's weight (default 1).
    Parameters that no row constrains (absent walls, the yaw when not
    refined) do not move.

    Returns:
        ``(cost, delta)``: the sum of squared residuals at ``params`` (as
        :func:`squared_error`) and the increment ``delta`` of ``params``.
    """
    num_walls = params.shape[0] - 3
    row_wall, is_floor = rows.row_wall, rows.is_floor
    arguments, used = _row_arguments(params, geometry, rows)
    residual, (d_yaw, d_height, d_distance) = jax.vmap(jax.value_and_grad(angular_residual))(*arguments)
    mask = jnp.where(used, _ones_if_none(rows.weights, row_wall, params.dtype), 0.0)
    residual = residual * mask
    d_yaw = d_yaw * mask if refine_yaw else jnp.zeros_like(d_yaw)
    shared = (
        jnp.stack([d_yaw, jnp.where(is_floor, 0.0, d_height), jnp.where(is_floor, d_height, 0.0)], -1) * mask[:, None]
    )
    d_distance = d_distance * mask
    segment = _segments(row_wall, num_walls)
    # normal equations [[A, C], [C^T, diag(D)]] delta = -[b, e]
    a = shared.T @ shared
    c = _wall_sums(shared * d_distance[:, None], segment, num_walls).T
    inverse = inverse_or_zero(_wall_sums(d_distance * d_distance, segment, num_walls))
    b = shared.T @ residual
    e = _wall_sums(d_distance * residual, segment, num_walls)
    complement = a - (c * inverse[None, :]) @ c.T
    rhs = b - c @ (inverse * e)
    diagonal = jnp.diagonal(complement)
    free = diagonal > 1e3 * jnp.finfo(params.dtype).eps * jnp.max(jnp.abs(diagonal))
    scale = jnp.where(free, 1.0 / jnp.sqrt(jnp.where(free, diagonal, 1.0)), 0.0)
    scaled = scale[:, None] * complement * scale[None, :] + jnp.diag(jnp.where(free, 0.0, 1.0))
    delta_shared = -scale * jnp.linalg.solve(scaled, scale * rhs)
    delta_distances = -inverse * (e + c.T @ delta_shared)
    return jnp.sum(residual * residual), jnp.concatenate([delta_shared, delta_distances])


def _used_geometry(rays: Float[Array, "m 6"], row_wall: Int[Array, " m"]) -> tuple[Array, Array, Array]:
    """:func:`column_geometry` of the used rows (unused rows zeroed)."""
    return column_geometry(jnp.where((row_wall >= 0)[:, None], rays, 0.0))


def squared_error(geometry: tuple[Array, Array, Array], rows: FitRows):
    """The maximum-likelihood cost ``params -> sum of squared (weighted) angular residuals`` of these rows."""
    return lambda params: jnp.sum(residuals_of(params, geometry, rows) ** 2)


_SCALE_SEARCH_ROWS = 512


def search_scale(
    vector: Float[Array, " n"], rows: FitRows, floor_depths: Float[Array, " S"]
) -> tuple[Float[Array, " P"], Bool[Array, ""]]:
    """The start of :func:`refine_walls` for a linear solution ``(x_0, h_c, h_f, d_1..d_K)`` (Atlanta order).

    The metric scale is the weakest part of a linear solution: it rests on
    ``x_0``, the coefficient of the small offsets ``rc`` of the optical
    centres, while the ratios of ``h_c, h_f, d_k`` (the room's shape) rest
    on the whole ray directions. Under noise ``x_0`` can come out tiny or of
    the wrong sign and ``vector / x_0`` is then a room kilometres wide. So
    the shape is kept and the scale is chosen by the maximum-likelihood cost
    itself: among ``vector / x_0`` and the shape scaled to each camera
    height ``-h_f`` in ``floor_depths`` (metres), the candidate with the
    least sum of squared angular residuals wins. On exact data ``vector / x_0``
    has zero cost and is kept. The candidates are scored on at most
    ``_SCALE_SEARCH_ROWS`` evenly strided rows: the grid only brackets the
    scale, which :func:`refine_walls` then fits on every row. ``row_weights``
    as for :func:`refine_walls`.

    Returns:
        ``(params, ok)``: ``(0, h_c, h_f, d_1..d_K)`` and whether any candidate was finite.
    """
    x0, shape = vector[0], vector[1:]
    linear, linear_ok = divide_if_significant(shape, x0, safe_norm(vector))
    # a floor below the camera (h_f < 0) fixes the sign of the shape
    unit, shape_ok = divide_if_significant(shape, -shape[1], safe_norm(shape))
    scaled = floor_depths[:, None] * unit[None, :]
    candidates = jnp.concatenate([linear[None], scaled])
    valid = jnp.concatenate([linear_ok[None], jnp.broadcast_to(shape_ok, floor_depths.shape)])
    params = jnp.concatenate([jnp.zeros((candidates.shape[0], 1), vector.dtype), candidates], 1)
    stride = max(1, rows.rays.shape[0] // _SCALE_SEARCH_ROWS)
    weights = _ones_if_none(rows.weights, rows.row_wall, vector.dtype)
    sampled = rows._replace(weights=weights).every(stride)
    cost = squared_error(_used_geometry(sampled.rays, sampled.row_wall), sampled)
    costs = jax.vmap(cost)(params)
    costs = jnp.where(valid & jnp.all(jnp.isfinite(params), 1) & jnp.isfinite(costs), costs, jnp.inf)
    return params[jnp.argmin(costs)], jnp.any(jnp.isfinite(costs))


def refine_walls(params: Float[Array, " P"], rows: FitRows, refine_yaw: bool, steps: int = 3) -> Float[Array, " P"]:
    """Gauss-Newton on the angular residuals (:func:`angular_residual`) from ``params``.

    Args:
        params: initial ``(t, h_c, h_f, d_1..d_K)`` (from a linear solver).
        rows: the rows fitted, with their weights.
        refine_yaw: static; False keeps ``t`` (Atlanta: known directions).
        steps: static number of Gauss-Newton steps (3: converged to float
            precision from the linear solutions in our experiments).

    Returns:
        The refined ``(t, h_c, h_f, d_1..d_K)``.
    """
    geometry = _used_geometry(rows.rays, rows.row_wall)

    def step(_, state):
        params, current, delta = state
        candidate = params + delta
        # the candidate's linearisation gives its cost and, if it is accepted, the next step
        candidate_cost, candidate_delta = gauss_newton_step(candidate, geometry, rows, refine_yaw)
        # a step that does not decrease the cost (far from the optimum, degenerate data) is refused
        better = candidate_cost <= current
        return (
            jnp.where(better, candidate, params),
            jnp.where(better, candidate_cost, current),
            jnp.where(better, candidate_delta, delta),
        )

    # the first iteration linearises at ``params`` itself (a zero step, accepted unless its cost is not
    # finite), so that the program holds one linearisation: a loop, not ``steps`` unrolled copies
    start = (params, jnp.array(jnp.inf, params.dtype), jnp.zeros_like(params))
    params, _, _ = jax.lax.fori_loop(0, steps + 1, step, start)
    return params
