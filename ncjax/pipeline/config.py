"""The pipeline's configuration: :class:`PipelineConfig`, one part per stage.

Every part is a frozen dataclass and a pytree (:func:`~ncjax.solvers.settings.settings`): its thresholds and
weights are traced, so that another value reuses the compiled pipeline, and its ``static_fields`` (shapes, loop
lengths, which code runs) compile anew. Column and pixel quantities are given for the 1024 x 512 reference
panorama and scaled with the camera's width and height. A stage reads its own part; the orchestration
(:mod:`ncjax.pipeline.run`) hands each stage its part and the few values it shares with another.
"""

from __future__ import annotations

import math
from typing import Any

import jax
from jaxtyping import ArrayLike, Float

from ..geometry.camera import NonCentralPanorama
from ..solvers.ransac import RansacConfig
from ..solvers.settings import check_fraction, check_non_negative, check_positive, replaced, scaled, settings

WORLDS = ("manhattan", "atlanta", "auto")
# the room model of the API and the CLI when none is given: per panorama, the branch that explains more of its rows
DEFAULT_WORLD = "auto"


@settings(static=())
class FloorCheckConfig:
    """Step 0 (:func:`~ncjax.pipeline.floor_check.ceiling_consistent_floor`, not in the paper).

    Attributes:
        threshold: pixels; a floor row farther than this from the one its column's ceiling row implies is
            replaced by it for the walls' fits. Off (inf) by default; the network's configuration sets it.
    """

    threshold: float = math.inf

    def __post_init__(self):
        check_positive(self, "threshold")


@settings(static=("min_corners", "nms_radius"))
class CornerConfig:
    """Step 1: corners from the corner probability (:func:`~ncjax.pipeline.corners.configured_corners`).

    Attributes:
        threshold: minimum corner probability of a peak.
        min_corners: where fewer peaks than this reach ``threshold`` (a network unsure of an image unlike its
            training data), the strongest peaks down to ``fallback_threshold`` make up the count (0: off; at
            most ``capacity`` and ``compact_capacity``).
        fallback_threshold: the lowest peak probability ``min_corners`` accepts (at or above ``threshold``: no
            fallback).
        nms_radius: non-maximum-suppression half-width, columns.
        exact_target_tolerance: a peak of the exact label target ``0.96**d`` that holds two corners closer than
            the suppression window (the wall between them seen almost edge-on) gives both, where its columns
            follow the encoding to within this many columns of distance
            (:func:`~ncjax.pipeline.corners.exact_target_corners`; a network's lobes never do; 0: off).
    """

    threshold: float = 0.3
    min_corners: int = 4
    fallback_threshold: float = 0.1
    nms_radius: float = 2.0
    exact_target_tolerance: float = 0.01

    def __post_init__(self):
        check_fraction(self, "threshold")  # probabilities
        check_fraction(self, "fallback_threshold")
        check_positive(self, "nms_radius")
        check_non_negative(self, "exact_target_tolerance")

    def radius(self, width: int) -> int:
        """``nms_radius`` in whole columns of a ``width``-column panorama."""
        return max(1, round(scaled(self.nms_radius, width, 1024)))


@settings(static=())
class OcclusionConfig:
    """Step 3: occlusions and spurious corners (:func:`~ncjax.pipeline.evidence.gather_evidence`).

    Attributes:
        threshold: boundary jump at a corner that means an occlusion, pixels.
        noise_factor: the jump must also exceed this many times the boundary noise, estimated from the rows
            about their RANSAC walls, times how much less surely the two sides' rows extrapolate than two full
            windows' (0: the fixed threshold alone).
        merge_fraction: consecutive walls each of which explains at least this fraction of the other's inlier
            pixels may be one wall.
    """

    threshold: float = 4.0
    noise_factor: float = 5.0
    merge_fraction: float = 0.8

    def __post_init__(self):
        check_positive(self, "threshold", "merge_fraction")
        check_fraction(self, "merge_fraction")
        check_non_negative(self, "noise_factor")


