"""Per-wall RANSAC with the single-wall solver (paper Section 4.4).

Each hypothesis is :func:`ncjax.solve_wall` on ``k`` sampled columns (one
ceiling and one floor ray each: the paper's ``k = 3``); it is scored by the
number of boundary pixels it reprojects within a threshold (pixels, the
closed form of :mod:`ncjax._reprojection`), and the best one is refitted on
its inliers. The number of hypotheses is the paper's
``n_hyp = log(1 - P) / log(1 - (1 - eps)^k)``, a static integer, so all
hypotheses are solved at once with ``jax.vmap``.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ._camera import NonCentralPanorama
from ._reprojection import wall_boundary_rows
from ._wall import Wall, solve_wall


def num_hypotheses(success_probability: float, outlier_rate: float, sample_size: int) -> int:
    """The paper's ``n_hyp = log(1 - P) / log(1 - (1 - eps)^k)``, rounded up.

    ``P = 0.9999``, ``eps = 0.2``, ``k = 3`` give 12.84, hence 13 hypotheses.

    Raises:
        ValueError: for probabilities outside (0, 1) or a sample size below 1.
    """
    if not 0.0 < success_probability < 1.0 or not 0.0 <= outlier_rate < 1.0 or sample_size < 1:
        raise ValueError(
            f"need 0 < P < 1, 0 <= outlier rate < 1, sample size >= 1; got P={success_probability}, "
            f"eps={outlier_rate}, k={sample_size}"
        )
    inlier_sample = (1.0 - outlier_rate) ** sample_size
    if inlier_sample >= 1.0:
        return 1
    return max(1, math.ceil(math.log(1.0 - success_probability) / math.log(1.0 - inlier_sample)))


def sample_columns(key: PRNGKeyArray, candidates: Bool[Array, " W"], sample_size: int) -> Int[Array, " k"]:
    """``sample_size`` distinct columns drawn uniformly among the candidates."""
    scores = jnp.where(candidates, jax.random.uniform(key, candidates.shape), -1.0)
    return jax.lax.top_k(scores, sample_size)[1]


def boundary_errors(
    cam: NonCentralPanorama, wall: Wall, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"]
) -> tuple[Float[Array, " W"], Float[Array, " W"]]:
    """Per column, the row distance (pixels) between a wall's reprojected lines and the boundaries.

    ``inf`` where the wall is not in front of the column.
    """
    columns = jnp.arange(cam.width, dtype=ceiling_v.dtype)
    ceiling, floor, seen = wall_boundary_rows(
        cam, wall.direction, wall.distance, wall.ceiling_height, wall.floor_height, columns
    )
    return jnp.where(seen, jnp.abs(ceiling - ceiling_v), jnp.inf), jnp.where(seen, jnp.abs(floor - floor_v), jnp.inf)


def ransac_wall(
    key: PRNGKeyArray,
    cam: NonCentralPanorama,
    ceiling_rays: Float[Array, "W 6"],
    floor_rays: Float[Array, "W 6"],
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    candidates: Bool[Array, " W"],
    num_hypotheses: int,
    sample_size: int,
    inlier_threshold: float,
    min_height: float = 0.1,
) -> tuple[Wall, Bool[Array, " W"], Bool[Array, " W"]]:
    """The wall that best explains the boundaries of the candidate columns.

    Args:
        key: PRNG key.
        cam: the camera.
        ceiling_rays: per-column rays of the ceiling boundary.
        floor_rays: per-column rays of the floor boundary.
        ceiling_v: per-column ceiling rows (for the inlier test).
        floor_v: per-column floor rows.
        candidates: the columns of this wall (finite rows, away from corners).
        num_hypotheses: static number of hypotheses (:func:`num_hypotheses`).
        sample_size: static number of columns per hypothesis (>= 3).
        inlier_threshold: maximum row error of an inlier, pixels.
        min_height: static; walls whose ceiling or floor is closer than this
            to the camera's plane are rejected (:func:`plausible_wall`).

    Returns:
        ``(wall, ceiling_inliers, floor_inliers)``; the wall refitted on the
        inliers of the best hypothesis, then the inliers of the refit.
        ``wall.ok`` is False when fewer than ``sample_size`` candidates exist
        or no hypothesis is valid.
    """
    samples = jax.vmap(sample_columns, in_axes=(0, None, None))(
        jax.random.split(key, num_hypotheses), candidates, sample_size
    )
    sure = jnp.ones(sample_size, bool)
    hypotheses = jax.vmap(lambda s: solve_wall(ceiling_rays[s], floor_rays[s], sure, sure))(samples)
    ceiling_error, floor_error = jax.vmap(boundary_errors, in_axes=(None, 0, None, None))(
        cam, hypotheses, ceiling_v, floor_v
    )
    ceiling_in = candidates & (ceiling_error < inlier_threshold)
    floor_in = candidates & (floor_error < inlier_threshold)
    valid = jax.vmap(plausible_wall, in_axes=(0, None))(hypotheses, min_height)
    score = jnp.where(valid, jnp.sum(ceiling_in, 1) + jnp.sum(floor_in, 1), -1)
    best = jnp.argmax(score)
    refit = solve_wall(ceiling_rays, floor_rays, ceiling_in[best], floor_in[best])
    # the algebraic refit can slide to the degenerate tiny wall; keep the hypothesis then
    wall = jax.tree.map(
        lambda r, h: jnp.where(plausible_wall(refit, min_height), r, h[best]), refit, hypotheses
    )
    ceiling_error, floor_error = boundary_errors(cam, wall, ceiling_v, floor_v)
    ceiling_in = candidates & (ceiling_error < inlier_threshold)
    floor_in = candidates & (floor_error < inlier_threshold)
    enough = jnp.sum(candidates) >= sample_size
    ok = plausible_wall(wall, min_height) & enough & (score[best] >= 0)
    return eqx.tree_at(lambda w: w.ok, wall, ok), ceiling_in, floor_in


def plausible_wall(wall: Wall, min_height: float) -> Bool[Array, ""]:
    """A solved wall that can bound a room: ceiling above and floor below the camera by ``min_height``.

    With little parallax (small ``rc``, far walls) and noise, the algebraic
    solution can shrink towards the degenerate wall of height 0 that touches
    the circle of optical centres; its rows still look plausible, so it is
    rejected here.
    """
    return wall.ok & (wall.ceiling_height > min_height) & (wall.floor_height < -min_height)
