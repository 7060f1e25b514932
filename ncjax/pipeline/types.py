"""What the pipeline returns (:class:`Layout`, :class:`LayoutStatus`) and what its stages pass on."""

from __future__ import annotations

import dataclasses
import enum

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama
from ..solvers.layout import WallLayout
from ..solvers.wall import Wall


class Rows(eqx.Module):
    """What the pipeline reads of a panorama: per column, its two boundary rows and corner probability.

    All fields traced; ``jax.vmap`` adds leading batch axes.

    Attributes:
        ceiling: ceiling-wall boundary row per column (pixels, sub-pixel; NaN = missing).
        floor: floor-wall boundary row per column.
        corner_prob: wall-wall corner probability per column, in [0, 1].
    """

    ceiling: Float[Array, "*batch W"]
    floor: Float[Array, "*batch W"]
    corner_prob: Float[Array, "*batch W"]


class Walls(eqx.Module):
    """A room's walls in the plan and its two heights (traced, ``K`` slots): what the final adjustment moves.

    Attributes:
        directions: (K, 2) unit wall directions.
        distances: (K,) signed distances of the walls from the camera's axis.
        ceiling_height: ``h_c``.
        floor_height: ``h_f``.
    """

    directions: Float[Array, "K 2"]
    distances: Float[Array, " K"]
    ceiling_height: Float[Array, ""]
    floor_height: Float[Array, ""]


class LayoutStatus(enum.IntEnum):
    """Why a layout failed (``Layout.status``); the first failing check in this order wins (see :attr:`reason`)."""

    OK = 0
    NO_SCALE = 1
    INVALID_INPUT = 2
    NO_CORNERS = 3
    TOO_MANY_WALLS = 4
    TOO_FEW_WALLS = 5
    WALL_FIT_FAILED = 6
    SOLVER_FAILED = 7
    DEGENERATE_LAYOUT = 8
    UNCERTAIN_SCALE = 9
    LOW_CONFIDENCE = 10
    SCALE_CONFLICT = 11

    def __str__(self) -> str:
        # its name, as the JSON's "status" and summary.csv give it (an IntEnum's str() is its number's)
        return self.name

    @property
    def reason(self) -> str:
        """What the status means, in words for the person who ran the reconstruction."""
        return _STATUS_REASONS[self]


_STATUS_REASONS = {
    LayoutStatus.OK: "a layout was found",
    LayoutStatus.NO_SCALE: "rc = 0: a central panorama has no metric scale",
    LayoutStatus.INVALID_INPUT: "too few columns have finite boundary rows",
    LayoutStatus.NO_CORNERS: "no corner probability peak reaches the threshold",
    LayoutStatus.TOO_MANY_WALLS: "more corners or walls than the layout's capacity K",
    LayoutStatus.TOO_FEW_WALLS: "fewer than 3 walls (4 in a Manhattan room)",
    LayoutStatus.WALL_FIT_FAILED: "RANSAC fitted fewer than 2 walls",
    LayoutStatus.SOLVER_FAILED: "the joint layout solver failed",
    LayoutStatus.DEGENERATE_LAYOUT: (
        "implausible layout: consecutive walls parallel, ceiling not above or floor not below the camera "
        "by min_height_fraction of the room height, room taller than max_room_height, corners farther than "
        "max_corner_distance or far beyond what the boundaries see (max_corner_range_ratio)"
    ),
    LayoutStatus.UNCERTAIN_SCALE: (
        "the boundaries do not fix the room's scale: the room height's standard deviation exceeds "
        "max_height_uncertainty of the height (rc small for the room's size, or walls the boundaries leave free)"
    ),
    LayoutStatus.LOW_CONFIDENCE: (
        "the network is unsure of this panorama: the layout explains fewer of its boundary rows than "
        "min_explained_fraction (clutter, doorways or textures unlike its training images); check the overlay"
    ),
    LayoutStatus.SCALE_CONFLICT: (
        "the boundaries are unlikely to be one room seen by this rig: the height their parallax measured is "
        "more than max_scale_conflict standard deviations from the height prior's, which gave the scale; "
        "check the overlay"
    ),
}

# Statuses whose layout is complete but flagged: every output keeps its geometry, marked with this label.
FLAGGED_STATUSES = {
    LayoutStatus.UNCERTAIN_SCALE: "uncertain scale",
    LayoutStatus.LOW_CONFIDENCE: "low confidence",
    LayoutStatus.SCALE_CONFLICT: "scale conflict",
}