@settings(static=())
class BranchConfig:
    """Step 4: the Manhattan and Atlanta branches (:mod:`~ncjax.pipeline.manhattan`,
    :mod:`~ncjax.pipeline.atlanta`) and ``world="auto"``'s choice between them.

    Attributes:
        merge_angle: Atlanta: walls that pass the merge test are merged only if their directions differ by
            less than this (degrees): a shallow corner between two walls seen far away passes the pixel test
            (Manhattan merges walls of one class, see :func:`~ncjax.pipeline.manhattan.manhattan_walls`).
        max_corner_offset: Atlanta: where two observed walls meet farther than this (columns) from their
            corner's column, or not at all, the corner's peak holds two corners (the network's lobes merge
            close ones) and a wall is inserted between them in the corner ray's plane, as at an occlusion, if
            their rows at that column are also more than ``stray_noise_factor`` times the rows' noise apart.
        stray_noise_factor: noisy directions of two walls that turn a little move their meeting far along
            them, but not their rows at the corner apart: see ``max_corner_offset`` (0: the offset alone).
        manhattan_tolerance: ``world="auto"``: largest deviation (degrees) of a RANSAC wall from the
            Manhattan frame for the Manhattan branch to win a tie (:func:`~ncjax.pipeline.run.choose_manhattan`).
        manhattan_margin: ``world="auto"``: the Manhattan layout is kept unless the Atlanta one explains more
            than this fraction of the usable boundary rows more. The Atlanta branch's free angle per wall lets
            it follow the rows' noise, which a margin of 0 rewards on noisy rows.
        turn_weight: Manhattan labelling: cost of a corner whose walls do not turn as its type says, relative
            to the best-supported wall's direction vote (:func:`~ncjax.pipeline.manhattan.manhattan_labels`).
            Small: the walls' directions decide and the corner types break ties.
    """

    merge_angle: float = 5.0
    max_corner_offset: float = 32.0
    stray_noise_factor: float = 2.0
    manhattan_tolerance: float = 5.0
    manhattan_margin: float = 0.0
    turn_weight: float = 0.02

    def __post_init__(self):
        check_positive(self, "merge_angle", "max_corner_offset", "manhattan_tolerance", "turn_weight")
        check_non_negative(self, "stray_noise_factor")
        check_fraction(self, "manhattan_margin")


