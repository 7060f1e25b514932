"""The geometric pipeline: per-column boundaries to a metric layout (paper Section 4.4, Fig. pipeline_geom).

0. Floor rows the ceiling contradicts (not in the paper): every ray of a column
   leaves one centre in one vertical plane, so ``tan(ceiling elevation) /
   tan(floor elevation) = h_c / h_f`` in every column. A floor row more than
   ``floor_consistency_threshold`` pixels from the row that the ceiling row and
   the panorama's median ratio give is replaced by that row
   (:func:`ceiling_consistent_floor`): furniture hides the floor-wall line far
   more often than anything hides the ceiling's. The replaced rows serve the
   walls' fits (steps 2-4); the final adjustment and its covariance (step 5)
   use the measured rows only, so they add no information the image lacks.
1. Corners from the corner probability (:mod:`ncjax._corners`); the columns
   between consecutive corners are one wall.
2. Per-wall RANSAC with the single-wall solver (:mod:`ncjax._ransac`).
3. At each corner, the boundaries of the two walls are compared at the
   corner column (lines through the rows on either side, and the two RANSAC
   walls' reprojections; the smaller difference counts): a jump of more than
   ``occlusion_threshold`` pixels, and more than ``occlusion_noise_factor``
   times the rows' noise about their walls, means an occlusion (the paper tests the
   same in 3D for Atlanta rooms; in pixels the test does not depend on the
   single walls' noisy scale). Consecutive walls each of which explains the
   other's pixels may be one wall split by a spurious corner.
4. Manhattan branch: each wall labelled ``u`` / ``u_perp`` (any yaw) from its
   direction (RANSAC's; for a wall RANSAC could not fit, its plan line at the
   heights of the fitted walls' joint solve) and the corner types together (a
   least-cost labelling of the wall cycle); consecutive walls of one class are
   merged when they are one plane, otherwise (an occlusion, or a narrow wall
   whose two corners gave one peak) a perpendicular wall is inserted through
   the nearer corner; the Manhattan layout solver.
   Atlanta branch: RANSAC directions, walls of one plane merged when their
   directions also agree within ``merge_angle``, a wall in the vertical
   plane of the corner ray at each occlusion, the Atlanta layout solver;
   then also such a wall at each corner whose two walls meet more than
   ``max_corner_offset`` columns from it (not in the paper: a narrow wall
   whose two corners gave one peak), and the solver again.
   Both branches' solvers weight the ceiling and floor rows by each
   boundary's noise about the RANSAC walls (not in the paper: a network's
   floor rows are several times noisier than its ceiling rows).
5. Final adjustment (:mod:`ncjax._adjust`, optimistix least squares) of both branches, its
   rows weighted likewise: the paper adjusts the Atlanta branch only; the Manhattan branch
   keeps one yaw.
6. Corners where consecutive walls meet.

``world="auto"`` (not in the paper) runs both branches and keeps the one that
succeeds, or, when both do, the Manhattan layout if it reprojects more of the
boundary rows within the inlier threshold than the Atlanta one; on a tie
(exact rows), if every RANSAC wall lies within ``manhattan_tolerance`` degrees
of the two perpendicular directions that fit them best (:func:`choose_manhattan`).

Everything has fixed capacity ``K`` (DESIGN.md section 4); failures are
status values (:class:`LayoutStatus`), never exceptions, inside traced code.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ._adjust import (
    BoundaryObservations,
    LayoutUncertainty,
    adjust_layout,
    boundary_weights,
    corner_column_offset,
    layout_residuals,
    layout_uncertainty,
    loop_corners,
    manhattan_directions,
    manhattan_yaw,
    not_computed,
    previous_walls,
    room_height_sigma,
)
from ._camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles, pixel_to_ray
from ._corners import column_walls, distance_to_corners, find_corners, side_extrapolation
from ._layout_solvers import solve_atlanta_layout
from ._plucker import cross_2d, horizontal_wall_line
from ._ransac import boundary_errors, num_hypotheses, ransac_wall, wall_columns
from ._reprojection import boundary_points, column_directions, fit_plan_lines, range_along, wall_boundary_rows
from ._wall import Wall, canonical_orientation

WORLDS = ("manhattan", "atlanta", "auto")
# longest lag (columns of a 1024-wide panorama) over which the boundary rows' errors count as correlated
_CORRELATION_COLUMNS = 256.0


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
        "implausible layout: consecutive walls parallel, ceiling not above or floor not below the camera, "
        "room taller than max_room_height or corners farther than max_corner_distance"
    ),
    LayoutStatus.UNCERTAIN_SCALE: (
        "the boundaries do not fix the room's scale: the room height's standard deviation exceeds "
        "max_height_uncertainty of the height (rc small for the room's size, or walls the boundaries leave free)"
    ),
}


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Parameters of the pipeline (static: hashable, changing them recompiles).

    Column and pixel quantities are given for the 1024 x 512 reference
    panorama and scaled with the camera's width and height.

    Attributes:
        capacity: K, wall and corner slots of the layout.
        compact_capacity: :func:`layout_from_boundaries` first runs concrete
            panoramas with this many slots, pads their Layouts to ``capacity``
            and reruns with ``capacity`` slots only the panoramas that did not
            fit (``TOO_MANY_WALLS``): the same layouts, and the cost of most
            stages is proportional to the slots (0: always ``capacity``).
        corner_threshold: minimum corner probability of a peak.
        min_corners: where fewer peaks than this reach ``corner_threshold``
            (a network unsure of an image unlike its training data), the
            strongest peaks down to ``fallback_corner_threshold`` make up the
            count (:func:`~ncjax._corners.find_corners`; 0: off; at most
            ``capacity`` and ``compact_capacity``).
        fallback_corner_threshold: the lowest peak probability ``min_corners``
            accepts (at or above ``corner_threshold``: no fallback).
        nms_radius: non-maximum-suppression half-width, columns.
        corner_margin: columns this close to a corner are not used to fit walls.
        success_probability: RANSAC's P (paper: 0.9999).
        outlier_rate: RANSAC's epsilon (paper: 0.2).
        sample_size: columns per RANSAC hypothesis (paper: 3).
        ransac_columns: columns per wall on which RANSAC scores its hypotheses
            and refits the best one, evenly spaced along the wall (all of them
            for a narrower wall); the cost grows with it, not with the width.
        inlier_threshold: row error of an inlier, pixels.
        occlusion_threshold: boundary jump at a corner that means an occlusion, pixels.
        occlusion_noise_factor: the jump must also exceed this many times the
            boundary noise, estimated from the rows about their RANSAC walls
            (0: the fixed threshold alone).
        merge_fraction: consecutive walls each of which explains at least
            this fraction of the other's inlier pixels may be one wall.
        merge_angle: Atlanta: such walls are merged only if their directions
            differ by less than this (degrees): a shallow corner between two
            walls seen far away passes the pixel test (Manhattan merges
            walls of one class, see :func:`_manhattan_layout`).
        max_corner_offset: Atlanta: where two observed walls meet farther than
            this (columns) from their corner's column, or not at all, the
            corner's peak holds two corners (the network's lobes merge close
            ones) and a wall is inserted between them in the corner ray's
            plane, as at an occlusion. Chosen on the tuning renders
            (experiments/RESULTS.md, session 21): 24-128 did about alike.
        manhattan_tolerance: ``world="auto"``: largest deviation (degrees) of a
            RANSAC wall from the Manhattan frame for the Manhattan branch to win
            a tie (:func:`choose_manhattan`).
        turn_weight: Manhattan labelling: cost of a corner whose walls do not
            turn as its type says, relative to the best-supported wall's
            direction vote (:func:`manhattan_labels`). Small: the walls'
            directions decide and the corner types break ties. Corners
            that the detector merged make the expected turns wrong, and on
            the network's rows a weight of 0.5 mislabelled walls in many
            rooms (experiments/RESULTS.md, session 21).
        corner_weight: weight of the corner-plane penalty of the adjustment.
        min_boundary_noise: the joint solvers and both adjustment passes weight
            the ceiling and floor rows by the squared inverse of each boundary's
            noise (about the RANSAC walls, about each pass's starting layout),
            taken as at least this (pixels): exact rows keep equal weights, and
            a value far above the rows' errors turns all the weighting off
            (:func:`ncjax._adjust.boundary_weights`).
        adjustment_steps: most least-squares (dogleg) steps of each of the two adjustment passes.
        adjustment_tolerance: the dogleg stops when a step changes every
            parameter (radians, metres) and every residual (pixels) by less
            than this plus this times its size (optimistix's Cauchy test).
            Float32 rounds the rows' residuals at about 1e-5 px, so a tighter
            test is never met and every panorama runs ``adjustment_steps``.
        adjustment_stride: the adjustment fits every this-many-th column (1:
            all); its cost is proportional to the number of columns it fits.
            2 (the default) halves that cost: on the network's rows, whose errors
            are correlated over tens of columns, the layouts are as accurate as
            with 1; under white noise of 1 px the corner error grows by 15-35%
            (experiments/RESULTS.md, session 15).
        inlier_pass_stride: the first adjustment pass, whose layout only
            picks the inlier rows of the second (and is its start), fits every
            this-many-th of the second's columns (1: the same columns).
        chunk_size: a batch runs this many panoramas at a time (one ``vmap``),
            chunk after chunk inside the same jitted call: a larger ``vmap``
            leaves the CPU's caches and runs slower per panorama (0: all at once).
        covariance: compute ``Layout.corner_covariance`` and ``height_covariance``
            (a Jacobian of the final adjustment: 10-20% of the batched throughput
            in our benchmark); False leaves them NaN.
        min_finite_fraction: fraction of columns with finite rows needed.
        max_height_uncertainty: a layout whose room height ``h_c - h_f`` has a
            standard deviation (:attr:`Layout.height_covariance`) above this
            fraction of the height fails with ``UNCERTAIN_SCALE``: the rows do
            not fix its scale (a baseline ``rc`` small for the room's size, or
            walls whose positions the rows leave free, where the covariance
            is infinite). Off (inf) by default; the network's configuration
            sets it (``ncjax._reconstruct.NETWORK_PIPELINE_CONFIG``). Needs
            ``covariance``.
        max_room_height: a layout whose ceiling is more than this above its
            floor (metres) is implausible (DEGENERATE_LAYOUT), e.g. a wall fit
            whose scale ran away.
        max_corner_distance: a layout with a corner farther than this from
            the camera (metres) is implausible (DEGENERATE_LAYOUT).
        floor_consistency_threshold: pixels; a floor row farther than this
            from the one its column's ceiling row implies is replaced by it
            (step 0, :func:`ceiling_consistent_floor`). Off (inf) by default;
            the network's configuration sets it.
    """

    capacity: int = 32
    compact_capacity: int = 16
    corner_threshold: float = 0.3
    min_corners: int = 4
    fallback_corner_threshold: float = 0.1
    nms_radius: float = 2.0
    corner_margin: float = 2.0
    success_probability: float = 0.9999
    outlier_rate: float = 0.2
    sample_size: int = 3
    ransac_columns: int = 64
    inlier_threshold: float = 3.0
    occlusion_threshold: float = 4.0
    occlusion_noise_factor: float = 5.0
    merge_fraction: float = 0.8
    merge_angle: float = 5.0
    max_corner_offset: float = 32.0
    manhattan_tolerance: float = 5.0
    turn_weight: float = 0.02
    corner_weight: float = 1.0
    min_boundary_noise: float = 0.5
    adjustment_steps: int = 8
    adjustment_tolerance: float = 1e-4
    adjustment_stride: int = 2
    inlier_pass_stride: int = 4
    chunk_size: int = 32
    covariance: bool = True
    min_finite_fraction: float = 0.5
    max_height_uncertainty: float = math.inf
    max_room_height: float = 10.0
    max_corner_distance: float = 50.0
    floor_consistency_threshold: float = math.inf

    def __post_init__(self):
        if self.capacity < 4:
            raise ValueError(f"capacity must be >= 4 walls, got {self.capacity}")
        if self.compact_capacity != 0 and self.compact_capacity < 4:
            raise ValueError(f"compact_capacity must be 0 (off) or >= 4 walls, got {self.compact_capacity}")
        if self.sample_size < 3:
            raise ValueError(f"sample_size must be >= 3 columns (the wall solver needs 3 rays per line), got {self.sample_size}")
        num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)  # validates
        if self.ransac_columns < 2 * self.sample_size:
            raise ValueError(f"ransac_columns must be >= 2 * sample_size, got {self.ransac_columns}")
        positive = (
            "nms_radius", "inlier_threshold", "occlusion_threshold", "merge_fraction", "merge_angle", "max_corner_offset",
            "manhattan_tolerance", "turn_weight", "adjustment_tolerance", "min_boundary_noise", "max_height_uncertainty",
            "floor_consistency_threshold",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if math.isfinite(self.max_height_uncertainty) and not self.covariance:
            raise ValueError("max_height_uncertainty needs covariance=True (it tests the height's covariance)")
        if self.occlusion_noise_factor < 0:
            raise ValueError(f"occlusion_noise_factor must be >= 0, got {self.occlusion_noise_factor}")
        for name in ("adjustment_stride", "inlier_pass_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1 column, got {getattr(self, name)}")
        slots = min(self.capacity, self.compact_capacity or self.capacity)
        if not 0 <= self.min_corners <= slots:
            raise ValueError(f"min_corners must be in [0, {slots}] (capacity and compact_capacity), got {self.min_corners}")
        if not self.fallback_corner_threshold >= 0:
            raise ValueError(f"fallback_corner_threshold must be >= 0, got {self.fallback_corner_threshold}")
        if self.corner_margin < 0 or self.corner_weight < 0 or self.adjustment_steps < 0 or self.chunk_size < 0:
            raise ValueError("corner_margin, corner_weight, adjustment_steps and chunk_size must be >= 0")

    @property
    def hypotheses(self) -> int:
        """RANSAC hypotheses per wall (paper's n_hyp)."""
        return num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)


