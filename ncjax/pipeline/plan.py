"""The plan layout (not in the paper): walls read off the floor rows' plan by robust lines, where a branch's
layout does not explain the rows.

A layout flagged ``LOW_CONFIDENCE`` reprojects less than ``checks.min_explained_fraction`` of the rows: its wall
solvers and least-squares adjustment fitted rows that leave the walls for whole stretches (a floor row run
through a doorway to the next room's floor, a ceiling row along a fan or a header) and the ceiling's rows, less
noisy about their RANSAC walls, pulled the walls where they say. On real photographs the rows themselves are
nearer the room than those layouts (experiments/RESULTS.md, "Real photographs"). The plan layout reads the room
from the floor rows alone, where a doorway's rows are a minority of their wall's:

1. each column's floor row (as the input gave it) is a plan point at the floor height
   (:func:`~ncjax.geometry.reprojection.boundary_points`): a height prior's on its virtual rig, whose rows are the
   image's boundary points at the prior's heights only, else the flagged layout's; rows within ``horizon_margin``
   of the horizon, whose points run off to infinity, are left out;
2. per RANSAC wall (the columns between two corner peaks), a line through its points: the least-median line of a
   fixed design of point pairs, then iteratively reweighted total least squares with Tukey's biweight
   (:func:`robust_plan_lines`): points farther from the line than ``tukey`` times the wall's robust spread count
   for nothing; a wall of fewer than ``min_wall_columns`` points runs between its neighbours' ends;
3. at each corner the two walls meet where their lines cross, unless they turn by less than ``min_turn`` degrees
   or cross behind the corner's ray or beyond ``checks.max_corner_range_ratio`` times the points' 95th-percentile
   range: there a wall is inserted in the corner ray's vertical plane, as at an occlusion (:func:`occluded_corners`).

A plan layout whose walls cross, with a corner inside the circle of optical centres, or with the camera's axis
outside it, is not used
(:func:`~ncjax.pipeline.run.plan_fallback`). No least squares through all the rows: the result is judged as every
layout is (:func:`~ncjax.pipeline.assemble.assemble_layout`); it keeps the flagged layout's height covariance (the
same heights' scale) and has no corner covariance (infinite: not determined).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama, pixel_to_angles
from ..geometry.plucker import cross_2d, wall_planes_meet
from ..geometry.reprojection import boundary_points, column_directions, fit_plan_lines
from ..solvers.settings import scaled
from .adjust import FREE_ANGLE
from .assemble import assemble_layout
from .config import PipelineConfig, PlanConfig
from .evidence import previous_of
from .refine import explained_fraction
from .types import BranchWalls, Layout, WallEvidence
from .uncertainty import LayoutUncertainty
from .walls import final_walls, place_unobserved_walls


def floor_plan_points(
    evidence: WallEvidence, floor_height: Float[ArrayLike, ""], horizon_margin: Float[ArrayLike, ""]
) -> tuple[Float[Array, "W 2"], Bool[Array, " W"]]:
    """Step 1: each usable column's floor row as the input gave it (before step 0, which replaces the floor rows
    that disagree with a ceiling row: under a fan the ceiling's) as a plan point at ``floor_height``, and which
    count."""
    cam, floor_v = evidence.cam, evidence.input_floor
    columns = jnp.arange(cam.width, dtype=floor_v.dtype)
    row = jnp.where(jnp.isfinite(floor_v), floor_v, cam.height - 1.0)
    _, elevation = pixel_to_angles(cam, columns, row)
    points, reached = boundary_points(cam, columns, row, floor_height)
    counted = evidence.usable & jnp.isfinite(floor_v) & reached & (elevation < -horizon_margin)
    return jnp.where(counted[:, None], points, 0.0), counted


def segment_medians(values: Float[Array, " W"], segments: Int[Array, " W"], count: int) -> Float[Array, " S"]:
    """The median of ``values`` in each of ``count`` segments (``segments`` outside ``[0, count)``: none; NaN for an
    empty segment): one sort of all the values by segment and value, not one per segment."""
    segments = jnp.where((segments >= 0) & (segments < count), segments, count)
    order = jnp.lexsort((values, segments))
    ordered = values[order]
    sizes = jax.ops.segment_sum(jnp.ones_like(segments), segments, count + 1)[:count]
    starts = jnp.cumsum(sizes) - sizes
    last = values.shape[0] - 1
    lower = ordered[jnp.clip(starts + (sizes - 1) // 2, 0, last)]
    upper = ordered[jnp.clip(starts + sizes // 2, 0, last)]
    return jnp.where(sizes > 0, 0.5 * (lower + upper), jnp.nan)


def least_median_lines(
    points: Float[Array, "W 2"], wall: Int[Array, " W"], capacity: int, samples: int
) -> tuple[Float[Array, "K 2"], Float[Array, " K"]]:
    """Per wall (``wall``: each point's, ``capacity``: none), of the lines through two of its points at ``samples``
    evenly spaced ranks (a fixed design: a doorway's stretch of rows leaves some pairs on the wall), the one whose
    median distance from the wall's points is least (least median of squares, Rousseeuw 1984)."""
    in_wall = wall[None, :] == jnp.arange(capacity)[:, None]  # (K, W)
    counts = jnp.sum(in_wall, axis=1)
    rank = jnp.cumsum(in_wall, axis=1) - 1  # (K, W): each point's rank in its wall
    targets = jnp.round(jnp.linspace(0.0, 1.0, samples)[None, :] * jnp.maximum(counts - 1, 0)[:, None])  # (K, S)
    chosen = in_wall[:, None, :] & (rank[:, None, :] == targets[:, :, None])  # (K, S, W)
    sample_points = points[jnp.argmax(chosen, axis=-1)]  # (K, S, 2)
    first, second = jnp.triu_indices(samples, 1)
    chord = sample_points[:, second] - sample_points[:, first]  # (K, P, 2)
    length = jnp.linalg.norm(chord, axis=-1, keepdims=True)
    directions = jnp.where(length > 0, chord / jnp.where(length > 0, length, 1.0), jnp.array([1.0, 0.0]))
    distances = cross_2d(directions, sample_points[:, first])  # (K, P)
    index = jnp.minimum(wall, capacity - 1)
    # each point's distance from its own wall's candidate lines, (P, W)
    residual = jnp.abs(cross_2d(directions[index].swapaxes(0, 1), points[None]) - distances[index].T)
    median = jax.vmap(segment_medians, in_axes=(0, None, None))(residual, wall, capacity).T  # (K, P)
    best = jnp.argmin(jnp.where(jnp.isfinite(median), median, jnp.inf), axis=1)
    pick = jnp.arange(capacity)
    return directions[pick, best], distances[pick, best]


def robust_plan_lines(
    points: Float[Array, "W 2"],
    counted: Bool[Array, " W"],
    column_wall: Int[Array, " W"],
    capacity: int,
    config: PlanConfig,
) -> tuple[Float[Array, "K 2"], Float[Array, " K"], Int[Array, " K"]]:
    """Step 2: per wall of ``column_wall`` (-1: none), its line through the counted points, robust to a stretch of
    them off it.

    From the least-median line (:func:`least_median_lines`, ``config.samples`` ranks) and from the total-least-squares
    line, iteratively reweighted total least squares (:func:`~ncjax.geometry.reprojection.fit_plan_lines`),
    ``config.iterations`` times, and of the two ends the one with the smaller median distance: a point's
    weight is Tukey's biweight ``(1 - (r / c)^2)^2`` of its distance ``r`` from its wall's line, ``c = tukey * s``
    with ``s`` the wall's robust spread (1.4826 times its points' median distance, at least ``min_spread`` times
    their median range: exact rows have no spread).

    Returns:
        ``(directions, distances, counts)``: the lines and each wall's number of counted points.
    """
    wall = jnp.where(counted & (column_wall >= 0), column_wall, capacity)  # capacity: no wall
    index = jnp.minimum(wall, capacity - 1)
    ranges = jnp.linalg.norm(points, axis=-1)
    floor_spread = config.min_spread * segment_medians(ranges, wall, capacity)

    def median_residual(lines):
        directions, distances = lines
        residual = jnp.abs(cross_2d(directions[index], points) - distances[index])
        return residual, segment_medians(residual, wall, capacity)

    def biweights(lines, _):
        residual, median = median_residual(lines)
        cut = config.tukey * jnp.maximum(jnp.nan_to_num(1.4826 * median), jnp.nan_to_num(floor_spread))
        scaled_residual = residual / jnp.maximum(cut[index], jnp.finfo(points.dtype).tiny)
        weights = jnp.where(wall < capacity, jnp.maximum(1.0 - scaled_residual**2, 0.0) ** 2, 0.0)
        return fit_plan_lines(points, weights, wall, capacity), None

    # two starts, each wall keeping the end nearer most of its points: the least-median line (a stretch of up to
    # half the points off the wall) and the total-least-squares one (the whole wall's direction)
    starts = (
        least_median_lines(points, wall, capacity, config.samples),
        fit_plan_lines(points, (wall < capacity).astype(points.dtype), wall, capacity),
    )
    ends = [jax.lax.scan(biweights, start, length=config.iterations)[0] for start in starts]
    first_nearer = median_residual(ends[0])[1] <= median_residual(ends[1])[1]
    directions, distances = jax.tree.map(
        lambda a, b: jnp.where(first_nearer.reshape((-1,) + (1,) * (a.ndim - 1)), a, b), *ends
    )
    return directions, distances, jax.ops.segment_sum(jnp.ones_like(wall), wall, capacity + 1)[:capacity]


def occluded_corners(
    cam: NonCentralPanorama,
    evidence: WallEvidence,
    lines: tuple[Float[Array, "K 2"], Float[Array, " K"]],
    has_line: Bool[Array, " K"],
    max_range: Float[ArrayLike, ""],
    min_turn: Float[ArrayLike, ""],
) -> Bool[Array, " K"]:
    """Step 3: the corners (``K``, corner ``j`` starts wall ``j``) where a wall is inserted in the corner ray's plane:
    the two walls' lines turn by less than ``min_turn`` degrees, or meet behind the corner's ray or farther than
    ``max_range`` from the axis. A corner next to a wall without a line of its own is left to the walls' placement."""
    directions, distances = lines
    previous = previous_of(evidence)
    meeting, meet = wall_planes_meet(directions[previous], distances[previous], directions, distances)
    turn = jnp.abs(cross_2d(directions[previous], directions))
    ahead = jnp.sum(meeting * column_directions(cam, evidence.corner_columns), axis=-1)
    crossing = meet & (turn >= jnp.sin(jnp.radians(min_turn))) & (ahead > cam.rc)
    crossing &= jnp.linalg.norm(meeting, axis=-1) <= max_range
    both = has_line & has_line[previous]
    return evidence.corner_mask & both & ~crossing & (jnp.sum(evidence.corner_mask) > 1)


def plan_walls(evidence: WallEvidence, heights: Float[Array, " 2"], config: PipelineConfig) -> BranchWalls:
    """Steps 1-3 (module docstring): the plan layout's walls at ``heights`` (``h_c``, ``h_f``)."""
    cam, plan = evidence.cam, config.plan
    capacity = evidence.corner_mask.shape[0]
    ceiling_height, floor_height = heights[0], heights[1]
    points, counted = floor_plan_points(evidence, floor_height, plan.horizon_margin)
    directions, distances, counts = robust_plan_lines(points, counted, evidence.column_wall, capacity, plan)
    # a narrow wall's few points give a direction too noisy to meet its neighbours by: it joins their ends
    has_line = evidence.corner_mask & (counts >= scaled(plan.min_wall_columns, cam.width, 1024))
    ranges = jnp.where(counted, jnp.linalg.norm(points, axis=-1), jnp.nan)
    max_range = config.checks.max_corner_range_ratio * jnp.nanquantile(ranges, 0.95)
    insert = occluded_corners(cam, evidence, (directions, distances), has_line, max_range, plan.min_turn)
    final = final_walls(evidence, jnp.zeros(capacity, bool), insert, False, 1)
    observed = final.mask & ~final.inserted & has_line[final.start_wall]
    final = eqx.tree_at(lambda f: f.observed, final, observed)
    directions, distances = place_unobserved_walls(
        cam, final, directions[final.start_wall], distances[final.start_wall]
    )
    labels = jnp.full(capacity, FREE_ANGLE)
    solved = jnp.any(observed) & (ceiling_height > 0) & (floor_height < 0)
    return BranchWalls(final, solved, directions, distances, ceiling_height, floor_height, labels)


def plan_layout(
    evidence: WallEvidence, heights: Float[Array, " 2"], height_covariance: Float[Array, "2 2"], config: PipelineConfig
) -> Layout:
    """The plan layout of ``evidence`` (module docstring) at ``heights`` (``h_c``, ``h_f``), judged by
    :func:`~ncjax.pipeline.assemble.assemble_layout` with ``height_covariance`` (the flagged layout's)."""
    walls = plan_walls(evidence, heights, config)
    explained = explained_fraction(evidence, walls.final, walls.walls, config)
    capacity = walls.final.mask.shape[0]
    dtype = height_covariance.dtype
    # no covariance of the corners (a robust fit, not the least squares the covariance describes); the heights'
    # scale is the flagged layout's
    undetermined = jnp.inf if config.uncertainty.covariance else jnp.nan
    uncertainty = LayoutUncertainty(
        jnp.full((capacity, 2, 2), undetermined, dtype),
        height_covariance,
        jnp.full(2, jnp.nan, dtype),
        jnp.asarray(jnp.nan, dtype),
    )
    return assemble_layout(evidence, walls, explained, uncertainty, config, plan=True)