class Layout(eqx.Module):
    """A room layout recovered from one panorama (docs/design.md section 5).

    All fields are traced arrays (``jax.vmap`` adds leading batch axes). Walls
    and corners share the ``K`` slots: corner ``k`` starts wall ``k``, walls
    run left to right in the image (decreasing azimuth) and the valid ones are
    the first slots.

    Attributes:
        ceiling_corners: (K, 3) metres, camera frame.
        floor_corners: (K, 3).
        mask: (K,) which slots are corners/walls.
        ceiling_height: ``h_c`` (m above the plane of optical centres).
        floor_height: ``h_f`` (negative).
        wall_directions: (K, 2) unit, canonical sign (camera on the left).
        wall_distances: (K,) signed distances (<= 0).
        ceiling_lines: (K, 6) Plücker lines.
        floor_lines: (K, 6).
        inserted: (K,) walls inserted for an occlusion (not seen in the image).
        corner_columns: (K,) image column of each corner as detected.
        manhattan: whether the Manhattan branch produced the layout.
        plan: whether the plan layout (:mod:`ncjax.pipeline.plan`: walls read robustly off the floor rows' plan)
            replaced the branch's, which was flagged ``LOW_CONFIDENCE``.
        explained_fraction: the fraction of the usable columns' ceiling and floor
            rows that the layout reprojects within ``PipelineConfig.inlier_threshold``
            (a quality indicator: on our test renders the 3D IoU grows with it;
            ``world="auto"`` compares the branches by it).
        corner_covariance: (K, 2, 2) first-order covariance (m^2) of each corner's
            plan position under the boundary rows' noise, estimated from the
            final adjustment's residuals and their correlation along the columns
            (:func:`ncjax.pipeline.uncertainty.layout_uncertainty`); all-infinite when the fit
            does not determine it (failed layouts included), NaN only with
            ``PipelineConfig(covariance=False)``.
            The rows' noise includes an offset per wall and the detected corner
            columns' error (``PipelineConfig.uncertainty``), calibrated on renders:
            94-96% of the true corners inside the 95% ellipse of the network's
            layouts of our test renders, 47% on real photographs, where rows leave
            the walls along whole stretches (experiments/RESULTS.md). It does not
            cover a wrong wall structure.
        height_covariance: (2, 2) covariance (m^2) of ``(h_c, h_f)``, likewise.
        status: :class:`LayoutStatus` code (int32).
        ok: ``status == OK``; corners of a failed layout are finite but meaningless.

    The per-slot fields hold zeros (False) in the slots outside ``mask``.
    """

    ceiling_corners: Float[Array, "*batch K 3"]
    floor_corners: Float[Array, "*batch K 3"]
    mask: Bool[Array, "*batch K"]
    ceiling_height: Float[Array, "*batch"]
    floor_height: Float[Array, "*batch"]
    wall_directions: Float[Array, "*batch K 2"]
    wall_distances: Float[Array, "*batch K"]
    ceiling_lines: Float[Array, "*batch K 6"]
    floor_lines: Float[Array, "*batch K 6"]
    inserted: Bool[Array, "*batch K"]
    corner_columns: Float[Array, "*batch K"]
    manhattan: Bool[Array, "*batch"]
    plan: Bool[Array, "*batch"]
    explained_fraction: Float[Array, "*batch"]
    corner_covariance: Float[Array, "*batch K 2 2"]
    height_covariance: Float[Array, "*batch 2 2"]
    status: Int[Array, "*batch"]
    ok: Bool[Array, "*batch"]


# the Layout fields with the K slots on their first (unbatched) axis
_SLOT_FIELDS = (
    "ceiling_corners",
    "floor_corners",
    "mask",
    "wall_directions",
    "wall_distances",
    "ceiling_lines",
    "floor_lines",
    "inserted",
    "corner_columns",
    "corner_covariance",
)


def pad_layout(layout: Layout, capacity: int) -> Layout:
    """``layout`` with its slots padded to ``capacity`` (static) with empty slots (zeros, mask False).

    Works on batched layouts: the slot axis follows the batch axes.
    """
    batch = layout.ok.ndim
    if layout.mask.shape[batch] == capacity:
        return layout

    def padded(x):
        widths = [(0, 0)] * x.ndim
        widths[batch] = (0, capacity - x.shape[batch])
        return jnp.pad(x, widths)

    return dataclasses.replace(layout, **{name: padded(getattr(layout, name)) for name in _SLOT_FIELDS})