class Layout(eqx.Module):
    """A room layout recovered from one panorama (DESIGN.md section 5).

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
        explained_fraction: the fraction of the usable columns' ceiling and floor
            rows that the layout reprojects within ``PipelineConfig.inlier_threshold``
            (a quality indicator: on our test renders the 3D IoU grows with it;
            ``world="auto"`` compares the branches by it).
        corner_covariance: (K, 2, 2) first-order covariance (m^2) of each corner's
            plan position under the boundary rows' noise, estimated from the
            final adjustment's residuals and their correlation along the columns
            (:func:`ncjax._adjust.layout_uncertainty`); infinite when the fit
            does not determine it, NaN with ``PipelineConfig(covariance=False)``.
            Calibrated for rows with independent or short-range correlated
            noise; a network's errors are correlated over whole walls and partly
            absorbed by the fit, so there the ellipses are too small (about 55%
            of the true corners inside the 95% ellipse on our test renders). It
            does not cover a wrong wall structure.
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
    explained_fraction: Float[Array, "*batch"]
    corner_covariance: Float[Array, "*batch K 2 2"]
    height_covariance: Float[Array, "*batch 2 2"]
    status: Int[Array, "*batch"]
    ok: Bool[Array, "*batch"]


# the Layout fields with the K slots on their first (unbatched) axis
_SLOT_FIELDS = (
    "ceiling_corners", "floor_corners", "mask", "wall_directions", "wall_distances", "ceiling_lines",
    "floor_lines", "inserted", "corner_columns", "corner_covariance",
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
    ``fitted``: RANSAC found wall ``j``; ``both_fitted``: walls ``j - 1`` and ``j``;
    ``occluded``: the boundaries jump at the corner; ``same_plane``: each of walls ``j - 1`` and ``j`` explains most
    inlier pixels of the other. ``ceiling_trusted`` / ``floor_trusted``: the column's row may enter the joint
    fit: usable, and an inlier of its RANSAC wall when RANSAC fitted one (a segment that holds two planes
    because a corner was missed keeps only the rows of the plane RANSAC found). ``row_weights``: the joint
    solvers' factors of the ceiling and floor rows, from each boundary's noise about the RANSAC walls
    (:func:`ncjax._adjust.boundary_weights` on the inlier rows of the fitted walls: cut at the inlier
    threshold, so a boundary much noisier than half of it reads as less noisy than it is).
    ``floor_measured``: the floor row is the input's, not one that step 0 put where the ceiling row says
    (those help the walls' fits, but the final adjustment and its covariance use measured rows only).
    """

    ceiling_rays: Float[Array, "W 6"]
    floor_rays: Float[Array, "W 6"]
    finite: Bool[Array, " W"]
    corner_columns: Float[Array, " K"]
    corner_mask: Bool[Array, " K"]
    corner_overflow: Bool[Array, ""]
    column_wall: Int[Array, " W"]
    walls: Wall
    usable: Bool[Array, " W"]
    ceiling_trusted: Bool[Array, " W"]
    floor_trusted: Bool[Array, " W"]
    floor_measured: Bool[Array, " W"]
    weights: Float[Array, " K"]
    row_weights: Float[Array, " 2"]
    fitted: Bool[Array, " K"]
    both_fitted: Bool[Array, " K"]
    same_plane: Bool[Array, " K"]
    occluded: Bool[Array, " K"]
    previous_nearer: Bool[Array, " K"]


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