@settings(static=("steps", "tolerance", "stride", "inlier_pass_stride"))
class AdjustmentConfig:
    """Step 5: the final least-squares adjustment (:func:`~ncjax.pipeline.refine.refine`).

    Attributes:
        corner_weight: weight of the corner-plane penalty of the adjustment.
        min_boundary_noise: the joint solvers and both adjustment passes weight the ceiling and floor rows by
            the squared inverse of each boundary's noise (about the RANSAC walls, about each pass's starting
            layout), taken as at least this (pixels): exact rows keep equal weights, and a value far above the
            rows' errors turns all the weighting off (:func:`ncjax.pipeline.adjust.boundary_weights`).
        steps: most least-squares (dogleg) steps of each of the two adjustment passes.
        tolerance: the dogleg stops when a step changes every parameter (radians, metres) and every residual
            (pixels) by less than this plus this times its size (optimistix's Cauchy test). Float32 rounds the
            rows' residuals at about 1e-5 px, so a tighter test is never met and every panorama runs ``steps``.
        stride: the adjustment fits every this-many-th column (1: all); its cost is proportional to the number
            of columns it fits.
        inlier_pass_stride: the first adjustment pass, whose layout only picks the inlier rows of the second
            (and is its start), fits every this-many-th of the second's columns (1: the same columns).
    """

    corner_weight: float = 1.0
    min_boundary_noise: float = 0.5
    steps: int = 8
    tolerance: float = 1e-4
    stride: int = 2
    inlier_pass_stride: int = 4

    def __post_init__(self):
        check_positive(self, "tolerance", "min_boundary_noise")
        check_non_negative(self, "corner_weight", "steps")
        for name in ("stride", "inlier_pass_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"AdjustmentConfig.{name} must be >= 1 column, got {getattr(self, name)}")

    def min_noise(self, cam: NonCentralPanorama) -> Float[ArrayLike, ""]:
        """``min_boundary_noise`` in this panorama's pixels."""
        return self.min_boundary_noise * scaled(1.0, cam.height, 512)


@settings(static=("covariance",))
class UncertaintyConfig:
    """Step 5: the layout's covariance (:func:`~ncjax.pipeline.uncertainty.layout_uncertainty`).

    Attributes:
        covariance: compute ``Layout.corner_covariance`` and ``height_covariance`` (a Jacobian of the final
            adjustment: 10-20% of the batched throughput); False leaves them NaN.
        wall_offset_ratio: the covariance's share of an error that the rows of one wall share (an offset per
            wall and boundary, which the fit absorbs and its residuals cannot show): its standard deviation as
            a multiple of the boundary's row noise. Off (0) by default, as for rows with independent errors;
            the network's configuration sets it.
        wall_offset_noise: that offset's standard deviation not tied to the rows' noise, pixels of a 512-row
            panorama. Off (0) by default.
        corner_column_noise: the covariance's share of the detected corner columns' error, their standard
            deviation in columns of a 1024-column panorama (the corner rows count at the rows' noise without
            it). Off (0) by default.
    """

    covariance: bool = True
    wall_offset_ratio: float = 0.0
    wall_offset_noise: float = 0.0
    corner_column_noise: float = 0.0

    def __post_init__(self):
        check_non_negative(self, "wall_offset_ratio", "wall_offset_noise", "corner_column_noise")


@settings(static=())
class ChecksConfig:
    """Step 6: when a layout fails or is flagged (:func:`~ncjax.pipeline.assemble.assemble_layout`).

    Attributes:
        min_finite_fraction: fraction of columns with finite rows needed (else ``INVALID_INPUT``).
        max_room_height: a layout whose ceiling is more than this above its floor (metres) is implausible
            (``DEGENERATE_LAYOUT``), e.g. a wall fit whose scale ran away.
        max_corner_distance: a layout with a corner farther than this from the camera (metres) is implausible.
        min_height_fraction: a layout whose ceiling or floor is nearer the camera than this fraction of the
            room height is implausible: no camera touches its ceiling or floor, but an adjustment that ran away
            can leave one of them there (0: only ceiling above and floor below the camera).
        max_height_uncertainty: a layout whose room height has a standard deviation above this fraction of the
            height fails with ``UNCERTAIN_SCALE``: the rows do not fix its scale (a baseline ``rc`` small for
            the room's size, or walls whose positions the rows leave free). Off (inf) by default; the network's
            configuration sets it. Needs ``uncertainty.covariance``.
        min_explained_fraction: an otherwise ok layout that reprojects fewer than this fraction of the usable
            boundary rows within the inlier threshold is flagged ``LOW_CONFIDENCE``: the network's rows do not
            describe one room. Off (0) by default; the network's configuration sets it.
        max_corner_range_ratio: a layout with a corner farther from the camera's axis than this many times the
            95th percentile of its boundary rows' ranges (their points at the layout's heights) is implausible
            (``DEGENERATE_LAYOUT``): a wall the rows see edge-on, met by its neighbour far beyond anything the
            rows see. Off (inf) by default; the network's configuration sets it.
    """

    min_finite_fraction: float = 0.5
    max_room_height: float = 10.0
    max_corner_distance: float = 50.0
    min_height_fraction: float = 0.05
    max_height_uncertainty: float = math.inf
    min_explained_fraction: float = 0.0
    max_corner_range_ratio: float = math.inf

    def __post_init__(self):
        check_fraction(self, "min_finite_fraction")
        check_positive(
            self, "max_room_height", "max_corner_distance", "max_height_uncertainty", "max_corner_range_ratio"
        )
        check_fraction(self, "min_height_fraction", 0.5, closed=False)
        check_fraction(self, "min_explained_fraction")


@settings(static=("wall_heights",))
class PriorConfig:
    """The scale from a height prior (:mod:`ncjax.pipeline.prior`).

    Attributes:
        wall_heights: RANSAC fits each wall at the prior's two heights
            (:func:`~ncjax.solvers.wall_at_heights.solve_wall_at_heights`: two unknowns instead of four); False: the
            paper's single-wall solver, whose walls carry their own heights.
        room_height: set by the height-prior route (:func:`~ncjax.pipeline.run.fit_walls`), not by hand: the
            room height (metres) its prior gives. The virtual rig's layout has an arbitrary scale, so the size
            checks apply to it scaled to this height. 0 (the default): the layout's own scale.
        max_scale_conflict: a non-central panorama whose geometry cannot fix its scale (``UNCERTAIN_SCALE``)
            takes it from a height prior when one is given (:func:`ncjax.reconstruct_batch`); where the height
            its parallax measured is more than this many standard deviations from the prior's
            (:func:`ncjax.pipeline.prior.scale_conflict`), the prior's layout is flagged ``SCALE_CONFLICT``. Off
            (inf) by default; the network's configuration sets it.
    """

    wall_heights: bool = True
    room_height: float = 0.0
    max_scale_conflict: float = math.inf

    def __post_init__(self):
        check_positive(self, "max_scale_conflict")
        check_non_negative(self, "room_height")


@settings(static=("fallback", "samples", "iterations"))
class PlanConfig:
    """The plan layout (:mod:`~ncjax.pipeline.plan`, not in the paper): where the chosen branch's layout is flagged
    ``LOW_CONFIDENCE``, walls read robustly off the floor rows' plan replace it if that layout has geometry.

    Attributes:
        fallback: compute the plan layout and use it so. Off by default; the network's configuration sets it.
        samples: each wall's robust line starts from the least-median line through two of this many of its points
            at evenly spaced ranks (:func:`~ncjax.pipeline.plan.least_median_lines`).
        iterations: reweightings of each wall's robust line (:func:`~ncjax.pipeline.plan.robust_plan_lines`).
        tukey: a point farther from its wall's line than this many times the wall's robust spread counts for
            nothing (Tukey's biweight constant: 95% efficiency for Gaussian errors).
        min_spread: the robust spread is at least this fraction of the wall's points' median range.
        min_turn: walls whose lines turn by less than this (degrees) do not meet at their corner: a wall is
            inserted there in the corner ray's plane, as at an occlusion.
        min_wall_columns: a wall with fewer plan points (columns of a 1024-column panorama) has no line of its
            own: it runs between its neighbours' ends.
        horizon_margin: floor rows whose elevation lies within this many radians of the horizon make no plan point.
    """

    fallback: bool = False
    samples: int = 7
    iterations: int = 10
    tukey: float = 4.685
    min_spread: float = 0.01
    min_turn: float = 30.0
    min_wall_columns: float = 16.0
    horizon_margin: float = 0.03

    def __post_init__(self):
        check_positive(self, "tukey", "min_spread", "min_turn", "min_wall_columns", "horizon_margin")
        if self.samples < 2 or self.iterations < 1:
            raise ValueError(f"samples must be >= 2 and iterations >= 1, got {self.samples} and {self.iterations}")


@settings(static=("capacity", "compact_capacity", "chunk_size"))
class PipelineConfig:
    """Parameters of the pipeline (frozen, hashable structure; a pytree whose leaves are the traced thresholds).

    Attributes:
        capacity: K, wall and corner slots of the layout.
        compact_capacity: :func:`~ncjax.layout_from_boundaries` first runs concrete panoramas with this many
            slots, pads their Layouts to ``capacity`` and reruns with ``capacity`` slots only the panoramas
            that did not fit (``TOO_MANY_WALLS``): the same layouts, and the cost of most stages is
            proportional to the slots (0: always ``capacity``).
        chunk_size: a batch runs this many panoramas at a time (one ``vmap``), chunk after chunk inside the
            same jitted call: a larger ``vmap`` leaves the CPU's caches and runs slower per panorama (0: all).
        floor_check: step 0.
        corners: step 1.
        ransac: step 2.
        occlusion: step 3.
        branches: step 4.
        adjustment: step 5.
        uncertainty: step 5's covariance.
        checks: step 6.
        plan: the plan layout that replaces a ``LOW_CONFIDENCE`` one.
        prior: the height prior's route.
    """

    capacity: int = 32
    compact_capacity: int = 16
    chunk_size: int = 32
    floor_check: FloorCheckConfig = FloorCheckConfig()
    corners: CornerConfig = CornerConfig()
    ransac: RansacConfig = RansacConfig()
    occlusion: OcclusionConfig = OcclusionConfig()
    branches: BranchConfig = BranchConfig()
    adjustment: AdjustmentConfig = AdjustmentConfig()
    uncertainty: UncertaintyConfig = UncertaintyConfig()
    checks: ChecksConfig = ChecksConfig()
    plan: PlanConfig = PlanConfig()
    prior: PriorConfig = PriorConfig()

    def __new__(cls, *args, **kwargs):
        moved = sorted(set(kwargs) & set(RENAMED))
        if moved:
            raise TypeError(
                "PipelineConfig's settings are grouped by stage: "
                + ", ".join(f"{name} is now {RENAMED[name]}" for name in moved)
                + ' (e.g. PipelineConfig().replace(corners={"threshold": 0.4}))'
            )
        return super().__new__(cls)

    def replace(self, **changes: Any) -> PipelineConfig:
        """This configuration with fields replaced; a stage's part takes a dict of its own changes:
        ``config.replace(capacity=16, corners={"threshold": 0.4})``."""
        return replaced(self, **changes)

    def __post_init__(self):
        if self.capacity < 4:
            raise ValueError(f"capacity must be >= 4 walls, got {self.capacity}")
        if self.compact_capacity != 0 and self.compact_capacity < 4:
            raise ValueError(f"compact_capacity must be 0 (off) or >= 4 walls, got {self.compact_capacity}")
        check_non_negative(self, "chunk_size")
        slots = min(self.capacity, self.compact_capacity or self.capacity)
        if not 0 <= self.corners.min_corners <= slots:
            raise ValueError(
                f"corners.min_corners must be in [0, {slots}] (capacity and compact_capacity), "
                f"got {self.corners.min_corners}"
            )
        if math.isfinite(self.checks.max_height_uncertainty) and not self.uncertainty.covariance:
            raise ValueError(
                "checks.max_height_uncertainty needs uncertainty.covariance=True (it tests the height's covariance)"
            )


# The flat names of the settings before they were grouped by stage, and where each one is now.
RENAMED = {
    "corner_threshold": "corners.threshold",
    "min_corners": "corners.min_corners",
    "fallback_corner_threshold": "corners.fallback_threshold",
    "nms_radius": "corners.nms_radius",
    "exact_target_tolerance": "corners.exact_target_tolerance",
    "corner_margin": "ransac.corner_margin",
    "success_probability": "ransac.success_probability",
    "outlier_rate": "ransac.outlier_rate",
    "sample_size": "ransac.sample_size",
    "ransac_columns": "ransac.columns",
    "inlier_threshold": "ransac.inlier_threshold",
    "occlusion_threshold": "occlusion.threshold",
    "occlusion_noise_factor": "occlusion.noise_factor",
    "merge_fraction": "occlusion.merge_fraction",
    "merge_angle": "branches.merge_angle",
    "max_corner_offset": "branches.max_corner_offset",
    "stray_noise_factor": "branches.stray_noise_factor",
    "manhattan_tolerance": "branches.manhattan_tolerance",
    "manhattan_margin": "branches.manhattan_margin",
    "turn_weight": "branches.turn_weight",
    "corner_weight": "adjustment.corner_weight",
    "min_boundary_noise": "adjustment.min_boundary_noise",
    "adjustment_steps": "adjustment.steps",
    "adjustment_tolerance": "adjustment.tolerance",
    "adjustment_stride": "adjustment.stride",
    "inlier_pass_stride": "adjustment.inlier_pass_stride",
    "covariance": "uncertainty.covariance",
    "wall_offset_ratio": "uncertainty.wall_offset_ratio",
    "wall_offset_noise": "uncertainty.wall_offset_noise",
    "corner_column_noise": "uncertainty.corner_column_noise",
    "min_finite_fraction": "checks.min_finite_fraction",
    "max_height_uncertainty": "checks.max_height_uncertainty",
    "max_room_height": "checks.max_room_height",
    "max_corner_distance": "checks.max_corner_distance",
    "min_height_fraction": "checks.min_height_fraction",
    "min_explained_fraction": "checks.min_explained_fraction",
    "prior_wall_heights": "prior.wall_heights",
    "prior_room_height": "prior.room_height",
    "max_scale_conflict": "prior.max_scale_conflict",
    "floor_consistency_threshold": "floor_check.threshold",
}


def static_structure(config: PipelineConfig) -> str:
    """What of ``config`` a compiled program depends on (its static fields), as text: a key for saved programs."""
    return str(jax.tree.structure(config))
