"""Steps 5-6: the final adjustment (:mod:`ncjax.pipeline.refine`), then corners where consecutive walls meet,
Plücker lines and the status."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..geometry.plucker import horizontal_wall_line
from ..geometry.reprojection import boundary_ranges
from ..solvers.wall import canonical_orientation
from .adjust import is_manhattan, loop_corners
from .config import PipelineConfig
from .refine import refine
from .types import BranchWalls, Layout, LayoutStatus, WallEvidence
from .uncertainty import LayoutUncertainty, room_height_sigma

# how far the rows see (:func:`seen_range`): a high quantile, not the farthest row, which one row run through a
# doorway into the next room sets
SEEN_RANGE_QUANTILE = 0.95


def assemble_layout(
    evidence: WallEvidence,
    branch: BranchWalls,
    explained_fraction: Float[Array, ""],
    uncertainty: LayoutUncertainty,
    config: PipelineConfig,
    plan: bool = False,
) -> Layout:
    """Step 6: corners where consecutive walls meet, Plücker lines and the status (``plan``: the walls are the
    plan layout's, :mod:`ncjax.pipeline.plan`).

    Reads ``config.checks``, the prior's room height ``config.prior.room_height`` (a prior's virtual rig is
    judged at the prior's scale) and ``config.uncertainty.covariance``.
    """
    cam, final, checks = evidence.cam, branch.final, config.checks
    directions, distances = branch.directions, branch.distances
    ceiling_height, floor_height = branch.ceiling_height, branch.floor_height
    manhattan = is_manhattan(branch.labels)
    covariance_computed = config.uncertainty.covariance
    mask = final.mask
    points, meet = loop_corners(directions, distances, mask)
    directions, distances = canonical_orientation(directions, distances)
    finite = jnp.all(jnp.isfinite(points)) & jnp.isfinite(ceiling_height) & jnp.isfinite(floor_height)
    farthest = jnp.max(jnp.where(mask, jnp.linalg.norm(jnp.where(mask[:, None], points, 0.0), axis=-1), 0.0))
    room_height = ceiling_height - floor_height
    # a prior's virtual rig solves the room at an arbitrary scale: judge its size at the prior's
    prior_room_height = config.prior.room_height
    to_metric = jnp.where(prior_room_height > 0, prior_room_height / room_height, 1.0)
    plausible = to_metric * room_height <= checks.max_room_height
    plausible &= to_metric * farthest <= checks.max_corner_distance
    # (no usable row to judge by: NaN, which the comparison passes)
    plausible &= ~(farthest > checks.max_corner_range_ratio * seen_range(evidence, ceiling_height, floor_height))
    # the ceiling above and the floor below the camera, neither of them at it (with a fraction below 0.5 the two
    # clearances also make the room height positive)
    clearance = checks.min_height_fraction * room_height
    plausible &= (ceiling_height > clearance) & (-floor_height > clearance)
    height_sigma = room_height_sigma(uncertainty.height_covariance)
    scale_unknown = height_sigma > checks.max_height_uncertainty * room_height
    failed = jnp.stack(
        [
            ~(cam.rc > 1e-6),
            jnp.mean(evidence.finite) < checks.min_finite_fraction,
            ~jnp.any(evidence.corner_mask),
            evidence.corner_overflow | final.overflow,
            jnp.sum(mask) < jnp.where(manhattan, 4, 3),
            jnp.sum(final.observed) < 2,
            ~branch.solver_ok,
            ~(jnp.all(meet) & finite & plausible),
            scale_unknown,
            explained_fraction < checks.min_explained_fraction,
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
        manhattan=jnp.asarray(manhattan),
        plan=jnp.asarray(plan),
        explained_fraction=explained_fraction,
        corner_covariance=jnp.where(
            mask[:, None, None], _undetermined_as_infinite(uncertainty.corner_covariance, covariance_computed), 0.0
        ),
        height_covariance=_undetermined_as_infinite(uncertainty.height_covariance, covariance_computed),
        status=status,
        ok=status == LayoutStatus.OK,
    )


def seen_range(
    evidence: WallEvidence, ceiling_height: Float[ArrayLike, ""], floor_height: Float[ArrayLike, ""]
) -> Float[Array, ""]:
    """The 95th percentile of the usable boundary rows' ranges from the camera's axis, their points at these
    heights (:func:`~ncjax.geometry.reprojection.boundary_ranges`): how far the rows see."""
    cam, rows = evidence.cam, evidence.rows

    def ranges(row, height):
        _, distance = boundary_ranges(cam, jnp.where(evidence.finite, row, 0.0), height)
        return jnp.where(evidence.usable, distance, jnp.nan)

    both = jnp.concatenate([ranges(rows.ceiling, ceiling_height), ranges(rows.floor, floor_height)])
    return jnp.nanquantile(both, SEEN_RANGE_QUANTILE)


def finish_layout(evidence: WallEvidence, branch: BranchWalls, config: PipelineConfig) -> Layout:
    """Steps 5-6 of a branch's walls: the final adjustment and its uncertainty (:func:`refine`), then
    :func:`assemble_layout`."""
    walls, explained, uncertainty = refine(evidence, branch, config)
    adjusted = eqx.tree_at(
        lambda b: (b.directions, b.distances, b.ceiling_height, b.floor_height),
        branch,
        (walls.directions, walls.distances, walls.ceiling_height, walls.floor_height),
    )
    return assemble_layout(evidence, adjusted, explained, uncertainty, config)


def _undetermined_as_infinite(covariance: Float[Array, "*n 2 2"], computed: bool) -> Float[Array, "*n 2 2"]:
    """A covariance with a NaN (a degenerate fit, e.g. on a failed layout) as all-infinite: not determined.

    When it was not ``computed`` (``UncertaintyConfig.covariance`` off) the NaN stays, the documented
    "not computed".
    """
    if not computed:
        return covariance
    undetermined = jnp.any(jnp.isnan(covariance), axis=(-2, -1), keepdims=True)
    return jnp.where(undetermined, jnp.inf, covariance)