def _scaled(value: float, size: int, reference: int) -> float:
    return value * size / reference


def _min_noise(config: PipelineConfig, cam: NonCentralPanorama) -> float:
    """``min_boundary_noise`` in this panorama's pixels."""
    return config.min_boundary_noise * _scaled(1.0, cam.height, 512)


def _nms_radius(config: PipelineConfig, width: int) -> int:
    return max(1, round(_scaled(config.nms_radius, width, 1024)))


def _gather_evidence(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    corner_prob: Float[Array, " W"],
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    config: PipelineConfig,
) -> WallEvidence:
    """Steps 1-3: corners, one RANSAC wall between each pair, and the boundary jump at each corner."""
    width, capacity = cam.width, config.capacity
    finite = jnp.isfinite(ceiling_v) & jnp.isfinite(floor_v)
    ceiling_v = jnp.where(finite, ceiling_v, cam.height / 4)
    floor_v = jnp.where(finite, floor_v, 3 * cam.height / 4)
    columns = jnp.arange(width, dtype=ceiling_v.dtype)
    azimuth = column_directions(cam, columns)
    ceiling_rays = pixel_to_ray(cam, columns, ceiling_v)
    floor_rays = pixel_to_ray(cam, columns, floor_v)

    corner_prob = jnp.where(jnp.isfinite(corner_prob), corner_prob, 0.0)
    corner_columns, corner_mask, overflow = find_corners(
        corner_prob, capacity, _nms_radius(config, width), config.corner_threshold,
        config.min_corners, config.fallback_corner_threshold,
    )
    column_wall = column_walls(corner_columns, corner_mask, width)
    away = distance_to_corners(corner_columns, corner_mask, width) >= _scaled(config.corner_margin, width, 1024)
    wall_of = jnp.where(column_wall >= 0, column_wall, capacity)  # segment ids, capacity: none
    seen_away = jax.ops.segment_sum((finite & away).astype(jnp.int32), wall_of, capacity + 1)
    # narrow walls (seen almost edge-on) keep the columns next to their corners
    few = seen_away < 2 * config.sample_size
    usable = finite & (column_wall >= 0) & (away | few[wall_of])

    pixels = _scaled(1.0, cam.height, 512)
    threshold = config.inlier_threshold * pixels
    sampled, sampled_valid = wall_columns(column_wall, usable, corner_columns, config.ransac_columns)
    walls = jax.vmap(ransac_wall, in_axes=(0, None, 0, 0, 0, 0, None, None, None))(
        jax.random.split(key, capacity),
        cam,
        azimuth[sampled],
        ceiling_rays[sampled],
        floor_rays[sampled],
        sampled_valid,
        config.hypotheses,
        config.sample_size,
        threshold,
    )

    previous = previous_walls(corner_mask)
    following = (jnp.arange(capacity) + 1) % jnp.maximum(jnp.sum(corner_mask), 1)
    wall = jnp.maximum(column_wall, 0)

    def errors_of(index):
        """Row errors of wall ``index[column]`` at each column (one wall per column, not K x W)."""
        return boundary_errors(cam, jax.tree.map(lambda x: x[index], walls), azimuth, ceiling_v, floor_v)

    ceiling_error, floor_error = errors_of(wall)
    ceiling_in, floor_in = usable & (ceiling_error < threshold), usable & (floor_error < threshold)
    inliers = ceiling_in | floor_in
    counts = jax.ops.segment_sum(ceiling_in.astype(jnp.int32) + floor_in, wall_of, capacity + 1)[:capacity]
    weights = jnp.where(walls.ok & corner_mask, counts, 0)

    def explained_fraction(neighbour):
        """Per wall, the fraction of its inlier columns whose rows wall ``neighbour[wall]`` explains too."""
        neighbour_ceiling, neighbour_floor = errors_of(neighbour[wall])
        explained = inliers & (neighbour_ceiling < threshold) & (neighbour_floor < threshold)
        total = jax.ops.segment_sum(jnp.stack([explained, inliers], -1).astype(jnp.int32), wall_of, capacity + 1)
        return total[:capacity, 0] / jnp.maximum(total[:capacity, 1], 1)

    # the boundary jump at each corner, from lines fitted to the rows on either side
    margin = _scaled(config.corner_margin, width, 1024)
    window = max(3, round(_scaled(8.0, width, 1024)))

    def extrapolate(rows, wall, side):
        own = finite[None, :] & (column_wall[None, :] == wall[:, None])
        return jax.vmap(side_extrapolation, in_axes=(None, 0, 0, None, None, None))(
            rows, own, corner_columns, side, window, margin
        )

    ceiling_here, seen_here = extrapolate(ceiling_v, jnp.arange(capacity), 1)
    floor_here, _ = extrapolate(floor_v, jnp.arange(capacity), 1)
    ceiling_before, seen_before = extrapolate(ceiling_v, previous, -1)
    floor_before, _ = extrapolate(floor_v, previous, -1)
    jump = jnp.maximum(jnp.abs(ceiling_here - ceiling_before), jnp.abs(floor_here - floor_before))
    fitted = walls.ok & corner_mask
    both_fitted = fitted & fitted[previous]

    def reprojected_rows(index):
        wall_ = jax.tree.map(lambda x: x[index], walls)
        return wall_boundary_rows(
            cam, wall_.direction, wall_.distance, wall_.ceiling_height, wall_.floor_height, corner_columns
        )

    # two fitted walls that meet at the corner reproject to one point there; a
    # line through the rows beside the corner misses it on a steep, curved boundary
    ceiling_a, floor_a, seen_a = reprojected_rows(jnp.arange(capacity))
    ceiling_b, floor_b, seen_b = reprojected_rows(previous)
    wall_jump = jnp.maximum(jnp.abs(ceiling_a - ceiling_b), jnp.abs(floor_a - floor_b))
    jump = jnp.where(both_fitted & seen_a & seen_b, jnp.minimum(jump, wall_jump), jump)
    # each of walls j - 1 and j explains most inliers of the other
    same_plane = (explained_fraction(previous) >= config.merge_fraction) & (
        explained_fraction(following)[previous] >= config.merge_fraction
    )
    # noisy rows make the jump noisy too: it must also stand out of the noise, whose scale is
    # robustly 1.4826 x the median row error of the usable columns about their RANSAC walls
    residuals = jnp.concatenate([ceiling_error, floor_error])
    residuals = jnp.where(jnp.tile(usable, 2) & jnp.isfinite(residuals), residuals, jnp.nan)
    noise = 1.4826 * jnp.nanmedian(residuals)
    noise = jnp.where(jnp.isfinite(noise), noise, 0.0)
    jump_threshold = jnp.maximum(config.occlusion_threshold * pixels, config.occlusion_noise_factor * noise)
    occluded = corner_mask & seen_here & seen_before & (jump > jump_threshold)
    previous_nearer = (floor_before - ceiling_before) > (floor_here - ceiling_here)
    on_fitted = fitted[wall]
    row_weights = boundary_weights(
        ceiling_error, floor_error, ceiling_in & on_fitted, floor_in & on_fitted, _min_noise(config, cam)
    )
    return WallEvidence(
        ceiling_rays=ceiling_rays,
        floor_rays=floor_rays,
        finite=finite,
        corner_columns=corner_columns,
        corner_mask=corner_mask,
        corner_overflow=overflow,
        column_wall=column_wall,
        walls=walls,
        usable=usable,
        ceiling_trusted=ceiling_in | (usable & ~on_fitted),
        floor_trusted=floor_in | (usable & ~on_fitted),
        floor_measured=jnp.ones_like(usable),
        weights=weights.astype(ceiling_v.dtype),
        row_weights=row_weights,
        fitted=fitted,
        both_fitted=both_fitted,
        same_plane=both_fitted & same_plane,
        occluded=occluded,
        previous_nearer=previous_nearer,
    )


