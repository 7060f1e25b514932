"""The pipeline's configuration: :class:`PipelineConfig` and its pixel scaling."""

from __future__ import annotations

import copy
import dataclasses
import math

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..geometry.camera import NonCentralPanorama
from ..solvers.ransac import num_hypotheses

WORLDS = ("manhattan", "atlanta", "auto")
# the room model of the API and the CLI when none is given: per panorama, the branch that explains more of its rows
DEFAULT_WORLD = "auto"


@dataclasses.dataclass(frozen=True)
class PipelineConfig:
    """Parameters of the pipeline (frozen, hashable).

    The thresholds and weights in :data:`TRACED_FIELDS` enter the compiled
    pipeline as traced values: changing them reuses the compiled program. The
    other fields set shapes, loop lengths or which code runs, and are static:
    changing one compiles the pipeline anew.

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
            count (:func:`~ncjax.pipeline.corners.find_corners`; 0: off; at most
            ``capacity`` and ``compact_capacity``).
        fallback_corner_threshold: the lowest peak probability ``min_corners``
            accepts (at or above ``corner_threshold``: no fallback).
        nms_radius: non-maximum-suppression half-width, columns.
        exact_target_tolerance: a peak of the exact label target ``0.96**d``
            that holds two corners closer than the suppression window (the
            wall between them seen almost edge-on) gives both, where its columns
            follow the encoding to within this many columns of distance
            (:func:`~ncjax.pipeline.corners.exact_target_corners`; a network's
            lobes never do; 0: off).
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
            boundary noise, estimated from the rows about their RANSAC walls,
            times how much less surely the two sides' rows extrapolate than two
            full windows' (0: the fixed threshold alone).
        merge_fraction: consecutive walls each of which explains at least
            this fraction of the other's inlier pixels may be one wall.
        merge_angle: Atlanta: such walls are merged only if their directions
            differ by less than this (degrees): a shallow corner between two
            walls seen far away passes the pixel test (Manhattan merges
            walls of one class, see :func:`~ncjax.pipeline.manhattan.manhattan_walls`).
        max_corner_offset: Atlanta: where two observed walls meet farther than
            this (columns) from their corner's column, or not at all, the
            corner's peak holds two corners (the network's lobes merge close
            ones) and a wall is inserted between them in the corner ray's
            plane, as at an occlusion, if their rows at that column are also
            more than ``stray_noise_factor`` times the rows' noise apart.
            Chosen on the tuning renders (experiments/RESULTS.md): 24-128 did
            about alike.
        stray_noise_factor: noisy directions of two walls that turn a little
            move their meeting far along them, but not their rows at the corner
            apart: see ``max_corner_offset`` (0: the offset alone). Chosen on
            exact rows plus 0-2 px of noise of other rooms than
            ``experiments/pipeline_table.py``'s and ``central_table.py``'s
            (0, 2, 3, 5 tried: 2 failed fewest).
        manhattan_tolerance: ``world="auto"``: largest deviation (degrees) of a
            RANSAC wall from the Manhattan frame for the Manhattan branch to win
            a tie (:func:`choose_manhattan`).
        manhattan_margin: ``world="auto"``: the Manhattan layout is kept
            unless the Atlanta one explains more than this fraction of the
            usable boundary rows more (:func:`choose_manhattan`). The Atlanta
            branch's free angle per wall lets it follow the rows' noise, which
            a margin of 0 rewards on noisy rows.
        turn_weight: Manhattan labelling: cost of a corner whose walls do not
            turn as its type says, relative to the best-supported wall's
            direction vote (:func:`manhattan_labels`). Small: the walls'
            directions decide and the corner types break ties. Corners
            that the detector merged make the expected turns wrong, and on
            the network's rows a weight of 0.5 mislabelled walls in many
            rooms (experiments/RESULTS.md).
        corner_weight: weight of the corner-plane penalty of the adjustment.
        min_boundary_noise: the joint solvers and both adjustment passes weight
            the ceiling and floor rows by the squared inverse of each boundary's
            noise (about the RANSAC walls, about each pass's starting layout),
            taken as at least this (pixels): exact rows keep equal weights, and
            a value far above the rows' errors turns all the weighting off
            (:func:`ncjax.pipeline.adjust.boundary_weights`).
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
            (experiments/RESULTS.md).
        inlier_pass_stride: the first adjustment pass, whose layout only
            picks the inlier rows of the second (and is its start), fits every
            this-many-th of the second's columns (1: the same columns).
        chunk_size: a batch runs this many panoramas at a time (one ``vmap``),
            chunk after chunk inside the same jitted call: a larger ``vmap``
            leaves the CPU's caches and runs slower per panorama (0: all at once).
        covariance: compute ``Layout.corner_covariance`` and ``height_covariance``
            (a Jacobian of the final adjustment: 10-20% of the batched throughput
            in our benchmark); False leaves them NaN.
        wall_offset_ratio: the covariance's share of an error that the rows of
            one wall share (an offset per wall and boundary, which the fit
            absorbs and its residuals cannot show): its standard deviation as
            a multiple of the boundary's row noise
            (:func:`ncjax.pipeline.uncertainty.layout_uncertainty`). Off (0)
            by default, as for rows with independent errors; the network's
            configuration sets it.
        wall_offset_noise: that offset's standard deviation not tied to the
            rows' noise, pixels of a 512-row panorama. Off (0) by default.
        corner_column_noise: the covariance's share of the detected corner
            columns' error, their standard deviation in columns of a
            1024-column panorama (the corner rows count at the rows' noise
            without it). Off (0) by default.
        min_finite_fraction: fraction of columns with finite rows needed.
        max_height_uncertainty: a layout whose room height ``h_c - h_f`` has a
            standard deviation (:attr:`Layout.height_covariance`) above this
            fraction of the height fails with ``UNCERTAIN_SCALE``: the rows do
            not fix its scale (a baseline ``rc`` small for the room's size, or
            walls whose positions the rows leave free, where the covariance
            is infinite). Off (inf) by default; the network's configuration
            sets it (``ncjax.reconstruction.NETWORK_PIPELINE_CONFIG``). Needs
            ``covariance``.
        max_room_height: a layout whose ceiling is more than this above its
            floor (metres) is implausible (DEGENERATE_LAYOUT), e.g. a wall fit
            whose scale ran away.
        max_corner_distance: a layout with a corner farther than this from
            the camera (metres) is implausible (DEGENERATE_LAYOUT).
        min_height_fraction: a layout whose ceiling or floor is nearer the
            camera than this fraction of the room height is implausible
            (DEGENERATE_LAYOUT): no camera touches its ceiling or floor, but
            an adjustment that ran away can leave one of them there (0: only
            ceiling above and floor below the camera).
        prior_wall_heights: with a height prior (:mod:`ncjax.pipeline.prior`),
            RANSAC fits each wall at the prior's two heights
            (:func:`~ncjax.solvers.wall_at_heights.solve_wall_at_heights`: two unknowns
            instead of four; experiments/RESULTS.md compares them); False:
            the paper's single-wall solver, whose walls carry their own heights.
        prior_room_height: set by the height-prior route
            (:func:`~ncjax.pipeline.run.prior_config`), not by hand: the
            room height (metres) its prior gives. The virtual rig's layout has
            an arbitrary scale, so the two limits above apply to it scaled to
            this height. 0 (the default): the layout's own scale.
        min_explained_fraction: an otherwise ok layout that reprojects fewer
            than this fraction of the usable boundary rows within
            ``inlier_threshold`` (:attr:`Layout.explained_fraction`) is flagged
            ``LOW_CONFIDENCE``: the network's rows do not describe one room
            (a panorama unlike its training images). Off (0) by default; the
            network's configuration sets it.
        floor_consistency_threshold: pixels; a floor row farther than this
            from the one its column's ceiling row implies is replaced by it
            (step 0, :func:`ceiling_consistent_floor`). Off (inf) by default;
            the network's configuration sets it.
        max_scale_conflict: a non-central panorama whose geometry cannot fix
            its scale (``UNCERTAIN_SCALE``) takes it from a height prior when
            one is given (:func:`ncjax.reconstruct_batch`); where the height
            its parallax measured is more than this many standard deviations
            from the prior's (:func:`ncjax.pipeline.prior.scale_conflict`),
            the prior's layout is flagged ``SCALE_CONFLICT``: the rows are
            unlikely to be this rig's view of one room. Off (inf) by default;
            the network's configuration sets it. Without ``covariance`` no
            height has a known spread and nothing is flagged.
    """

    capacity: int = 32
    compact_capacity: int = 16
    corner_threshold: float = 0.3
    min_corners: int = 4
    fallback_corner_threshold: float = 0.1
    nms_radius: float = 2.0
    exact_target_tolerance: float = 0.01
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
    stray_noise_factor: float = 2.0
    manhattan_tolerance: float = 5.0
    manhattan_margin: float = 0.0
    turn_weight: float = 0.02
    corner_weight: float = 1.0
    min_boundary_noise: float = 0.5
    adjustment_steps: int = 8
    adjustment_tolerance: float = 1e-4
    adjustment_stride: int = 2
    inlier_pass_stride: int = 4
    chunk_size: int = 32
    covariance: bool = True
    wall_offset_ratio: float = 0.0
    wall_offset_noise: float = 0.0
    corner_column_noise: float = 0.0
    min_finite_fraction: float = 0.5
    max_height_uncertainty: float = math.inf
    max_room_height: float = 10.0
    max_corner_distance: float = 50.0
    min_height_fraction: float = 0.05
    prior_wall_heights: bool = True
    prior_room_height: float = 0.0
    floor_consistency_threshold: float = math.inf
    min_explained_fraction: float = 0.0
    max_scale_conflict: float = math.inf

    def __post_init__(self):
        if self.capacity < 4:
            raise ValueError(f"capacity must be >= 4 walls, got {self.capacity}")
        if self.compact_capacity != 0 and self.compact_capacity < 4:
            raise ValueError(f"compact_capacity must be 0 (off) or >= 4 walls, got {self.compact_capacity}")
        if self.sample_size < 3:
            raise ValueError(
                f"sample_size must be >= 3 columns (the wall solver needs 3 rays per line), got {self.sample_size}"
            )
        num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)  # validates
        if self.ransac_columns < 2 * self.sample_size:
            raise ValueError(f"ransac_columns must be >= 2 * sample_size, got {self.ransac_columns}")
        positive = (
            "nms_radius",
            "inlier_threshold",
            "occlusion_threshold",
            "merge_fraction",
            "merge_angle",
            "max_corner_offset",
            "manhattan_tolerance",
            "turn_weight",
            "adjustment_tolerance",
            "min_boundary_noise",
            "max_height_uncertainty",
            "floor_consistency_threshold",
            "max_scale_conflict",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if math.isfinite(self.max_height_uncertainty) and not self.covariance:
            raise ValueError("max_height_uncertainty needs covariance=True (it tests the height's covariance)")
        for name in (
            "exact_target_tolerance",
            "occlusion_noise_factor",
            "stray_noise_factor",
            "wall_offset_ratio",
            "wall_offset_noise",
            "corner_column_noise",
            "prior_room_height",
        ):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("adjustment_stride", "inlier_pass_stride"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1 column, got {getattr(self, name)}")
        slots = min(self.capacity, self.compact_capacity or self.capacity)
        if not 0 <= self.min_corners <= slots:
            raise ValueError(
                f"min_corners must be in [0, {slots}] (capacity and compact_capacity), got {self.min_corners}"
            )
        if not 0 <= self.manhattan_margin <= 1:
            raise ValueError(f"manhattan_margin must be in [0, 1], got {self.manhattan_margin}")
        if not 0 <= self.min_height_fraction < 0.5:
            raise ValueError(f"min_height_fraction must be in [0, 0.5), got {self.min_height_fraction}")
        if not 0 <= self.min_explained_fraction <= 1:
            raise ValueError(f"min_explained_fraction must be in [0, 1], got {self.min_explained_fraction}")
        if not self.fallback_corner_threshold >= 0:
            raise ValueError(f"fallback_corner_threshold must be >= 0, got {self.fallback_corner_threshold}")
        if self.corner_margin < 0 or self.corner_weight < 0 or self.adjustment_steps < 0 or self.chunk_size < 0:
            raise ValueError("corner_margin, corner_weight, adjustment_steps and chunk_size must be >= 0")

    @property
    def hypotheses(self) -> int:
        """RANSAC hypotheses per wall (paper's n_hyp)."""
        return num_hypotheses(self.success_probability, self.outlier_rate, self.sample_size)


def scaled(value: Float[ArrayLike, ""], size: int, reference: int) -> Float[ArrayLike, ""]:
    """``value``, given for a ``reference``-pixel side, for a side of ``size`` pixels."""
    return value * size / reference


def min_noise(config: PipelineConfig, cam: NonCentralPanorama) -> Float[ArrayLike, ""]:
    """``min_boundary_noise`` in this panorama's pixels."""
    return config.min_boundary_noise * scaled(1.0, cam.height, 512)


def nms_radius(config: PipelineConfig, width: int) -> int:
    return max(1, round(scaled(config.nms_radius, width, 1024)))


# The fields the pipeline only compares with or multiplies by: jitted as traced scalars (see PipelineConfig), so that
# configurations differing in them share the compiled programs (max_scale_conflict is only read after them).
TRACED_FIELDS = (
    "corner_threshold",
    "fallback_corner_threshold",
    "exact_target_tolerance",
    "corner_margin",
    "inlier_threshold",
    "occlusion_threshold",
    "occlusion_noise_factor",
    "merge_fraction",
    "merge_angle",
    "max_corner_offset",
    "stray_noise_factor",
    "manhattan_tolerance",
    "manhattan_margin",
    "turn_weight",
    "corner_weight",
    "min_boundary_noise",
    "wall_offset_ratio",
    "wall_offset_noise",
    "corner_column_noise",
    "min_finite_fraction",
    "max_height_uncertainty",
    "max_room_height",
    "max_corner_distance",
    "min_height_fraction",
    "prior_room_height",
    "floor_consistency_threshold",
    "min_explained_fraction",
    "max_scale_conflict",
)


def static_part(config: PipelineConfig) -> PipelineConfig:
    """``config`` with its :data:`TRACED_FIELDS` at the class defaults: the jit's static key, equal for
    configurations that differ in those fields only."""
    return dataclasses.replace(config, **{name: _DEFAULTS[name] for name in TRACED_FIELDS})


def traced_part(config: PipelineConfig) -> dict[str, Float[Array, ""]]:
    """The values of ``config``'s :data:`TRACED_FIELDS`, as (weakly typed) JAX scalars to pass to a jitted call."""
    return {name: jnp.asarray(getattr(config, name)) for name in TRACED_FIELDS}


def with_traced(static: PipelineConfig, values: dict[str, Float[Array, ""]]) -> PipelineConfig:
    """Inside a jitted call: ``static`` with the traced ``values`` of :func:`traced_part` in place.

    Not validated again (they were when the configuration was made, and tracers have no truth value).
    """
    config = copy.copy(static)
    for name, value in values.items():
        object.__setattr__(config, name, value)
    return config


_DEFAULTS = {field.name: field.default for field in dataclasses.fields(PipelineConfig)}
