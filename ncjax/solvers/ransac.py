"""Per-wall RANSAC with the single-wall solver (paper Section 4.4).

Each hypothesis is :func:`~.wall.solve_wall` on ``k`` sampled columns (one ceiling and one floor ray each: the paper's
``k = 3``; with a height prior's known heights :func:`~.wall_at_heights.solve_wall_at_heights`); it is scored by the
number of boundary pixels it reprojects within a threshold (pixels, the closed form of
:mod:`ncjax.geometry.reprojection`, tested as directions: :func:`inlier_rows`), and the best one is refitted on its
inliers. Hypotheses are scored and refitted on at most ``G`` columns of the wall (:func:`wall_columns`), so the cost
does not grow with the image width. The number of hypotheses is the paper's
``n_hyp = log(1 - P) / log(1 - (1 - eps)^k)``, a static integer, so all hypotheses are solved at once with ``jax.vmap``.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama
from ..geometry.reprojection import boundary_rows_along, range_along
from .settings import check_non_negative, check_positive, scaled, settings
from .wall import Wall, solve_wall
from .wall_at_heights import solve_wall_at_heights


@settings(static=("success_probability", "outlier_rate", "sample_size", "columns"))
class RansacConfig:
    """Step 2 of the pipeline: one RANSAC wall per pair of corners (:func:`ransac_wall`).

    Attributes:
        success_probability: RANSAC's P (paper: 0.9999).
        outlier_rate: RANSAC's epsilon (paper: 0.2).
        sample_size: columns per RANSAC hypothesis (paper: 3).
        columns: columns per wall on which RANSAC scores its hypotheses and refits the best one, evenly spaced
            along the wall (all of them for a narrower wall); the cost grows with it, not with the width.
        inlier_threshold: row error of an inlier, pixels (also the rows a layout explains, step 5).
        corner_margin: columns this close to a corner are not used to fit walls.
    """

    success_probability: float = 0.9999
    outlier_rate: float = 0.2
    sample_size: int = 3
    columns: int = 64
    inlier_threshold: float = 3.0
    corner_margin: float = 2.0

    def __post_init__(self):
        if self.sample_size < 3:
            raise ValueError(
                f"sample_size must be >= 3 columns (the wall solver needs 3 rays per line), got {self.sample_size}"
            )
        num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)  # validates
        if self.columns < 2 * self.sample_size:
            raise ValueError(f"RansacConfig.columns must be >= 2 * sample_size, got {self.columns}")
        check_positive(self, "inlier_threshold")
        check_non_negative(self, "corner_margin")

    @property
    def hypotheses(self) -> int:
        """RANSAC hypotheses per wall (paper's n_hyp)."""
        return num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)


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


def wall_columns(
    column_wall: Int[Array, " W"],
    candidate: Bool[Array, " W"],
    corner_columns: Float[Array, " K"],
    size: int,
) -> tuple[Int[Array, "K G"], Bool[Array, "K G"]]:
    """Up to ``size`` candidate columns of each wall, evenly spaced along it (fixed size ``G``).

    RANSAC scores its hypotheses on these columns only: a wall's hypotheses
    need its own columns, not all ``W`` (``K`` walls would cost ``K W`` row
    evaluations per hypothesis), and a few dozen columns spread over the wall
    rank hypotheses as well as all of them.

    Args:
        column_wall: the wall of each column (corner ``k`` starts wall ``k``), -1 for none.
        candidate: columns that may be used.
        corner_columns: start column of each wall (walls wrap around the image).
        size: static ``G``.

    Returns:
        ``(columns, valid)``: per wall, column indices in image order from its
        start corner; all candidates when it has at most ``G`` of them
        (``valid`` marks them), else ``G`` evenly spaced ones.
    """
    width, capacity = column_wall.shape[0], corner_columns.shape[0]
    wall = jnp.where(candidate & (column_wall >= 0), column_wall, capacity)
    start = jnp.floor(corner_columns[jnp.minimum(wall, capacity - 1)]).astype(jnp.int32)
    along = (jnp.arange(width, dtype=jnp.int32) - start) % width
    order = jnp.argsort(wall * width + along)  # candidates grouped by wall, in image order
    counts = jax.ops.segment_sum(jnp.ones(width, jnp.int32), wall, capacity + 1)[:capacity]
    first = jnp.cumsum(counts) - counts
    slot = jnp.arange(size, dtype=jnp.int32)
    offset = slot[None, :] * jnp.maximum(counts, size)[:, None] // size
    return order[jnp.minimum(first[:, None] + offset, width - 1)], slot[None, :] < counts[:, None]


