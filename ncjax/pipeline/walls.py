"""The wall loop after merging and insertion, and the plan geometry both branches share."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama
from ..geometry.plucker import cross_2d
from ..geometry.reprojection import boundary_points, column_directions, fit_plan_lines, range_along, wall_boundary_rows
from ..solvers.layout import WallLayout, solve_atlanta_layout
from .types import BranchWalls, FinalWalls, WallEvidence


def wall_groups(corner_mask: Bool[Array, " K"], merge: Bool[Array, " K"]) -> tuple[Int[Array, " K"], Int[Array, ""]]:
    """Group of each RANSAC wall after merging, and the number of groups.

    A corner that is not merged starts a group; walls before the first start
    belong to the last group (the loop wraps).
    """
    starts = corner_mask & ~merge
    num_groups = jnp.sum(starts)
    group = jnp.cumsum(starts) - 1
    return jnp.where(group < 0, num_groups - 1, group), num_groups


def final_walls(
    evidence: WallEvidence, merge: Bool[Array, " K"], insert: Bool[Array, " K"], manhattan: bool, min_columns: int
) -> FinalWalls:
    """Merge the walls split by spurious corners and insert the occluded ones.

    Wall groups: a corner that is not merged starts a group; walls before the
    first start belong to the last group (the loop wraps). Slot ``2g`` holds the
    wall inserted before group ``g`` (if any), slot ``2g + 1`` group ``g``; the
    valid slots are then compacted to the front. A wall is observed with at
    least ``min_columns`` trusted columns (:class:`WallEvidence`).
    """
    capacity = evidence.corner_mask.shape[0]
    starts = evidence.corner_mask & ~merge
    group_of_wall, num_groups = wall_groups(evidence.corner_mask, merge)
    start_corner = (
        jnp.zeros(capacity, jnp.int32)
        .at[jnp.where(starts, group_of_wall, capacity)]
        .set(jnp.arange(capacity, dtype=jnp.int32), mode="drop")
    )
    group_valid = jnp.arange(capacity) < num_groups
    insert_before = group_valid & insert[start_corner]
    slot_valid = jnp.stack([insert_before, group_valid], 1).reshape(-1)
    order = jnp.argsort(~slot_valid, stable=True)
    rank = jnp.zeros_like(order).at[order].set(jnp.arange(2 * capacity, dtype=order.dtype))
    slot = order[:capacity]
    group = slot // 2
    inserted = slot % 2 == 0
    mask = slot_valid[slot]
    corner = start_corner[group]
    nearer_is_previous = evidence.previous_nearer[corner]
    if manhattan:
        # Only the occluding corner (on the nearer wall) is seen.
        corner_used = jnp.where(
            insert_before[group], jnp.where(inserted, nearer_is_previous, ~nearer_is_previous), True
        )
    else:
        corner_used = jnp.ones(capacity, bool)
    index = jnp.arange(capacity)
    count = jnp.maximum(jnp.sum(mask), 1)
    # an unfitted wall hangs on its predecessor; an inserted one on the nearer wall
    near_neighbour = jnp.where(nearer_is_previous | ~inserted, (index - 1) % count, (index + 1) % count)
    wall = evidence.column_wall
    column_wall = jnp.where(wall >= 0, rank[2 * group_of_wall[jnp.maximum(wall, 0)] + 1], -1)
    column_wall = jnp.where(column_wall < capacity, column_wall, -1).astype(jnp.int32)
    trusted = evidence.ceiling_trusted & evidence.floor_trusted
    columns_seen = jax.ops.segment_sum(
        trusted.astype(jnp.int32), jnp.where(column_wall >= 0, column_wall, capacity), capacity + 1
    )
    observed = mask & ~inserted & (columns_seen[:capacity] >= min_columns)
    return FinalWalls(
        mask=mask,
        inserted=inserted & mask,
        observed=observed,
        group=group,
        start_wall=corner,
        corner_columns=evidence.corner_columns[corner],
        corner_used=corner_used & mask,
        near_neighbour=near_neighbour,
        column_wall=column_wall,
        overflow=jnp.sum(slot_valid) > capacity,
    )


def group_directions(evidence: WallEvidence, merge: Bool[Array, " K"], final: FinalWalls) -> Float[Array, "K 2"]:
    """Per final wall, the inlier-weighted mean direction of its merged RANSAC walls."""
    capacity = merge.shape[0]
    group_of_wall, _ = wall_groups(evidence.corner_mask, merge)
    group_of_wall = jnp.where(evidence.corner_mask, group_of_wall, capacity)
    # canonical signs (camera on the left) agree for walls of one plane
    summed = jax.ops.segment_sum(evidence.weights[:, None] * evidence.walls.direction, group_of_wall, capacity + 1)
    return summed[final.group]


def point_on_wall(
    cam: NonCentralPanorama, direction: Float[Array, "K 2"], distance: Float[Array, " K"], column: Float[Array, " K"]
) -> Float[Array, "K 2"]:
    """Where the vertical half-plane of ``column`` meets a wall (plan view)."""
    along = column_directions(cam, column)
    t = range_along(cam, direction, distance, along)
    t = jnp.where(jnp.isfinite(t), t, 0.0)
    return (cam.rc + t)[:, None] * along


def boundary_gap(
    cam: NonCentralPanorama, first: tuple, second: tuple, column: Float[Array, " K"]
) -> tuple[Float[Array, " K"], Bool[Array, " K"]]:
    """How far apart two walls' boundaries cross ``column`` (pixels: the larger of the ceiling and floor rows'
    differences), and whether both walls are seen there.

    ``first`` and ``second`` are ``(direction, distance, ceiling_height, floor_height)`` of
    :func:`~ncjax.geometry.reprojection.wall_boundary_rows`.
    """
    ceiling_a, floor_a, seen_a = wall_boundary_rows(cam, *first, column)
    ceiling_b, floor_b, seen_b = wall_boundary_rows(cam, *second, column)
    return jnp.maximum(jnp.abs(ceiling_a - ceiling_b), jnp.abs(floor_a - floor_b)), seen_a & seen_b


def signed_distance(direction: Float[Array, "K 2"], point: Float[Array, "K 2"]) -> Float[Array, " K"]:
    return cross_2d(direction, point)  # e2 . p with e2 = (-uy, ux)


def place_unobserved_walls(
    cam: NonCentralPanorama, final: FinalWalls, directions: Float[Array, "K 2"], distances: Float[Array, " K"]
) -> tuple[Float[Array, "K 2"], Float[Array, " K"]]:
    """The walls ``final`` does not observe, placed (free angles): occlusion walls in the corner ray's vertical
    plane (the paper's Fig. Atocc), unfitted walls through their two corners on the neighbouring walls; the observed
    walls keep ``directions`` and ``distances``."""
    count = jnp.maximum(jnp.sum(final.mask), 1)
    index = jnp.arange(final.mask.shape[0])
    previous, following = (index - 1) % count, (index + 1) % count
    start = point_on_wall(cam, directions[previous], distances[previous], final.corner_columns)
    end = point_on_wall(cam, directions[following], distances[following], final.corner_columns[following])
    chord = end - start
    length = jnp.linalg.norm(chord, axis=-1, keepdims=True)
    through_corners = jnp.where(length > 0, chord / jnp.where(length > 0, length, 1.0), directions)
    radial = column_directions(cam, final.corner_columns)
    new_direction = jnp.where(final.inserted[:, None], radial, through_corners)
    new_distance = jnp.where(final.inserted, 0.0, signed_distance(through_corners, start))
    keep = final.observed[:, None]
    return jnp.where(keep, directions, new_direction), jnp.where(final.observed, distances, new_distance)


def several_corners(evidence: WallEvidence) -> Bool[Array, ""]:
    return jnp.sum(evidence.corner_mask) > 1


def plan_lines(evidence: WallEvidence, column_wall: Int[Array, " W"], h_c, h_f) -> Float[Array, "K 2"]:
    """Per wall of ``column_wall`` (-1: none), the direction of the plan line through its boundary points at
    heights ``h_c``, ``h_f``."""
    cam, ceiling_v, floor_v = evidence.cam, evidence.rows.ceiling, evidence.rows.floor
    columns = jnp.arange(cam.width, dtype=ceiling_v.dtype)
    ceiling, ceiling_ok = boundary_points(cam, columns, jnp.where(evidence.finite, ceiling_v, 0.0), h_c)
    floor, floor_ok = boundary_points(cam, columns, jnp.where(evidence.finite, floor_v, 0.0), h_f)
    points = jnp.concatenate([ceiling, floor])
    ok = jnp.concatenate([ceiling_ok, floor_ok]) & jnp.tile(evidence.usable, 2)
    wall = jnp.tile(column_wall, 2)  # -1 (no wall): dropped
    directions, _ = fit_plan_lines(points, ok.astype(points.dtype), wall, evidence.corner_mask.shape[0])
    return directions


def solver_columns(evidence: WallEvidence, column_wall: Int[Array, " W"]) -> Int[Array, " W"]:
    """Columns fed to the joint solvers, by wall: those whose ceiling and floor rows are both trusted
    (:class:`WallEvidence`)."""
    return jnp.where(evidence.ceiling_trusted & evidence.floor_trusted, column_wall, -1)


def solve_final_walls(
    evidence: WallEvidence,
    final: FinalWalls,
    directions: Float[Array, "K 2"],
    snap: Callable[[Float[Array, "K 2"]], Float[Array, "K 2"]],
    max_room_height: Float[ArrayLike, ""],
) -> tuple[WallLayout, Bool[Array, ""]]:
    """The final walls' joint solve in two passes (:func:`~ncjax.solvers.layout.solve_atlanta_layout`).

    The first pass solves the final walls that RANSAC fitted, with ``directions``, for the heights; at
    those heights every observed wall's direction is its boundary points' plan line (:func:`plan_lines`),
    made a branch's by ``snap`` (the Manhattan branch keeps one yaw); the second pass solves the observed
    walls with those directions. The two passes are one traced pass run twice (``lax.scan``), so that the
    program compiles it once. Where the second pass's room is taller than ``max_room_height`` (metres) and
    the first pass's is not, the second pass's walls are scaled to the first pass's room height.

    Returns:
        The second pass's walls, and whether both passes succeeded.
    """
    fit_index = solver_columns(evidence, final.column_wall)

    def one_pass(state, _):
        mask, pass_directions = state
        solved = solve_atlanta_layout(
            evidence.ceiling_rays,
            evidence.floor_rays,
            fit_index,
            mask,
            pass_directions,
            boundary_weights=evidence.row_weights,
        )
        plan = plan_lines(evidence, final.column_wall, solved.ceiling_height, solved.floor_height)
        return (final.observed, snap(plan)), solved

    fitted = final.observed & evidence.fitted[final.start_wall]
    _, passes = jax.lax.scan(one_pass, (fitted, directions), length=2)
    first, second = (jax.tree.map(lambda x, i=i: x[i], passes) for i in range(2))
    # the plan lines of narrow walls' few noisy rows can send the second pass's scale far off (rooms hundreds of
    # times too large under 1-2 px of row noise, where the rows barely tell scales apart): an implausibly tall
    # room takes the first pass's room height
    plausible = (room_height(first) > 0) & (room_height(first) <= max_room_height)
    use_first = first.ok & plausible & ~(room_height(second) <= max_room_height)
    at_first = scaled_walls(second, room_height(first) / room_height(second))
    chosen = jax.tree.map(lambda a, b: jnp.where(use_first, a, b), at_first, second)
    return chosen, jnp.all(passes.ok)


def room_height(walls: WallLayout | BranchWalls) -> Float[Array, "*batch"]:
    return walls.ceiling_height - walls.floor_height


def scaled_walls(walls: WallLayout | BranchWalls, factor: Float[Array, "*batch"]) -> WallLayout | BranchWalls:
    """``walls`` (one layout's, or a batch's with one factor each) scaled about the camera's axis by ``factor``:
    distances and heights, the same directions; a factor that is not finite and positive leaves them as they are."""
    factor = jnp.where(jnp.isfinite(factor) & (factor > 0), factor, 1.0)
    return eqx.tree_at(
        lambda w: (w.distances, w.ceiling_height, w.floor_height),
        walls,
        (walls.distances * factor[..., None], walls.ceiling_height * factor, walls.floor_height * factor),
    )
