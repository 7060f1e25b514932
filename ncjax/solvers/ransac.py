"""Per-wall RANSAC with the single-wall solver (paper Section 4.4).

Each hypothesis is :func:`~.wall.solve_wall` on ``k`` sampled columns (one ceiling and one floor ray each: the paper's
``k = 3``; with a height prior's known heights :func:`~.wall_at_heights.solve_wall_at_heights`). The paper counts
the boundary pixels a hypothesis reprojects within a threshold; here each candidate row costs its squared error in
thresholds, capped at 1 (MSAC, Torr and Zisserman 2000: the inlier count with the inliers' errors as tie-breaker,
so that among the many hypotheses that explain a clean wall the closest wins, not the first sampled). Errors are
angles in the column's half-plane (:func:`boundary_angles`, the closed form of :mod:`ncjax.geometry.reprojection`).
The ``optimised`` best hypotheses are each refitted on their inliers, whose inliers are found again and refitted,
``refits`` times (local optimisation, Chum et al. 2003), and the least cost after that wins: hypotheses in the basin
of one wall end at that wall, and two walls of similar support are compared at their optima, so the answer depends
little on the RANSAC key. Hypotheses are scored and refitted on at most ``G`` columns of the wall
(:func:`wall_columns`), so the cost does not grow with the image width. The random hypotheses number the paper's
``n_hyp = log(1 - P) / log(1 - (1 - eps)^k)``, a static integer; 16 more, the same for every key, span windows of
the wall (:data:`WINDOWS`, :func:`spread_columns`). With ``strata`` set, a fixed design replaces the random samples
(:func:`stratified_fractions`): one sample from every ``k`` of ``strata`` equal stretches of the wall, so that
whenever ``k`` stretches are free of outliers (a photograph's rows leave a wall for whole stretches, along furniture
and doorways) one sample is too, and the wall no longer depends on the key. All are solved at once with ``jax.vmap``.
"""

from __future__ import annotations

import functools
import itertools
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama
from ..geometry.reprojection import boundary_rows_along, range_along
from .settings import check_non_negative, check_positive, scaled, settings
from .wall import Wall, solve_wall
from .wall_at_heights import solve_wall_at_heights


