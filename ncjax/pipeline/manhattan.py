"""Manhattan branch (paper Section 4.2): wall labels ``u`` / ``u_perp``, merging, insertion, one yaw."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama
from .adjust import manhattan_directions, manhattan_yaw
from .config import BranchConfig
from .evidence import previous_of
from .types import BranchWalls, FinalWalls, WallEvidence
from .walls import final_walls, plan_lines, point_on_wall, several_corners, signed_distance, solve_final_walls


def manhattan_frame(
    directions: Float[Array, "K 2"], weights: Float[Array, " K"]
) -> tuple[Int[Array, " K"], Float[Array, " K"]]:
    """Cluster wall directions into ``u`` (label 0) and ``u_perp`` (label 1), any yaw.

    The yaw is the weighted circular mean of ``4 theta`` (walls 90 degrees
    apart agree there).

    Returns:
        ``(labels, deviation)``: per wall its class and its angle to the
        nearest Manhattan direction (radians, in [0, pi/4]).
    """
    theta = jnp.arctan2(directions[:, 1], directions[:, 0])
    yaw = 0.25 * jnp.arctan2(jnp.sum(weights * jnp.sin(4 * theta)), jnp.sum(weights * jnp.cos(4 * theta)))
    quarter_turns = jnp.round((theta - yaw) / (math.pi / 2))
    deviation = jnp.abs(theta - yaw - quarter_turns * (math.pi / 2))
    return (quarter_turns.astype(jnp.int32) % 2), deviation


def cyclic_binary_labels(
    unary: Float[Array, "K 2"], same_cost: Float[Array, " K"], turn_cost: Float[Array, " K"], valid: Bool[Array, " K"]
) -> Int[Array, " K"]:
    """Labels ``l_j`` in {0, 1} of the valid slots (a cycle, in index order) of least total cost.

    The cost is ``sum_j unary[j, l_j]`` plus, at each corner ``j`` (between the
    previous valid slot and ``j``), ``same_cost[j]`` when the two labels agree
    and ``turn_cost[j]`` when they differ. Exact: dynamic programming over
    the chain for each label of the first slot; invalid slots pass the label
    through at no cost (slot 0 must be valid).
    """
    unary = jnp.where(valid[:, None], unary, 0.0)
    agree = jnp.eye(2, dtype=bool)
    transition = jnp.where(agree[None], same_cost[:, None, None], turn_cost[:, None, None])  # [corner, previous, label]
    transition = jnp.where(valid[:, None, None], transition, jnp.where(agree, 0.0, jnp.inf)[None])

    def chain(first):
        start = unary[0] + jnp.where(jnp.arange(2) == first, 0.0, jnp.inf)

        def forward(cost, step):
            unary_j, transition_j = step
            total = cost[:, None] + transition_j
            return jnp.min(total, axis=0) + unary_j, jnp.argmin(total, axis=0)

        cost, back = jax.lax.scan(forward, start, (unary[1:], transition[1:]))
        cost = cost + transition[0][:, first]  # the corner that closes the loop at slot 0
        last = jnp.argmin(cost)

        def backward(label, back_j):
            return back_j[label], label

        _, labels = jax.lax.scan(backward, last, back, reverse=True)
        return cost[last], jnp.concatenate([jnp.array([first]), labels])

    costs, labels = jax.vmap(chain)(jnp.arange(2))
    return labels[jnp.argmin(costs)].astype(jnp.int32)


def manhattan_labels(
    evidence: WallEvidence,
    directions: Float[Array, "K 2"],
    support: Float[Array, " K"],
    turn_weight: Float[ArrayLike, ""],
) -> Int[Array, " K"]:
    """Manhattan class of each RANSAC wall, from its direction and the corner types together.

    Walls turn by 90 degrees at every corner that is neither an occlusion nor
    a split of one plane, and each wall's direction votes for its class
    (:func:`manhattan_frame`) with its share of the ``support`` (its rows),
    less as it deviates from the frame. The labelling that disagrees least with both
    (:func:`cyclic_binary_labels`; a disagreeing corner costs ``turn_weight``,
    the best-supported wall 1) survives noisy single-wall directions, walls
    without a direction (zero support) and corners the detector missed (an odd
    number of turns: the corner that does not turn goes where the walls' own
    directions agree). A corner whose peak follows the exact label target holds
    no merged corners: not turning there costs as much as the best-supported wall's vote,
    unless its walls part there.
    """
    mask = evidence.corner_mask
    by_direction, deviation = manhattan_frame(directions, support)
    confidence = support / jnp.maximum(jnp.max(support), 1.0) * (1 - deviation / (math.pi / 4))
    unary = confidence[:, None] * (by_direction[:, None] != jnp.arange(2)[None, :])
    turn_expected = ~evidence.occluded & ~evidence.same_plane
    # a corner of the exact label target is a true corner, not two merged or a spurious one: it turns,
    # unless its walls part there (an occlusion the jump test missed)
    sure_turn = evidence.corner_exact & ~evidence.walls_part
    same_cost = jnp.where(turn_expected, jnp.where(sure_turn, 1.0, turn_weight), 0.0)
    turn_cost = jnp.where(turn_expected, 0.0, turn_weight)
    return cyclic_binary_labels(unary, same_cost, turn_cost, mask)


def _segment_directions(evidence: WallEvidence) -> tuple[Float[Array, "K 2"], Float[Array, " K"]]:
    """Per RANSAC segment, a direction and its support (rows) for :func:`manhattan_labels`.

    A fitted wall keeps its RANSAC direction and inlier count. A segment RANSAC
    could not fit (a narrow wall: a few degrees of rows fix its own metric scale
    poorly, so the single-wall solver fails) gets the direction of the plan line
    through its boundary points at the ceiling and floor heights of the fitted
    walls' joint solve, whose rows fix the heights well, with its trusted rows as support.
    """
    heights = evidence.heights
    plan = plan_lines(evidence, evidence.column_wall, heights.ceiling_height, heights.floor_height)
    usable_plan = heights.ok & jnp.all(jnp.isfinite(plan), axis=-1)
    capacity = evidence.corner_mask.shape[0]
    rows = (evidence.ceiling_trusted & evidence.floor_trusted).astype(evidence.weights.dtype) * 2
    counts = jax.ops.segment_sum(
        rows, jnp.where(evidence.column_wall >= 0, evidence.column_wall, capacity), capacity + 1
    )
    by_plan = ~evidence.fitted & evidence.corner_mask & usable_plan
    directions = jnp.where(by_plan[:, None], plan, evidence.walls.direction)
    support = jnp.where(by_plan, counts[:capacity], evidence.weights)
    return directions, support


def _place_manhattan_walls(
    cam: NonCentralPanorama, final: FinalWalls, directions: Float[Array, "K 2"], distances: Float[Array, " K"]
) -> Float[Array, " K"]:
    """Distances of the unobserved Manhattan walls: through the corner they share with their near neighbour.

    For a wall inserted at an occlusion that is the occluding corner (on the
    nearer of the two walls around it); for an unfitted wall, its start corner.
    """
    near = final.near_neighbour
    corner = point_on_wall(cam, directions[near], distances[near], final.corner_columns)
    return jnp.where(final.observed, distances, signed_distance(directions, corner))


def manhattan_walls(
    evidence: WallEvidence, config: BranchConfig, min_columns: int, max_room_height: Float[ArrayLike, ""]
) -> BranchWalls:
    """Manhattan branch (step 4 of :mod:`ncjax.pipeline.run`): a wall is observed with ``min_columns`` trusted
    columns (:func:`~ncjax.pipeline.walls.final_walls`), a room taller than ``max_room_height`` is implausible
    (:func:`~ncjax.pipeline.walls.solve_final_walls`)."""
    labels = manhattan_labels(evidence, *_segment_directions(evidence), config.turn_weight)
    same_class = labels[previous_of(evidence)] == labels
    # Manhattan walls never meet at 0 degrees: consecutive walls of one class are one plane split by a
    # spurious corner if both were fitted and each explains the other's rows; otherwise a wall lies between
    # them, one whose corners the detector merged into one peak, or an occluded one. A wall that RANSAC could
    # not fit is no sign of a spurious corner (narrow walls between close corners are the usual reason)
    one_plane = ~evidence.occluded & evidence.same_plane
    merge = evidence.corner_mask & same_class & one_plane & several_corners(evidence)
    insert = evidence.corner_mask & same_class & ~one_plane
    final = final_walls(evidence, merge, insert, True, min_columns)
    wall_labels = jnp.where(final.inserted, 1 - labels[final.start_wall], labels[final.start_wall])
    fitted = final.observed & evidence.fitted[final.start_wall]
    yaw = manhattan_yaw(evidence.walls.direction[final.start_wall], wall_labels, fitted)

    def snap(plan):
        return manhattan_directions(manhattan_yaw(plan, wall_labels, final.observed), wall_labels)

    solved, ok = solve_final_walls(evidence, final, manhattan_directions(yaw, wall_labels), snap, max_room_height)
    distances = _place_manhattan_walls(evidence.cam, final, solved.directions, solved.distances)
    heights = (solved.ceiling_height, solved.floor_height)
    return BranchWalls(final, ok, solved.directions, distances, *heights, wall_labels)