def _previous(evidence: WallEvidence) -> Int[Array, " K"]:
    return previous_walls(evidence.corner_mask)


def wall_groups(corner_mask: Bool[Array, " K"], merge: Bool[Array, " K"]) -> tuple[Int[Array, " K"], Int[Array, ""]]:
    """Group of each RANSAC wall after merging, and the number of groups.

    A corner that is not merged starts a group; walls before the first start
    belong to the last group (the loop wraps).
    """
    starts = corner_mask & ~merge
    num_groups = jnp.sum(starts)
    group = jnp.cumsum(starts) - 1
    return jnp.where(group < 0, num_groups - 1, group), num_groups


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
    evidence: WallEvidence, directions: Float[Array, "K 2"], support: Float[Array, " K"], turn_weight: float
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
    directions agree).
    """
    mask = evidence.corner_mask
    by_direction, deviation = manhattan_frame(directions, support)
    confidence = support / jnp.maximum(jnp.max(support), 1.0) * (1 - deviation / (math.pi / 4))
    unary = confidence[:, None] * (by_direction[:, None] != jnp.arange(2)[None, :])
    turn_expected = ~evidence.occluded & ~evidence.same_plane
    same_cost = jnp.where(turn_expected, turn_weight, 0.0)
    turn_cost = jnp.where(turn_expected, 0.0, turn_weight)
    return cyclic_binary_labels(unary, same_cost, turn_cost, mask)


def _segment_directions(
    cam: NonCentralPanorama, evidence: WallEvidence, ceiling_v, floor_v, config: PipelineConfig
) -> tuple[Float[Array, "K 2"], Float[Array, " K"]]:
    """Per RANSAC segment, a direction and its support (rows) for :func:`manhattan_labels`.

    A fitted wall keeps its RANSAC direction and inlier count. A segment RANSAC
    could not fit (a narrow wall: a few degrees of rows fix its own metric scale
    poorly, so the single-wall solver fails) gets the direction of the plan line
    through its boundary points at the ceiling and floor heights of the fitted
    walls' joint solve, whose rows fix the heights well, with its trusted rows as support.
    """
    heights = solve_atlanta_layout(
        evidence.ceiling_rays, evidence.floor_rays, _fit_index(evidence, evidence.column_wall), evidence.fitted,
        evidence.walls.direction, boundary_weights=evidence.row_weights,
    )
    plan = _plan_lines(cam, evidence, evidence.column_wall, ceiling_v, floor_v, heights.ceiling_height, heights.floor_height)
    usable_plan = heights.ok & jnp.all(jnp.isfinite(plan), axis=-1)
    capacity = evidence.corner_mask.shape[0]
    rows = (evidence.ceiling_trusted & evidence.floor_trusted).astype(evidence.weights.dtype) * 2
    counts = jax.ops.segment_sum(rows, jnp.where(evidence.column_wall >= 0, evidence.column_wall, capacity), capacity + 1)
    by_plan = ~evidence.fitted & evidence.corner_mask & usable_plan
    directions = jnp.where(by_plan[:, None], plan, evidence.walls.direction)
    support = jnp.where(by_plan, counts[:capacity], evidence.weights)
    return directions, support


def _final_walls(
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
    start_corner = jnp.zeros(capacity, jnp.int32).at[jnp.where(starts, group_of_wall, capacity)].set(
        jnp.arange(capacity, dtype=jnp.int32), mode="drop"
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
    columns_seen = jax.ops.segment_sum(trusted.astype(jnp.int32), jnp.where(column_wall >= 0, column_wall, capacity), capacity + 1)
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


def _group_directions(evidence: WallEvidence, merge: Bool[Array, " K"], final: FinalWalls) -> Float[Array, "K 2"]:
    """Per final wall, the inlier-weighted mean direction of its merged RANSAC walls."""
    capacity = merge.shape[0]
    group_of_wall, _ = wall_groups(evidence.corner_mask, merge)
    group_of_wall = jnp.where(evidence.corner_mask, group_of_wall, capacity)
    # canonical signs (camera on the left) agree for walls of one plane
    summed = jax.ops.segment_sum(evidence.weights[:, None] * evidence.walls.direction, group_of_wall, capacity + 1)
    return summed[final.group]


def _observations(
    evidence: WallEvidence, final: FinalWalls, ceiling_v, floor_v, height: int, stride: int
) -> BoundaryObservations:
    """The adjustment's data: every ``stride``-th column (the cost of a step grows with their number)."""
    observations = BoundaryObservations(
        columns=jnp.arange(ceiling_v.shape[0]),
        ceiling_v=jnp.where(evidence.finite, ceiling_v, height / 4),
        floor_v=jnp.where(evidence.finite, floor_v, 3 * height / 4),
        ceiling_used=evidence.ceiling_trusted & (final.column_wall >= 0),
        floor_used=evidence.floor_trusted & evidence.floor_measured & (final.column_wall >= 0),
        column_wall=final.column_wall,
        corner_columns=final.corner_columns,
        corner_used=final.corner_used,
        wall_mask=final.mask,
    )
    return _strided(observations, stride)


