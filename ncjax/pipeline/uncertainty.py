"""First-order covariance of an adjusted layout (corners and heights)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import jax.scipy.linalg
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama
from ..geometry.linalg import inverse_or_zero
from ..geometry.plucker import safe_sqrt
from ..solvers.settings import scaled
from .adjust import (
    BoundaryObservations,
    layout_least_squares,
    loop_corners,
    used_rows,
)
from .config import AdjustmentConfig, UncertaintyConfig
from .sparse_normal import (
    jacobian_product,
    normal_matrix,
    probe_jacobian,
    scale_columns,
    squared_column_norms,
    transpose_product,
)
from .types import Walls

# longest lag (columns of a 1024-wide panorama) over which the boundary rows' errors count as correlated
CORRELATION_COLUMNS = 256.0

_LAGS_PER_ITERATION = 8


def correlation_time(
    rows: Float[Array, "2 N"], used: Bool[Array, "2 N"], column_wall: Int[Array, " N"], max_lag: int
) -> Float[Array, ""]:
    """Integrated autocorrelation time ``tau = 1 + 2 sum_k rho_k`` of the row residuals along the columns.

    ``rho_k`` is the correlation of the residuals of two used rows ``k``
    observations apart on one wall (ceiling and floor pooled). The sum stops
    before the first ``rho_k <= 0`` (a simple form of Geyer's initial positive
    sequence: past it the estimates are noise) or at ``max_lag`` (static).
    ``N / tau`` is the effective number of independent rows: a network's
    boundary errors are smooth along a wall, and treating them as independent
    would make the covariance far too small.
    """
    variance = jnp.sum(jnp.where(used, rows * rows, 0.0)) / jnp.maximum(jnp.sum(used), 1)

    def correlation(lag):
        # cyclic: the last column of a panorama neighbours the first
        pair = used & jnp.roll(used, -lag, 1) & (column_wall == jnp.roll(column_wall, -lag))[None, :]
        product = jnp.sum(jnp.where(pair, rows * jnp.roll(rows, -lag, 1), 0.0)) / jnp.maximum(jnp.sum(pair), 1)
        return product / jnp.where(variance > 0, variance, 1.0)

    # a few lags per loop iteration: one panorama alone pays the loop's overhead per iteration
    iterations = -(-max_lag // _LAGS_PER_ITERATION)
    chunks = jax.lax.map(
        lambda first: jnp.stack([correlation(first + j) for j in range(_LAGS_PER_ITERATION)]),
        1 + _LAGS_PER_ITERATION * jnp.arange(iterations),
    )
    correlations = chunks.reshape(-1)[:max_lag]
    counted = jnp.cumprod(correlations > 0)
    return 1.0 + 2.0 * jnp.sum(counted * correlations)


class LayoutUncertainty(eqx.Module):
    """Gauss-Newton covariance of an adjusted layout (all fields traced).

    Attributes:
        corner_covariance: (K, 2, 2) covariance of each corner's plan position (m^2); zero for empty slots.
        height_covariance: (2, 2) covariance of ``(h_c, h_f)`` (m^2).
        row_sigma: (2,) the estimated noise of the ceiling and of the floor rows, pixels (RMS of each
            boundary's used rows' residuals, per degree of freedom; 0 for a boundary without used rows).
        correlation_time: :func:`correlation_time` of the used rows' weighted residuals (the covariance
            is scaled by it).
    """

    corner_covariance: Float[Array, "K 2 2"]
    height_covariance: Float[Array, "2 2"]
    row_sigma: Float[Array, " 2"]
    correlation_time: Float[Array, ""]


def not_computed(capacity: int, dtype) -> LayoutUncertainty:
    """A :class:`LayoutUncertainty` of NaNs, for a pipeline configured without covariances."""

    def nan(*shape):
        return jnp.full(shape, jnp.nan, dtype)

    return LayoutUncertainty(nan(capacity, 2, 2), nan(2, 2), nan(2), nan())


def room_height_sigma(height_covariance: Float[ArrayLike, "*#batch 2 2"]) -> Float[Array, "*batch"]:
    """Standard deviation (m) of the room height ``h_c - h_f`` under a covariance of ``(h_c, h_f)``.

    Infinite where the covariance is not finite (a fit that does not
    determine the heights, or covariances not computed).
    """
    covariance = jnp.asarray(height_covariance)
    variance = covariance[..., 0, 0] + covariance[..., 1, 1] - 2 * covariance[..., 0, 1]
    return jnp.where(jnp.isfinite(variance), jnp.sqrt(jnp.maximum(jnp.nan_to_num(variance), 0.0)), jnp.inf)


def _wall_offset_spread(
    jacobian: Float[Array, "R A"],
    structure,
    inverse: Float[Array, "P P"],
    observations: BoundaryObservations,
    sigma: Float[Array, " 2"],
) -> Float[Array, "offsets P"]:
    """Rows ``s_b (A^-1 J^T u_wb)^T`` whose Gram matrix is the per-wall offsets' share of the covariance.

    ``u_wb`` indicates the used rows of boundary ``b`` on wall ``w``, ``s_b = sigma[b]`` the offset's standard
    deviation in the fit's weighted units (see :func:`layout_uncertainty`).
    """
    count = observations.columns.shape[0]
    slots = observations.wall_mask.shape[0]
    on_wall = used_rows(observations)[:, None, :] & (
        observations.column_wall[None, None, :] == jnp.arange(slots)[None, :, None]
    )  # (2, K, N)
    indicators = jnp.zeros((2, slots, jacobian.shape[0]), jacobian.dtype)
    indicators = indicators.at[0, :, :count].set(on_wall[0]).at[1, :, count : 2 * count].set(on_wall[1])
    gradients = jax.vmap(lambda u: transpose_product(jacobian, structure, u))(indicators.reshape(2 * slots, -1))
    return jnp.repeat(sigma, slots)[:, None] * (gradients @ inverse)


# A weak prior on every parameter, in units of its own scale (the equilibrated normal matrix has a unit
# diagonal): 1e-6 of the information the rows give a parameter that they alone fix, so a standard deviation
# 1000 times that parameter's. float32
# Cholesky fails from a condition number of about 1e7 (a wall seen by a few columns at a grazing angle), which
# made every covariance of the layout infinite; with the prior, a direction the rows fix keeps its variance
# and one they hardly fix gets about 1e6 times the rows' noise, so whatever depends on it stays uncertain.
COVARIANCE_RIDGE = 1e-6


def layout_uncertainty(
    cam: NonCentralPanorama,
    observations: BoundaryObservations,
    walls: Walls,
    labels: Int[Array, " K"] | None,
    adjustment: AdjustmentConfig = AdjustmentConfig(),
    config: UncertaintyConfig = UncertaintyConfig(),
) -> LayoutUncertainty:
    """First-order covariance of the corners and heights of a layout that :func:`adjust_layout` returned.

    With ``J`` the Jacobian of the adjustment's (weighted) residuals in its own
    parameters (one yaw or an angle per wall, distances, heights), the
    parameter covariance is the sandwich ``tau (J^T J)^-1 J^T V J (J^T J)^-1``:
    ``V`` is diagonal, each boundary's rows at their own variance (their sum of
    squared residuals over their count minus their share of the free parameters;
    the corner rows at that of all rows), ``tau`` the rows' :func:`correlation_time`.
    When both boundaries' weighted rows are equally noisy, as the weights of
    independent noise would make them, it is ``tau sigma^2 (J^T J)^-1``.

    Rows may also share an error along a whole wall (a network that follows a
    skirting board or a furniture edge): an offset per wall and boundary, of
    standard deviation ``hypot(config.wall_offset_ratio sigma_b, config.wall_offset_noise)``
    (``sigma_b`` the boundary's row noise above). The fit absorbs such an
    offset into the wall, so its residuals cannot show it; its share
    ``(J^T J)^-1 J^T u u^T J (J^T J)^-1`` per wall (``u`` the wall's used
    rows) is added to the sandwich, and does not shrink as the wall's
    columns grow. Likewise a corner detector's column error: the corner rows'
    variance is the rows' pooled one plus ``(corner_weight config.corner_column_noise)^2``.
    It is propagated to
    each corner's plan position through the Jacobian of the corner (where
    consecutive walls meet). It describes the noise of the rows, not a
    wrong wall structure (a missed or extra corner).

    A weak prior (``COVARIANCE_RIDGE``) keeps ``J^T J`` invertible in float32:
    the directions the rows hardly fix get huge variances, not a failed
    factorisation. A parameter that no residual depends on (a wall that no used
    row or corner row sees) gets an infinite variance: the corners of that wall,
    or the heights if it is one of them.

    Args:
        cam, observations, walls, labels: as for :func:`~ncjax.pipeline.adjust.adjust_layout`; the walls are
            its result.
        adjustment: the adjustment's settings: its ``corner_weight``, and its column ``stride``, which sets
            the largest lag of :func:`correlation_time` (``CORRELATION_COLUMNS`` columns of a 1024-column
            panorama, in observations).
        config: the per-wall offset's standard deviation, as a multiple of the rows' noise
            (``wall_offset_ratio``) and in pixels of a 512-row panorama (``wall_offset_noise``), and the
            detected corner columns' standard deviation in columns of a 1024-column one (``corner_column_noise``).

    Returns:
        A :class:`LayoutUncertainty`; infinite where a parameter is free (see above).
    """
    corner_weight = adjustment.corner_weight
    max_lag = max(1, round(scaled(CORRELATION_COLUMNS, cam.width, 1024) / adjustment.stride))
    wall_offset_noise = config.wall_offset_noise * scaled(1.0, cam.height, 512)
    corner_column_noise = config.corner_column_noise * scaled(1.0, cam.width, 1024)
    problem, residuals, structure = layout_least_squares(cam, observations, walls, labels, corner_weight)
    flat, unravel = jax.flatten_util.ravel_pytree(problem.start)
    values, linear = jax.linearize(lambda f: residuals(unravel(f)), flat)
    jacobian = probe_jacobian(linear, structure, flat.dtype)
    count = observations.columns.shape[0]
    rows = jnp.stack([values[:count], values[count : 2 * count]])  # weighted by observations.row_weights
    used = used_rows(observations)
    walls = jnp.sum(observations.wall_mask)
    free = 2 + walls + jnp.sum(problem.angle_used)
    squares = jnp.sum(jnp.where(used, rows * rows, 0.0), axis=1)
    pooled_variance = jnp.sum(squares) / jnp.maximum(jnp.sum(used) - free, 1)
    # each boundary's own variance (its weighted rows' noise differs when the weights are off), the free
    # parameters' degrees of freedom shared out by the rows' counts
    counts = jnp.sum(used, axis=1)
    degrees = counts * (1.0 - free / jnp.maximum(jnp.sum(counts), 1))
    boundary_variance = squares / jnp.maximum(degrees, 1.0)
    # on the weighted rows: exact rows, whose residuals are float rounding, do not count
    tau = correlation_time(rows, used, observations.column_wall, max_lag)
    residual_variance = jnp.concatenate(
        [
            jnp.repeat(boundary_variance, count),
            jnp.full(values.shape[0] - 2 * count, pooled_variance + (corner_weight * corner_column_noise) ** 2),
        ]
    )
    # unit columns first: angles (radians) and lengths (metres) differ in scale, and float32
    # inverts the equilibrated normal matrix far more accurately (no negative variances)
    # (the columns are scaled before their products, not after: J^T J spans 1e9 and float32 loses the difference)
    norms = safe_sqrt(squared_column_norms(jacobian, structure))
    scale = inverse_or_zero(norms)
    scaled_jacobian = scale_columns(jacobian, structure, scale)
    identity = jnp.eye(flat.shape[0], dtype=flat.dtype)
    cholesky = jnp.linalg.cholesky(normal_matrix(scaled_jacobian, structure) + COVARIANCE_RIDGE * identity)
    inverse = jax.scipy.linalg.cho_solve((cholesky, True), identity)
    # the sandwich (J^T J)^-1 J^T V J (J^T J)^-1 (the fit's weights need not be the rows' inverse
    # variances) as the Gram matrix of V^1/2 J (J^T J)^-1: positive semi-definite in float32 too, which
    # the product of the three matrices is not where J^T J is ill-conditioned
    spread = jax.vmap(
        lambda column: jacobian_product(scaled_jacobian * safe_sqrt(residual_variance)[:, None], structure, column),
        in_axes=1,
        out_axes=1,
    )(inverse)
    # the prior's share of the sandwich, (A^-1 (J^T V J + ridge s I) A^-1 with A = J^T J + ridge I): without it a
    # direction the rows leave free (J v = 0) would get variance 0 instead of s / ridge
    prior = safe_sqrt(COVARIANCE_RIDGE * pooled_variance) * inverse
    offset_sigma = jnp.sqrt(
        config.wall_offset_ratio**2 * boundary_variance + (wall_offset_noise * observations.row_weights) ** 2
    )  # weighted units: a weight times pixels
    offsets = _wall_offset_spread(scaled_jacobian, structure, inverse, observations, offset_sigma)
    sandwich = tau * (spread.T @ spread + prior.T @ prior) + offsets.T @ offsets
    covariance = scale[:, None] * sandwich * scale[None, :]
    # a parameter no residual depends on (a wall that no used row or corner row sees, a height without rows) has
    # scale 0, hence covariance 0: what depends on it is set infinite below
    unconstrained = norms == 0
    failed = ~jnp.all(jnp.isfinite(covariance))
    covariance = jnp.where(failed, 0.0, covariance)

    def corners(f):
        corner_walls = problem.walls(unravel(f))
        return loop_corners(corner_walls.directions, corner_walls.distances, observations.wall_mask)[0]

    corner_jacobian = jax.jacfwd(corners)(flat)  # (K, 2, P)
    corner_covariance = jnp.einsum("kip,pq,kjq->kij", corner_jacobian, covariance, corner_jacobian)
    loose = failed | jnp.any((corner_jacobian != 0) & unconstrained, axis=(1, 2))
    corner_covariance = jnp.where(
        observations.wall_mask[:, None, None], jnp.where(loose[:, None, None], jnp.inf, corner_covariance), 0.0
    )
    height_covariance = jnp.where(failed | jnp.any(unconstrained[-2:]), jnp.inf, covariance[-2:, -2:])
    row_sigma = safe_sqrt(boundary_variance) / observations.row_weights
    return LayoutUncertainty(corner_covariance, height_covariance, row_sigma, tau)