def sample_columns(key: PRNGKeyArray, candidates: Bool[Array, " n"], sample_size: int) -> Int[Array, " k"]:
    """``sample_size`` distinct indices drawn uniformly among the candidates."""
    scores = jnp.where(candidates, jax.random.uniform(key, candidates.shape), -1.0)
    return jax.lax.top_k(scores, sample_size)[1]


def boundary_errors(
    cam: NonCentralPanorama,
    wall: Wall,
    azimuth: Float[Array, "n 2"],
    ceiling_v: Float[Array, " n"],
    floor_v: Float[Array, " n"],
) -> tuple[Float[Array, " n"], Float[Array, " n"]]:
    """Per column, the row distance (pixels) between a wall's reprojected lines and the boundaries.

    Columns are given by their unit horizontal direction ``azimuth``
    (:func:`ncjax.geometry.reprojection.column_directions`, computed once by the
    caller). The wall's fields broadcast against the columns (one wall, or
    one per column). ``inf`` where the wall is not in front of the column.
    """
    ceiling, floor, seen = boundary_rows_along(
        cam, wall.direction, wall.distance, wall.ceiling_height, wall.floor_height, azimuth
    )
    return jnp.where(seen, jnp.abs(ceiling - ceiling_v), jnp.inf), jnp.where(seen, jnp.abs(floor - floor_v), jnp.inf)


def elevation_band(
    rays: Float[Array, "n 6"], azimuth: Float[Array, "n 2"], tolerance: Float[ArrayLike, ""]
) -> Float[Array, "n 2 2"]:
    """The in-plane directions ``tolerance`` radians below and above each boundary ray.

    A boundary ray of elevation ``phi`` in the half-plane of its column's unit
    azimuth ``a`` points along ``(cos phi, sin phi)`` in that half-plane
    (``cos phi`` read as ``xi . a``, so that rows past the zenith or nadir keep
    their sign). The result holds the lower and the upper edge of the band,
    ``(cos, sin)`` of ``phi -+ tolerance``. Rows are an affine function of the
    elevation, so ``tolerance = threshold * fov_vertical / height`` radians is
    the band of rows within ``threshold`` pixels.
    """
    cosine, sine = jnp.cos(tolerance), jnp.sin(tolerance)
    c, s = jnp.sum(rays[:, 0:2] * azimuth, -1), rays[:, 2]
    lower = jnp.stack([c * cosine + s * sine, s * cosine - c * sine], -1)
    upper = jnp.stack([c * cosine - s * sine, s * cosine + c * sine], -1)
    return jnp.stack([lower, upper], 1)


def inlier_rows(
    cam: NonCentralPanorama,
    wall: Wall,
    azimuth: Float[Array, "n 2"],
    ceiling_band: Float[Array, "n 2 2"],
    floor_band: Float[Array, "n 2 2"],
) -> tuple[Bool[Array, " n"], Bool[Array, " n"]]:
    """Which columns' ceiling and floor boundaries a wall reprojects inside their :func:`elevation_band`.

    The wall's line at height ``h`` is seen from the column's optical centre
    in the in-plane direction ``(t, h)`` (range ``t > 0``,
    :mod:`ncjax.geometry.reprojection`); it is inside the band when it lies
    counter-clockwise of the lower edge and clockwise of the upper one. The
    same test as ``boundary_errors(...) < threshold``, with two cross
    products instead of an arctangent per (hypothesis, column) pair.

    Args:
        cam: the camera.
        wall: one wall.
        azimuth: unit horizontal direction ``a`` of each column.
        ceiling_band: the ceiling rows' bands.
        floor_band: the floor rows' bands.
    """
    t = range_along(cam, wall.direction, wall.distance, azimuth)
    seen = jnp.isfinite(t) & (t > 0)
    t = jnp.where(seen, t, 1.0)

    def inside(height, band):
        lower, upper = band[:, 0], band[:, 1]
        return seen & (lower[:, 0] * height - lower[:, 1] * t > 0) & (t * upper[:, 1] - height * upper[:, 0] > 0)

    return inside(wall.ceiling_height, ceiling_band), inside(wall.floor_height, floor_band)