_PER_COLUMN_FIELDS = ("columns", "ceiling_v", "floor_v", "ceiling_used", "floor_used", "column_wall")


def _strided(observations: BoundaryObservations, stride: int) -> BoundaryObservations:
    """Every ``stride``-th of the observed columns; the per-wall fields are kept."""
    return dataclasses.replace(
        observations, **{name: getattr(observations, name)[::stride] for name in _PER_COLUMN_FIELDS}
    )


def _fit_index(evidence: WallEvidence, column_wall: Int[Array, " W"]) -> Int[Array, " W"]:
    """Columns fed to the joint solvers, by wall: those whose ceiling and floor rows are both trusted (:class:`WallEvidence`)."""
    return jnp.where(evidence.ceiling_trusted & evidence.floor_trusted, column_wall, -1)


def _row_errors(cam, observations: BoundaryObservations, walls) -> tuple[Float[Array, " N"], Float[Array, " N"]]:
    """Ceiling and floor row errors (pixels) of the observed columns on the walls ``(directions, distances, h_c, h_f)``."""
    errors = layout_residuals(*walls, cam, observations, 0.0)
    count = observations.columns.shape[0]
    return errors[:count], errors[count : 2 * count]


def _using(observations: BoundaryObservations, ceiling_used, floor_used) -> BoundaryObservations:
    return eqx.tree_at(lambda o: (o.ceiling_used, o.floor_used), observations, (ceiling_used, floor_used))


def _noise_weighted(cam, observations: BoundaryObservations, errors, config) -> BoundaryObservations:
    """``observations`` with each boundary's rows weighted by the squared inverse of its noise, from its
    rows' ``errors`` (ceiling, floor) about a layout (:func:`ncjax._adjust.boundary_weights`)."""
    weights = boundary_weights(*errors, observations.ceiling_used, observations.floor_used, _min_noise(config, cam))
    return eqx.tree_at(lambda o: o.row_weights, observations, weights)


def _refine(cam, evidence, final, ceiling_v, floor_v, directions, distances, h_c, h_f, labels, config):
    """Step 5: adjust on the trusted columns, keep the inliers of that layout, adjust again.

    Each pass weights the ceiling and floor rows by the squared inverse of each
    boundary's noise about its starting layout (:func:`ncjax._adjust.boundary_weights`).
    The second pass estimates it on its inlier rows, whose errors are cut at
    ``inlier_threshold``: a boundary noisier than about half the threshold reads
    as less noisy than it is, which softens the weighting (it was tuned so, on
    tuning renders). The first pass only has to bring the layout within
    ``inlier_threshold`` of the inlier rows, so it fits a subset of the columns
    (``inlier_pass_stride``); the second starts next to its optimum.

    Returns:
        The adjusted walls (:func:`ncjax._adjust.adjust_layout`), the fraction of the usable
        columns' ceiling and floor rows they reproject within ``inlier_threshold``, and their
        :func:`ncjax._adjust.layout_uncertainty` on the rows of the second adjustment.
    """
    observations = _observations(evidence, final, ceiling_v, floor_v, cam.height, config.adjustment_stride)
    subset = _strided(observations, config.inlier_pass_stride)
    subset = _noise_weighted(cam, subset, _row_errors(cam, subset, (directions, distances, h_c, h_f)), config)
    adjusted = adjust_layout(
        cam, subset, directions, distances, h_c, h_f, labels, config.corner_weight, config.adjustment_steps,
        config.adjustment_tolerance,
    )
    threshold = config.inlier_threshold * _scaled(1.0, cam.height, 512)
    ceiling_error, floor_error = _row_errors(cam, observations, adjusted[:4])
    inliers = _using(
        observations,
        observations.ceiling_used & (jnp.abs(ceiling_error) < threshold),
        observations.floor_used & (jnp.abs(floor_error) < threshold),
    )
    inliers = _noise_weighted(cam, inliers, (ceiling_error, floor_error), config)
    adjusted = adjust_layout(
        cam, inliers, *adjusted[:4], labels, config.corner_weight, config.adjustment_steps, config.adjustment_tolerance
    )
    if config.covariance:
        max_lag = max(1, round(_scaled(_CORRELATION_COLUMNS, cam.width, 1024) / config.adjustment_stride))
        uncertainty = layout_uncertainty(cam, inliers, *adjusted[:4], labels, config.corner_weight, max_lag)
    else:
        uncertainty = not_computed(distances.shape[0], distances.dtype)
    # every usable column counts, on whichever wall this layout gives it, so that the two branches compare
    usable = evidence.usable[:: config.adjustment_stride]
    seen = usable & (observations.column_wall >= 0)
    ceiling_error, floor_error = _row_errors(cam, _using(observations, seen, seen), adjusted[:4])
    explained = jnp.sum(seen & (jnp.abs(ceiling_error) < threshold)) + jnp.sum(seen & (jnp.abs(floor_error) < threshold))
    return adjusted, explained / jnp.maximum(2 * jnp.sum(usable), 1), uncertainty


def _point_on_wall(
    cam: NonCentralPanorama, direction: Float[Array, "K 2"], distance: Float[Array, " K"], column: Float[Array, " K"]
) -> Float[Array, "K 2"]:
    """Where the vertical half-plane of ``column`` meets a wall (plan view)."""
    along = column_directions(cam, column)
    t = range_along(cam, direction, distance, along)
    t = jnp.where(jnp.isfinite(t), t, 0.0)
    return (cam.rc + t)[:, None] * along


def _signed_distance(direction: Float[Array, "K 2"], point: Float[Array, "K 2"]) -> Float[Array, " K"]:
    return cross_2d(direction, point)  # e2 . p with e2 = (-uy, ux)


def _place_manhattan_walls(
    cam: NonCentralPanorama, final: FinalWalls, directions: Float[Array, "K 2"], distances: Float[Array, " K"]
) -> Float[Array, " K"]:
    """Distances of the unobserved Manhattan walls: through the corner they share with their near neighbour.

    For a wall inserted at an occlusion that is the occluding corner (on the
    nearer of the two walls around it); for an unfitted wall, its start corner.
    """
    near = final.near_neighbour
    corner = _point_on_wall(cam, directions[near], distances[near], final.corner_columns)
    return jnp.where(final.observed, distances, _signed_distance(directions, corner))