@settings(static=("success_probability", "outlier_rate", "sample_size", "columns", "refits", "optimised", "strata"))
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
        refits: times a hypothesis is refitted on its inliers and its inliers found again (local
            optimisation: hypotheses near the same wall end at the same one).
        optimised: hypotheses of least cost that are refitted; the one of least cost after its refits wins.
        strata: 0 draws the random hypotheses with the key (the paper's); ``S > 0`` replaces them with the
            ``C(S, sample_size)`` samples of :func:`stratified_fractions`, the same for every key.
    """

    success_probability: float = 0.9999
    outlier_rate: float = 0.2
    sample_size: int = 3
    columns: int = 64
    inlier_threshold: float = 3.0
    corner_margin: float = 2.0
    refits: int = 3
    optimised: int = 8
    strata: int = 0

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
        if self.refits < 1 or self.optimised < 1:
            raise ValueError(f"RansacConfig.refits and optimised must be >= 1, got {self.refits}, {self.optimised}")
        if self.strata and self.strata < self.sample_size:
            raise ValueError(f"RansacConfig.strata must be 0 or >= sample_size, got {self.strata}")

    @property
    def hypotheses(self) -> int:
        """Sampled hypotheses per wall besides :data:`WINDOWS`': the paper's n_hyp, or the stratified design's."""
        if self.strata:
            return math.comb(self.strata, self.sample_size)
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


# the windows of a wall's candidate columns (fractions of them in image order) that its deterministic hypotheses
# span: the whole wall, and windows of a half, a third and a quarter of it overlapping by half (16 in all)
WINDOWS = tuple(
    (start * width / 2, start * width / 2 + width)
    for width in (1.0, 1 / 2, 1 / 3, 1 / 4)
    for start in range(round(2 / width) - 1)
)


def columns_at(candidates: Bool[Array, " n"], fractions: Float[Array, " k"]) -> Int[Array, " k"]:
    """The candidates at ``fractions`` (in [0, 1]) of the candidates in image order.

    Fractions closer than one candidate apart pick the same one: a degenerate sample whose wall
    :func:`plausible_wall` rejects.
    """
    ranks = jnp.round(fractions * (jnp.sum(candidates) - 1)).astype(jnp.int32)
    return jnp.searchsorted(jnp.cumsum(candidates), ranks + 1)


def spread_columns(candidates: Bool[Array, " n"], window: tuple[float, float], sample_size: int) -> Int[Array, " k"]:
    """``sample_size`` candidates evenly spread over ``window`` (fractions of the candidates in image order).

    The window's ends are its farthest columns: the sample sees the wall under the widest angles it can, which
    is what fixes a non-central wall's distance.
    """
    return columns_at(candidates, jnp.linspace(*window, sample_size))


def stratified_fractions(strata: int, sample_size: int) -> np.ndarray:
    """The fixed samples of :attr:`RansacConfig.strata`: (C(S, k), k) fractions of a wall's candidates.

    The wall's candidates are cut into ``strata`` equal stretches; sample ``i`` takes one point in each stretch
    of the ``i``-th combination of ``sample_size`` of them. Within its stretch the point moves from sample to
    sample along an additive recurrence of irrational steps (the square roots of primes), so that the samples
    use many columns, not the same ``strata``: a stray row at one column spoils few of them.
    """
    combinations = np.array(list(itertools.combinations(range(strata), sample_size)), np.float64)
    steps = np.sqrt([2.0, 3.0, 5.0, 7.0, 11.0, 13.0, 17.0, 19.0, 23.0, 29.0])[:sample_size] % 1.0
    steps = np.resize(steps, sample_size)  # samples of more than 10 columns reuse the steps
    within = (np.arange(1, len(combinations) + 1)[:, None] * steps[None, :]) % 1.0
    return (combinations + within) / strata


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


def boundary_angles(
    cam: NonCentralPanorama,
    wall: Wall,
    azimuth: Float[Array, "n 2"],
    ceiling_rays: Float[Array, "n 6"],
    floor_rays: Float[Array, "n 6"],
) -> tuple[Float[Array, " n"], Float[Array, " n"]]:
    """Per column, the angle (radians) between each boundary ray and the wall's line at that boundary's height.

    Both lie in the column's vertical half-plane of unit azimuth ``a``: the ray of elevation ``phi`` along
    ``(cos phi, sin phi)`` (``cos phi`` read as ``xi . a``, so that rows past the zenith or nadir keep their
    sign), the wall's line at height ``h`` seen from the column's optical centre along ``(t, h)`` (range
    ``t > 0``, :mod:`ncjax.geometry.reprojection`). Rows are an affine function of the elevation, so the
    angle times ``height / fov_vertical`` is :func:`boundary_errors`' row error in pixels, with one
    arctangent of two products per column. ``inf`` where the wall is not in front of the column.
    """
    t = range_along(cam, wall.direction, wall.distance, azimuth)
    seen = jnp.isfinite(t) & (t > 0)
    t = jnp.where(seen, t, 1.0)

    def angle(height, rays):
        c, s = jnp.sum(rays[:, 0:2] * azimuth, -1), rays[:, 2]
        return jnp.where(seen, jnp.abs(jnp.arctan2(c * height - s * t, c * t + s * height)), jnp.inf)

    return angle(wall.ceiling_height, ceiling_rays), angle(wall.floor_height, floor_rays)


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
        key: PRNG key of the random samples (unused with ``config.strata``).
        cam: the camera.
        columns: the wall's columns.
        config: the static number of hypotheses (:attr:`RansacConfig.hypotheses`) and columns per hypothesis
            (``sample_size``, >= 3), and the maximum row error of an inlier (``inlier_threshold``, pixels of a
            512-row panorama).
        heights: the known ``(h_c, h_f)`` of a height prior, or None. Given, every hypothesis and the refit are
            plan lines at those heights (:func:`~.wall_at_heights.solve_wall_at_heights`): two unknowns instead
            of four, which rows a few pixels off fix far better than the scale of one wall's weak parallax.

    Returns:
        The wall of the hypothesis of least MSAC cost after ``config.refits`` refits on its inliers; ``ok``
        is False when fewer than ``sample_size`` candidates exist or no hypothesis is valid.
    """
    azimuth, ceiling_rays, floor_rays, candidates = columns
    sample_size, min_height = config.sample_size, MIN_WALL_HEIGHT
    tolerance = config.inlier_threshold * scaled(1.0, cam.height, 512) * cam.fov_vertical / cam.height
    if config.strata:
        fractions = jnp.asarray(stratified_fractions(config.strata, sample_size), jnp.float32)
        sampled = jax.vmap(columns_at, in_axes=(None, 0))(candidates, fractions)
    else:
        sampled = jax.vmap(sample_columns, in_axes=(0, None, None))(
            jax.random.split(key, config.hypotheses), candidates, sample_size
        )
    # the deterministic hypotheses span the wall whatever the key: each wall of the room has several, so that
    # the answer rests on them unless a random sample finds a better wall
    spread_samples = jnp.stack([spread_columns(candidates, window, sample_size) for window in WINDOWS])
    samples = jnp.concatenate([spread_samples, sampled])
    if heights is None:
        solve = solve_wall
    else:
        solve = functools.partial(solve_wall_at_heights, ceiling_height=heights[0], floor_height=heights[1])

    def scored(wall: Wall) -> tuple[Float[Array, ""], tuple[Bool[Array, " G"], Bool[Array, " G"]]]:
        """MSAC's cost of a wall (each candidate row's squared error in inlier thresholds, capped at 1;
        inf for an implausible wall) and its inlier rows."""
        angles = boundary_angles(cam, wall, azimuth, ceiling_rays, floor_rays)
        cost = sum(jnp.sum(jnp.where(candidates, jnp.minimum(jnp.square(a / tolerance), 1.0), 0.0)) for a in angles)
        inliers = tuple(candidates & (a < tolerance) for a in angles)
        return jnp.where(plausible_wall(wall, min_height), cost, jnp.inf), inliers

    sure = jnp.ones(sample_size, bool)
    hypotheses = jax.vmap(lambda s: solve(ceiling_rays[s], floor_rays[s], sure, sure))(samples)
    costs, inliers = jax.vmap(scored)(hypotheses)

    def refitted(state, _):
        # the algebraic refit can slide to the degenerate tiny wall; keep the wall it came from then
        wall, cost, wall_inliers = state
        refit = solve(ceiling_rays, floor_rays, *wall_inliers)
        keep = plausible_wall(refit, min_height)
        return jax.tree.map(lambda r, w: jnp.where(keep, r, w), (refit, *scored(refit)), state), None

    def optimised(start):
        return jax.lax.scan(refitted, start, length=config.refits)[0]

    # the best few hypotheses are optimised, so that two structures of similar support (the floor line and a
    # desk's edge) are compared at their optima, not by whichever of their samples happened to be closer
    _, best = jax.lax.top_k(-costs, min(config.optimised, len(WINDOWS) + config.hypotheses))
    walls, costs, _ = jax.vmap(optimised)(jax.tree.map(lambda x: x[best], (hypotheses, costs, inliers)))
    chosen = jnp.argmin(costs)
    wall, cost = jax.tree.map(lambda x: x[chosen], walls), costs[chosen]
    enough = jnp.sum(candidates) >= sample_size
    ok = plausible_wall(wall, min_height) & enough & jnp.isfinite(cost)
    return eqx.tree_at(lambda w: w.ok, wall, ok)


def plausible_wall(wall: Wall, min_height: float) -> Bool[Array, ""]:
    """A solved wall that can bound a room: ceiling above and floor below the camera by ``min_height``.

    With little parallax (small ``rc``, far walls) and noise, the algebraic
    solution can shrink towards the degenerate wall of height 0 that touches
    the circle of optical centres; its rows still look plausible, so it is
    rejected here.
    """
    return wall.ok & (wall.ceiling_height > min_height) & (wall.floor_height < -min_height)