class WallEvidence(eqx.Module):
    """Steps 1-3, shared by both branches (internal; all fields traced, ``K`` slots).

    Corner ``j`` starts RANSAC wall ``j``; ``previous`` is wall ``j - 1`` (cyclic).
    ``corner_exact``: the corner's peak follows the exact label target, so no other corner hides in it
    (:func:`ncjax.pipeline.corners.find_corners`).
    ``fitted``: RANSAC found wall ``j``; ``both_fitted``: walls ``j - 1`` and ``j``; ``occluded``: the boundaries
    jump at the corner; ``walls_part``: walls ``j - 1`` and ``j``, both fitted, reproject there more than
    ``occlusion_noise_factor`` times the rows' noise apart; ``jump_seen``: the rows on both sides extrapolate to the
    corner (3 columns each at least); ``jump_stands_out``: that jump exceeds ``occlusion_noise_factor`` times its
    noise (``occluded`` also needs ``occlusion_threshold``); ``same_plane``: each of walls ``j - 1`` and ``j``
    explains most inlier pixels of the other. ``ceiling_trusted`` / ``floor_trusted``: the column's row may enter
    the joint fit: usable, and an inlier of its RANSAC wall when RANSAC fitted one (a segment that holds two planes
    because a corner was missed keeps only the rows of the plane RANSAC found). ``row_weights``: the joint solvers'
    factors of the ceiling and floor rows, from each boundary's noise about the RANSAC walls
    (:func:`ncjax.pipeline.adjust.boundary_weights` on the inlier rows of the fitted walls: cut at the inlier
    threshold, so a boundary much noisier than half of it reads as less noisy than it is). ``floor_measured``: the
    floor row is the input's, not one that step 0 put where the ceiling row says (those help the walls' fits, but
    the final adjustment and its covariance use measured rows only); ``input_floor``: every column's floor row as
    the input gave it, before step 0 (the plan layout's, :mod:`~ncjax.pipeline.plan`). ``heights``: the fitted
    walls' joint solve (:func:`ncjax.solvers.layout.solve_atlanta_layout` on their RANSAC directions), for its
    ceiling and floor heights. ``row_noise``: the rows' noise about the RANSAC walls (pixels; 1.4826 x their
    median absolute error). ``cam`` and ``rows``: the camera and the rows (after step 0) the evidence was gathered from.
    """

    cam: NonCentralPanorama
    rows: Rows
    ceiling_rays: Float[Array, "W 6"]
    floor_rays: Float[Array, "W 6"]
    finite: Bool[Array, " W"]
    corner_columns: Float[Array, " K"]
    corner_mask: Bool[Array, " K"]
    corner_exact: Bool[Array, " K"]
    corner_overflow: Bool[Array, ""]
    column_wall: Int[Array, " W"]
    walls: Wall
    usable: Bool[Array, " W"]
    ceiling_trusted: Bool[Array, " W"]
    floor_trusted: Bool[Array, " W"]
    floor_measured: Bool[Array, " W"]
    input_floor: Float[Array, " W"]
    weights: Float[Array, " K"]
    row_weights: Float[Array, " 2"]
    fitted: Bool[Array, " K"]
    both_fitted: Bool[Array, " K"]
    same_plane: Bool[Array, " K"]
    occluded: Bool[Array, " K"]
    walls_part: Bool[Array, " K"]
    jump_seen: Bool[Array, " K"]
    jump_stands_out: Bool[Array, " K"]
    previous_nearer: Bool[Array, " K"]
    heights: WallLayout
    row_noise: Float[Array, ""]


class FinalWalls(eqx.Module):
    """The wall loop after merging and occlusion insertion (internal; traced, ``K`` slots).

    ``observed`` walls have enough usable columns for the joint solvers; the
    others (inserted at occlusions, or too narrow) are placed from their
    neighbours and corner rays and then held by the corner penalty.
    """

    mask: Bool[Array, " K"]
    inserted: Bool[Array, " K"]
    observed: Bool[Array, " K"]
    group: Int[Array, " K"]
    start_wall: Int[Array, " K"]
    corner_columns: Float[Array, " K"]
    corner_used: Bool[Array, " K"]
    near_neighbour: Int[Array, " K"]
    column_wall: Int[Array, " W"]
    overflow: Bool[Array, ""]


class BranchWalls(eqx.Module):
    """A branch's walls before the final adjustment (internal; traced, ``K`` slots): what steps 5-6 take.

    The Manhattan and Atlanta branches' walls are one pytree, so that ``world="auto"`` adjusts both as one
    batch. ``labels``: the Manhattan labels (0: ``u``, 1: ``u_perp``), or all
    :data:`~ncjax.pipeline.adjust.FREE_ANGLE` (an Atlanta layout: an angle per wall).
    """

    final: FinalWalls
    solver_ok: Bool[Array, ""]
    directions: Float[Array, "K 2"]
    distances: Float[Array, " K"]
    ceiling_height: Float[Array, ""]
    floor_height: Float[Array, ""]
    labels: Int[Array, " K"]

    @property
    def walls(self) -> Walls:
        """The branch's walls and heights."""
        return Walls(self.directions, self.distances, self.ceiling_height, self.floor_height)