def _place_atlanta_walls(
    cam: NonCentralPanorama, final: FinalWalls, directions: Float[Array, "K 2"], distances: Float[Array, " K"]
) -> tuple[Float[Array, "K 2"], Float[Array, " K"]]:
    """Unobserved Atlanta walls: occlusion walls in the corner ray's vertical plane (the paper's
    Fig. Atocc), unfitted walls through their two corners on the neighbouring walls."""
    count = jnp.maximum(jnp.sum(final.mask), 1)
    index = jnp.arange(final.mask.shape[0])
    previous, following = (index - 1) % count, (index + 1) % count
    start = _point_on_wall(cam, directions[previous], distances[previous], final.corner_columns)
    end = _point_on_wall(cam, directions[following], distances[following], final.corner_columns[following])
    chord = end - start
    length = jnp.linalg.norm(chord, axis=-1, keepdims=True)
    through_corners = jnp.where(length > 0, chord / jnp.where(length > 0, length, 1.0), directions)
    radial = column_directions(cam, final.corner_columns)
    new_direction = jnp.where(final.inserted[:, None], radial, through_corners)
    new_distance = jnp.where(final.inserted, 0.0, _signed_distance(through_corners, start))
    keep = final.observed[:, None]
    return jnp.where(keep, directions, new_direction), jnp.where(final.observed, distances, new_distance)


def _several_corners(evidence: WallEvidence) -> Bool[Array, ""]:
    return jnp.sum(evidence.corner_mask) > 1


def _manhattan_layout(evidence, ceiling_v, floor_v, cam, config) -> Layout:
    """Manhattan branch (step 4 of the module docstring) and steps 5-6."""
    labels = manhattan_labels(evidence, *_segment_directions(cam, evidence, ceiling_v, floor_v, config), config.turn_weight)
    same_class = labels[_previous(evidence)] == labels
    # Manhattan walls never meet at 0 degrees: consecutive walls of one class are one plane split by a
    # spurious corner if both were fitted and each explains the other's rows; otherwise a wall lies between
    # them, one whose corners the detector merged into one peak, or an occluded one. A wall that RANSAC could
    # not fit is no sign of a spurious corner (narrow walls between close corners are the usual reason)
    one_plane = ~evidence.occluded & evidence.same_plane
    merge = evidence.corner_mask & same_class & one_plane & _several_corners(evidence)
    insert = evidence.corner_mask & same_class & ~one_plane
    final = _final_walls(evidence, merge, insert, True, config.sample_size)
    wall_labels = jnp.where(final.inserted, 1 - labels[final.start_wall], labels[final.start_wall])
    fit_index = _fit_index(evidence, final.column_wall)
    fitted = final.observed & evidence.fitted[final.start_wall]
    yaw = manhattan_yaw(evidence.walls.direction[final.start_wall], wall_labels, fitted)
    heights = solve_atlanta_layout(
        evidence.ceiling_rays, evidence.floor_rays, fit_index, fitted, manhattan_directions(yaw, wall_labels),
        boundary_weights=evidence.row_weights,
    )
    plan = _plan_lines(cam, evidence, final.column_wall, ceiling_v, floor_v, heights.ceiling_height, heights.floor_height)
    yaw = manhattan_yaw(plan, wall_labels, final.observed)
    solved = solve_atlanta_layout(
        evidence.ceiling_rays, evidence.floor_rays, fit_index, final.observed, manhattan_directions(yaw, wall_labels),
        boundary_weights=evidence.row_weights,
    )
    distances = _place_manhattan_walls(cam, final, solved.directions, solved.distances)
    adjusted, explained, uncertainty = _refine(
        cam, evidence, final, ceiling_v, floor_v, solved.directions, distances,
        solved.ceiling_height, solved.floor_height, wall_labels, config,
    )
    return _assemble(cam, evidence, final, *adjusted[:4], explained, uncertainty, heights.ok & solved.ok, True, config)


def _plan_lines(cam, evidence, column_wall, ceiling_v, floor_v, h_c, h_f) -> Float[Array, "K 2"]:
    """Per wall of ``column_wall`` (-1: none), the direction of the plan line through its boundary points at heights ``h_c``, ``h_f``."""
    columns = jnp.arange(cam.width, dtype=ceiling_v.dtype)
    ceiling, ceiling_ok = boundary_points(cam, columns, jnp.where(evidence.finite, ceiling_v, 0.0), h_c)
    floor, floor_ok = boundary_points(cam, columns, jnp.where(evidence.finite, floor_v, 0.0), h_f)
    points = jnp.concatenate([ceiling, floor])
    ok = jnp.concatenate([ceiling_ok, floor_ok]) & jnp.tile(evidence.usable, 2)
    wall = jnp.tile(column_wall, 2)  # -1 (no wall): dropped
    directions, _ = fit_plan_lines(points, ok.astype(points.dtype), wall, evidence.corner_mask.shape[0])
    return directions


def _solve_atlanta_walls(evidence, merge, insert, ceiling_v, floor_v, cam, config):
    """The Atlanta wall loop after merging and insertion, and its walls from the joint solver.

    Returns:
        ``(final, ok, directions, distances, ceiling_height, floor_height)``.
    """
    final = _final_walls(evidence, merge, insert, False, config.sample_size)
    fit_index = _fit_index(evidence, final.column_wall)
    heights = solve_atlanta_layout(
        evidence.ceiling_rays,
        evidence.floor_rays,
        fit_index,
        final.observed & evidence.fitted[final.start_wall],
        _group_directions(evidence, merge, final),
        boundary_weights=evidence.row_weights,
    )
    # every observed wall's direction from its boundary points at those heights
    directions = _plan_lines(cam, evidence, final.column_wall, ceiling_v, floor_v, heights.ceiling_height, heights.floor_height)
    solved = solve_atlanta_layout(
        evidence.ceiling_rays, evidence.floor_rays, fit_index, final.observed, directions,
        boundary_weights=evidence.row_weights,
    )
    directions, distances = _place_atlanta_walls(cam, final, solved.directions, solved.distances)
    return final, heights.ok & solved.ok, directions, distances, solved.ceiling_height, solved.floor_height


def corner_offsets(
    cam: NonCentralPanorama,
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    wall_mask: Bool[Array, " K"],
    corner_columns: Float[Array, " K"],
) -> Float[Array, " K"]:
    """Per corner ``k``, how far (columns) from ``corner_columns[k]`` walls ``k - 1`` and ``k`` meet (inf: they do not)."""
    previous = previous_walls(wall_mask)
    offset, meet = jax.vmap(corner_column_offset, in_axes=(0, 0, None, 0))(
        jnp.stack([directions[previous], directions], 1), jnp.stack([distances[previous], distances], 1), cam, corner_columns
    )
    offset = jnp.abs(offset)
    return jnp.where((meet | ~wall_mask) & jnp.isfinite(offset), offset, jnp.inf)


def _atlanta_layout(evidence, ceiling_v, floor_v, cam, config) -> Layout:
    """Atlanta branch (step 4 of the module docstring) and steps 5-6."""
    ransac_directions = evidence.walls.direction
    turn = cross_2d(ransac_directions[_previous(evidence)], ransac_directions)
    parallel = jnp.abs(turn) < math.sin(math.radians(config.merge_angle))
    merge = evidence.same_plane & parallel & ~evidence.occluded & _several_corners(evidence)
    insert = evidence.occluded
    final, _, directions, distances, _, _ = _solve_atlanta_walls(evidence, merge, insert, ceiling_v, floor_v, cam, config)
    # two observed walls that meet far from their corner's column (or are parallel) hold a wall between them
    # whose two corners gave one peak: it is inserted in the corner ray's plane, as at an occlusion
    both_observed = final.observed & final.observed[previous_walls(final.mask)]
    offsets = corner_offsets(cam, directions, distances, final.mask, final.corner_columns)
    stray = both_observed & (offsets > _scaled(config.max_corner_offset, cam.width, 1024))
    capacity = insert.shape[0]
    insert = insert.at[jnp.where(stray, final.start_wall, capacity)].set(True, mode="drop")
    final, ok, directions, distances, h_c, h_f = _solve_atlanta_walls(evidence, merge, insert, ceiling_v, floor_v, cam, config)
    adjusted, explained, uncertainty = _refine(cam, evidence, final, ceiling_v, floor_v, directions, distances, h_c, h_f, None, config)
    return _assemble(cam, evidence, final, *adjusted[:4], explained, uncertainty, ok, False, config)


