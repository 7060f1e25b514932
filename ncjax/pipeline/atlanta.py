"""Atlanta branch (paper Section 4.3): merged walls, walls inserted at occlusions and merged corners."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ..geometry.camera import NonCentralPanorama
from ..geometry.plucker import cross_2d
from ..geometry.polygon import previous_in_loop
from ..solvers.settings import scaled
from .adjust import FREE_ANGLE, corner_column_offset
from .config import BranchConfig
from .evidence import previous_of
from .types import BranchWalls, WallEvidence
from .walls import (
    boundary_gap,
    final_walls,
    group_directions,
    place_unobserved_walls,
    several_corners,
    solve_final_walls,
)


def _solve_atlanta_walls(evidence, merge, insert, min_columns, max_room_height) -> BranchWalls:
    """The Atlanta wall loop after merging and insertion, and its walls from the joint solver."""
    final = final_walls(evidence, merge, insert, False, min_columns)
    solved, ok = solve_final_walls(
        evidence, final, group_directions(evidence, merge, final), lambda plan: plan, max_room_height
    )
    directions, distances = place_unobserved_walls(evidence.cam, final, solved.directions, solved.distances)
    labels = jnp.full(merge.shape[0], FREE_ANGLE)
    return BranchWalls(final, ok, directions, distances, solved.ceiling_height, solved.floor_height, labels)


def corner_offsets(
    cam: NonCentralPanorama,
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    wall_mask: Bool[Array, " K"],
    corner_columns: Float[Array, " K"],
) -> Float[Array, " K"]:
    """Per corner ``k``, how far (columns) from ``corner_columns[k]`` walls ``k - 1`` and ``k`` meet (inf: never)."""
    previous = previous_in_loop(wall_mask)
    offset, meet = jax.vmap(corner_column_offset, in_axes=(0, 0, None, 0))(
        jnp.stack([directions[previous], directions], 1),
        jnp.stack([distances[previous], distances], 1),
        cam,
        corner_columns,
    )
    offset = jnp.abs(offset)
    return jnp.where((meet | ~wall_mask) & jnp.isfinite(offset), offset, jnp.inf)


def _stray_corners(evidence: WallEvidence, walls: BranchWalls, config: BranchConfig) -> Bool[Array, " K"]:
    """Corners of two observed walls that hold a wall between them whose two corners gave one peak.

    The two walls meet more than ``max_corner_offset`` columns from the corner (or are parallel). Noisy
    directions of walls that turn a little move their meeting far along them, but not their boundaries
    apart at the corner: there the two walls' rows must also differ by more than ``stray_noise_factor``
    times the rows' noise. At a corner whose peak follows the exact label target (no corner hides in it),
    the rows' jump there must stand out of its noise instead, where both sides' rows measure it.
    """
    cam, final = evidence.cam, walls.final
    directions, distances, h_c, h_f = walls.directions, walls.distances, walls.ceiling_height, walls.floor_height
    previous = previous_in_loop(final.mask)
    both_observed = final.observed & final.observed[previous]
    offsets = corner_offsets(cam, directions, distances, final.mask, final.corner_columns)
    gap, _ = boundary_gap(
        cam,
        (directions, distances, h_c, h_f),
        (directions[previous], distances[previous], h_c, h_f),
        final.corner_columns,
    )
    # at a corner of the exact label target only an occlusion can hide a wall: where the rows' own jump is
    # measured, it must stand out of its noise (the occlusion test without its fixed threshold); fitted
    # walls as narrow as the corner's neighbours often are part there under row noise
    corner = final.start_wall
    apart = jnp.where(
        evidence.corner_exact[corner] & evidence.jump_seen[corner],
        evidence.jump_stands_out[corner],
        ~(gap <= config.stray_noise_factor * evidence.row_noise),
    )
    return both_observed & (offsets > scaled(config.max_corner_offset, cam.width, 1024)) & apart


def atlanta_walls(
    evidence: WallEvidence, config: BranchConfig, min_columns: int, max_room_height: Float[ArrayLike, ""]
) -> BranchWalls:
    """Atlanta branch (step 4 of :mod:`ncjax.pipeline.run`; ``min_columns`` and ``max_room_height`` as in
    :func:`~ncjax.pipeline.manhattan.manhattan_walls`)."""
    ransac_directions = evidence.walls.direction
    turn = cross_2d(ransac_directions[previous_of(evidence)], ransac_directions)
    parallel = jnp.abs(turn) < jnp.sin(jnp.radians(config.merge_angle))
    merge = evidence.same_plane & parallel & ~evidence.occluded & several_corners(evidence)
    capacity = merge.shape[0]

    def one_pass(insert, _):
        # the walls with those of ``insert`` inserted (in the corner ray's plane, as at an occlusion), and
        # ``insert`` with the stray corners of that layout's walls
        walls = _solve_atlanta_walls(evidence, merge, insert, min_columns, max_room_height)
        stray = _stray_corners(evidence, walls, config)
        return insert.at[jnp.where(stray, walls.final.start_wall, capacity)].set(True, mode="drop"), walls

    # the walls at the occlusions, then with the stray corners' walls too: one traced pass run twice
    _, passes = jax.lax.scan(one_pass, evidence.occluded, length=2)
    return jax.tree.map(lambda x: x[1], passes)