class WallColumns(NamedTuple):
    """One wall's columns as RANSAC sees them (traced, ``G`` columns, :func:`wall_columns`).

    Attributes:
        azimuth: unit horizontal direction of each column.
        ceiling_rays: their rays of the ceiling boundary.
        floor_rays: their rays of the floor boundary.
        candidates: which of them are used (finite rows, away from corners).
    """

    azimuth: Float[Array, "G 2"]
    ceiling_rays: Float[Array, "G 6"]
    floor_rays: Float[Array, "G 6"]
    candidates: Bool[Array, " G"]


# walls whose ceiling or floor is closer than this (metres) to the camera's plane are rejected (:func:`plausible_wall`)
MIN_WALL_HEIGHT = 0.1


def ransac_wall(
    key: PRNGKeyArray,
    cam: NonCentralPanorama,
    columns: WallColumns,
    config: RansacConfig,
    heights: tuple[Float[Array, ""], Float[Array, ""]] | None = None,
) -> Wall:
    """The wall that best explains the boundaries of the candidate columns.

    Args:
        key: PRNG key.
        cam: the camera.
        columns: the wall's columns.
        config: the static number of hypotheses (:attr:`RansacConfig.hypotheses`) and columns per hypothesis
            (``sample_size``, >= 3), and the maximum row error of an inlier (``inlier_threshold``, pixels of a
            512-row panorama).
        heights: the known ``(h_c, h_f)`` of a height prior, or None. Given, every hypothesis and the refit are
            plan lines at those heights (:func:`~.wall_at_heights.solve_wall_at_heights`): two unknowns instead
            of four, which rows a few pixels off fix far better than the scale of one wall's weak parallax.

    Returns:
        The wall refitted on the inliers of the best hypothesis; ``ok`` is
        False when fewer than ``sample_size`` candidates exist or no
        hypothesis is valid.
    """
    azimuth, ceiling_rays, floor_rays, candidates = columns
    sample_size, min_height = config.sample_size, MIN_WALL_HEIGHT
    inlier_threshold = config.inlier_threshold * scaled(1.0, cam.height, 512)
    samples = jax.vmap(sample_columns, in_axes=(0, None, None))(
        jax.random.split(key, config.hypotheses), candidates, sample_size
    )
    if heights is None:
        solve = solve_wall
    else:
        solve = functools.partial(solve_wall_at_heights, ceiling_height=heights[0], floor_height=heights[1])
    sure = jnp.ones(sample_size, bool)
    hypotheses = jax.vmap(lambda s: solve(ceiling_rays[s], floor_rays[s], sure, sure))(samples)
    tolerance = inlier_threshold * cam.fov_vertical / cam.height
    bands = elevation_band(ceiling_rays, azimuth, tolerance), elevation_band(floor_rays, azimuth, tolerance)
    ceiling_in, floor_in = jax.vmap(inlier_rows, in_axes=(None, 0, None, None, None))(cam, hypotheses, azimuth, *bands)
    ceiling_in, floor_in = candidates & ceiling_in, candidates & floor_in
    valid = jax.vmap(plausible_wall, in_axes=(0, None))(hypotheses, min_height)
    score = jnp.where(valid, jnp.sum(ceiling_in, 1) + jnp.sum(floor_in, 1), -1)
    best = jnp.argmax(score)
    refit = solve(ceiling_rays, floor_rays, ceiling_in[best], floor_in[best])
    # the algebraic refit can slide to the degenerate tiny wall; keep the hypothesis then
    wall = jax.tree.map(lambda r, h: jnp.where(plausible_wall(refit, min_height), r, h[best]), refit, hypotheses)
    enough = jnp.sum(candidates) >= sample_size
    ok = plausible_wall(wall, min_height) & enough & (score[best] >= 0)
    return eqx.tree_at(lambda w: w.ok, wall, ok)


def plausible_wall(wall: Wall, min_height: float) -> Bool[Array, ""]:
    """A solved wall that can bound a room: ceiling above and floor below the camera by ``min_height``.

    With little parallax (small ``rc``, far walls) and noise, the algebraic
    solution can shrink towards the degenerate wall of height 0 that touches
    the circle of optical centres; its rows still look plausible, so it is
    rejected here.
    """
    return wall.ok & (wall.ceiling_height > min_height) & (wall.floor_height < -min_height)