def _assemble(
    cam: NonCentralPanorama,
    evidence: WallEvidence,
    final: FinalWalls,
    directions: Float[Array, "K 2"],
    distances: Float[Array, " K"],
    ceiling_height: Float[Array, ""],
    floor_height: Float[Array, ""],
    explained_fraction: Float[Array, ""],
    uncertainty: LayoutUncertainty,
    solver_ok: Bool[Array, ""],
    manhattan: bool,
    config: PipelineConfig,
) -> Layout:
    """Step 6: corners where consecutive walls meet, Plücker lines and the status."""
    mask = final.mask
    points, meet = loop_corners(directions, distances, mask)
    directions, distances = canonical_orientation(directions, distances)
    finite = jnp.all(jnp.isfinite(points)) & jnp.isfinite(ceiling_height) & jnp.isfinite(floor_height)
    farthest = jnp.max(jnp.where(mask, jnp.linalg.norm(jnp.where(mask[:, None], points, 0.0), axis=-1), 0.0))
    plausible = (ceiling_height - floor_height <= config.max_room_height) & (farthest <= config.max_corner_distance)
    height_sigma = room_height_sigma(uncertainty.height_covariance)
    scale_unknown = height_sigma > config.max_height_uncertainty * (ceiling_height - floor_height)
    failed = jnp.stack(
        [
            ~(cam.rc > 1e-6),
            jnp.mean(evidence.finite) < config.min_finite_fraction,
            ~jnp.any(evidence.corner_mask),
            evidence.corner_overflow | final.overflow,
            jnp.sum(mask) < (4 if manhattan else 3),
            jnp.sum(final.observed) < 2,
            ~solver_ok,
            ~(jnp.all(meet) & finite & (ceiling_height > 0) & (floor_height < 0) & plausible),
            scale_unknown,
        ]
    )
    status = jnp.where(jnp.any(failed), jnp.argmax(failed) + 1, LayoutStatus.OK).astype(jnp.int32)
    points = jnp.where(mask[:, None] & jnp.isfinite(points), points, 0.0)
    ceiling_height = jnp.nan_to_num(ceiling_height)
    floor_height = jnp.nan_to_num(floor_height)

    def at(height):
        return jnp.concatenate([points, jnp.broadcast_to(height, points.shape[:1])[:, None]], -1) * mask[:, None]

    return Layout(
        ceiling_corners=at(ceiling_height),
        floor_corners=at(floor_height),
        mask=mask,
        ceiling_height=ceiling_height,
        floor_height=floor_height,
        wall_directions=jnp.where(mask[:, None], directions, 0.0),
        wall_distances=jnp.where(mask, distances, 0.0),
        ceiling_lines=horizontal_wall_line(directions, distances, ceiling_height) * mask[:, None],
        floor_lines=horizontal_wall_line(directions, distances, floor_height) * mask[:, None],
        inserted=final.inserted,
        corner_columns=jnp.where(mask, final.corner_columns, 0.0),
        manhattan=jnp.array(manhattan),
        explained_fraction=explained_fraction,
        corner_covariance=jnp.where(mask[:, None, None], uncertainty.corner_covariance, 0.0),
        height_covariance=uncertainty.height_covariance,
        status=status,
        ok=status == LayoutStatus.OK,
    )


def ceiling_consistent_floor(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"], threshold: float
) -> tuple[Float[Array, " W"], Bool[Array, " W"]]:
    """Floor rows that contradict their column's ceiling row, replaced by the row it implies (step 0).

    A column's rays all leave one centre on the circle, in one vertical plane
    (paper eq. pluckerray), so they meet the wall at one horizontal range
    ``t``: ``tan(phi_c) = h_c / t`` and ``tan(phi_f) = h_f / t``, and
    ``tan(phi_c) / tan(phi_f) = h_c / h_f`` in every column, whatever the
    walls. The panorama's median of that ratio gives each column's floor
    elevation from its ceiling one. The ratio is the image's own, not a
    prior; the metric scale still comes from the rows' non-central parallax.

    Args:
        cam: the camera.
        ceiling_v, floor_v: boundary rows (pixels; NaN = missing).
        threshold: pixels (at 512 rows); inf keeps every row.

    Returns:
        ``(floor_v, replaced)``: the rows, and which were replaced.
    """
    columns = jnp.arange(ceiling_v.shape[0], dtype=ceiling_v.dtype)
    _, ceiling_elevation = pixel_to_angles(cam, columns, ceiling_v)
    azimuth, floor_elevation = pixel_to_angles(cam, columns, floor_v)
    ratio = jnp.nanmedian(jnp.tan(ceiling_elevation) / jnp.tan(floor_elevation))
    _, implied = angles_to_pixel(cam, azimuth, jnp.arctan(jnp.tan(ceiling_elevation) / ratio))
    replaced = jnp.abs(floor_v - implied) > _scaled(threshold, cam.height, 512)
    # a ceiling row below the horizon (an outlier) implies nothing about the floor's
    replaced = replaced & jnp.isfinite(implied) & (ratio < 0) & (ceiling_elevation > 0)
    return jnp.where(replaced, implied, floor_v), replaced


def layout_from_evidence(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    corner_prob: Float[Array, " W"],
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    world: str,
    config: PipelineConfig,
) -> Layout:
    """The traceable pipeline for one panorama (no input checks; see :func:`layout_from_boundaries`)."""
    replaced = jnp.zeros(floor_v.shape, bool)
    if math.isfinite(config.floor_consistency_threshold):
        floor_v, replaced = ceiling_consistent_floor(cam, ceiling_v, floor_v, config.floor_consistency_threshold)
    evidence = _gather_evidence(ceiling_v, floor_v, corner_prob, cam, key, config)
    evidence = eqx.tree_at(lambda e: e.floor_measured, evidence, ~replaced)
    if world == "manhattan":
        return _manhattan_layout(evidence, ceiling_v, floor_v, cam, config)
    if world == "atlanta":
        return _atlanta_layout(evidence, ceiling_v, floor_v, cam, config)
    _, deviation = manhattan_frame(evidence.walls.direction, evidence.weights)
    counted = evidence.corner_mask & evidence.walls.ok
    in_frame = jnp.all(jnp.where(counted, deviation, 0.0) < math.radians(config.manhattan_tolerance))
    manhattan = _manhattan_layout(evidence, ceiling_v, floor_v, cam, config)
    atlanta = _atlanta_layout(evidence, ceiling_v, floor_v, cam, config)
    use_manhattan = choose_manhattan(manhattan.ok, atlanta.ok, manhattan.explained_fraction, atlanta.explained_fraction, in_frame)
    return jax.tree.map(lambda m, a: jnp.where(use_manhattan, m, a), manhattan, atlanta)


def choose_manhattan(
    manhattan_ok: Bool[Array, ""],
    atlanta_ok: Bool[Array, ""],
    manhattan_explained: Float[Array, ""],
    atlanta_explained: Float[Array, ""],
    in_frame: Bool[Array, ""],
) -> Bool[Array, ""]:
    """``world="auto"``: whether to keep the Manhattan branch's layout rather than the Atlanta one.

    A branch that failed loses to one that did not. Otherwise the Manhattan layout is kept when it
    reprojects more of the usable boundary rows within the inlier threshold than the Atlanta one
    (which has a free angle per wall, so it rarely loses unless the room is Manhattan), and on a
    tie (exact rows: both explain everything) when every RANSAC wall lies within
    ``manhattan_tolerance`` of a Manhattan frame.
    """
    better = (manhattan_explained > atlanta_explained) | ((manhattan_explained == atlanta_explained) & in_frame)
    return manhattan_ok & (~atlanta_ok | better)


def _padded_layout(ceiling_v, floor_v, corner_prob, cam, key, world, config, slots):
    return pad_layout(layout_from_evidence(ceiling_v, floor_v, corner_prob, cam, key, world, config), slots)


_layout_jit = jax.jit(_padded_layout, static_argnames=("world", "config", "slots"))


def layout_from_boundaries(
    ceiling_v: Float[ArrayLike, "*batch W"],
    floor_v: Float[ArrayLike, "*batch W"],
    corner_prob: Float[ArrayLike, "*batch W"],
    cam: NonCentralPanorama,
    world: str = "manhattan",
    config: PipelineConfig = PipelineConfig(),
    key: PRNGKeyArray | None = None,
) -> Layout:
    """Metric room layout from the per-column network outputs (paper Section 4.4).

    Jitted; leading batch axes are mapped with ``jax.vmap``. Inside your own
    ``jax.jit``/``jax.vmap`` it traces like any JAX function. Concrete arrays
    run with ``config.compact_capacity`` slots first and only the panoramas
    that need more are rerun with ``config.capacity`` (the same layouts,
    faster); the Layout has ``config.capacity`` slots either way.

    Args:
        ceiling_v: ceiling-wall boundary row per column (pixels, sub-pixel; NaN = missing).
        floor_v: floor-wall boundary row per column.
        corner_prob: wall-wall corner probability per column, in [0, 1].
        cam: the camera; ``cam.width`` must equal the number of columns. Its
            traced fields (``rc``, the fields of view) are scalars, shared by the
            batch, or have the batch's shape (one camera per panorama).
        world: static: "manhattan", "atlanta" or "auto".
        config: static :class:`PipelineConfig`.
        key: PRNG key of the RANSAC sampling (default ``jax.random.key(0)``).

    Returns:
        A :class:`Layout`; check ``ok`` / ``status``.

    Raises:
        ValueError: for an unknown ``world``, arrays whose shapes do not match
            the camera, or camera fields of another shape than the batch's.
    """
    if world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {world!r}")
    arrays = [jnp.asarray(x) for x in (ceiling_v, floor_v, corner_prob)]
    arrays = [x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.float32) for x in arrays]
    shape = arrays[0].shape
    if any(x.shape != shape for x in arrays) or not shape or shape[-1] != cam.width:
        raise ValueError(
            f"ceiling_v, floor_v and corner_prob must share one shape (..., W) with W = cam.width = {cam.width}; "
            f"got {[tuple(x.shape) for x in arrays]}"
        )
    batch = shape[:-1]
    fields = jax.tree.leaves(cam)
    if any(jnp.shape(x) not in ((), batch) for x in fields):
        raise ValueError(
            f"the camera's rc and fields of view must be scalars or of the batch's shape {batch}; "
            f"got {[jnp.shape(x) for x in fields]}"
        )
    key = jax.random.key(0) if key is None else key
    if not batch:
        return _layout_with_fallback(*arrays, cam, key, world, config)
    flat = [x.reshape(-1, cam.width) for x in arrays]
    cams = jax.tree.map(lambda x: jnp.broadcast_to(x, batch).reshape(-1), cam)
    keys = jax.random.split(key, flat[0].shape[0])
    layout = _layout_with_fallback(*flat, cams, keys, world, config)
    return jax.tree.map(lambda x: x.reshape(batch + x.shape[1:]), layout)


def _layout_with_fallback(ceiling_v, floor_v, corner_prob, cam, key, world, config) -> Layout:
    """One panorama (1D rows) or a flat batch: with ``config.compact_capacity`` slots first where that can help.

    A rerun with ``config.capacity`` slots replaces the compact run's
    ``TOO_MANY_WALLS`` layouts; the checks before that status do not depend
    on the slots, so it is raised exactly when the layout needs more of them.
    Traced inputs run with ``config.capacity`` slots directly.
    """
    batched = ceiling_v.ndim == 2
    run = functools.partial(_batched_layout_jit if batched else _layout_jit, world=world, slots=config.capacity)
    full = dataclasses.replace(config, compact_capacity=0)
    compact = config.compact_capacity
    if not 0 < compact < config.capacity or any(isinstance(x, jax.core.Tracer) for x in (ceiling_v, floor_v, corner_prob)):
        return run(ceiling_v, floor_v, corner_prob, cam, key, config=full)
    layout = run(ceiling_v, floor_v, corner_prob, cam, key, config=dataclasses.replace(full, capacity=compact))
    if not batched:
        return run(ceiling_v, floor_v, corner_prob, cam, key, config=full) if layout.status == LayoutStatus.TOO_MANY_WALLS else layout
    rerun = np.flatnonzero(np.asarray(layout.status) == LayoutStatus.TOO_MANY_WALLS)
    if not rerun.size:
        return layout
    # padded to a power of two: few batch sizes, so few compilations
    padding = (1 << (rerun.size - 1).bit_length()) - rerun.size
    picked = jnp.asarray(np.concatenate([rerun, np.full(padding, rerun[0])]))
    destination = jnp.asarray(np.concatenate([rerun, np.full(padding, ceiling_v.shape[0])]))
    return _rerun_jit(ceiling_v, floor_v, corner_prob, cam, key, layout, picked, destination, world=world, config=full)


def _batched_layout(ceiling_v, floor_v, corner_prob, cams, keys, world, config, slots):
    def one(c, f, p, cam, k):
        return _padded_layout(c, f, p, cam, k, world, config, slots)

    if not 0 < config.chunk_size < ceiling_v.shape[0]:
        return jax.vmap(one)(ceiling_v, floor_v, corner_prob, cams, keys)
    # the last, partial chunk (if any) is one more vmap after the loop over the full ones
    return jax.lax.map(lambda args: one(*args), (ceiling_v, floor_v, corner_prob, cams, keys), batch_size=config.chunk_size)


_batched_layout_jit = jax.jit(_batched_layout, static_argnames=("world", "config", "slots"))


def _rerun(ceiling_v, floor_v, corner_prob, cams, keys, layout, picked, destination, world, config):
    """``layout`` with the panoramas ``picked`` solved again with ``config``: gather, solve and scatter in one call.

    Result ``i`` goes to panorama ``destination[i]``; out-of-range
    destinations (the padding of ``picked``) are dropped.
    """
    inputs = jax.tree.map(lambda x: x[picked], (ceiling_v, floor_v, corner_prob, cams, keys))
    redone = _batched_layout(*inputs, world, config, config.capacity)
    return jax.tree.map(lambda old, new: old.at[destination].set(new, mode="drop"), layout, redone)


_rerun_jit = jax.jit(_rerun, static_argnames=("world", "config"))
