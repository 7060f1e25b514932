"""Steps 5-6: the final adjustment (:mod:`ncjax.pipeline.refine`), then corners where consecutive walls meet,
Plücker lines and the status."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry.camera import NonCentralPanorama
from ..geometry.plucker import horizontal_wall_line
from ..solvers.wall import canonical_orientation
from .adjust import is_manhattan, loop_corners
from .config import PipelineConfig
from .refine import refine
from .types import BranchWalls, FinalWalls, Layout, LayoutStatus, WallEvidence
from .uncertainty import LayoutUncertainty, room_height_sigma


def assemble_layout(
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
    manhattan: Bool[Array, ""],
    config: PipelineConfig,
) -> Layout:
    """Step 6: corners where consecutive walls meet, Plücker lines and the status."""
    mask = final.mask
    points, meet = loop_corners(directions, distances, mask)
    directions, distances = canonical_orientation(directions, distances)
    finite = jnp.all(jnp.isfinite(points)) & jnp.isfinite(ceiling_height) & jnp.isfinite(floor_height)
    farthest = jnp.max(jnp.where(mask, jnp.linalg.norm(jnp.where(mask[:, None], points, 0.0), axis=-1), 0.0))
    room_height = ceiling_height - floor_height
    # a prior's virtual rig solves the room at an arbitrary scale: judge its size at the prior's
    to_metric = jnp.where(config.prior_room_height > 0, config.prior_room_height / room_height, 1.0)
    plausible = to_metric * room_height <= config.max_room_height
    plausible &= to_metric * farthest <= config.max_corner_distance
    # the ceiling above and the floor below the camera, neither of them at it (with a fraction below 0.5 the two
    # clearances also make the room height positive)
    clearance = config.min_height_fraction * room_height
    plausible &= (ceiling_height > clearance) & (-floor_height > clearance)
    height_sigma = room_height_sigma(uncertainty.height_covariance)
    scale_unknown = height_sigma > config.max_height_uncertainty * room_height
    failed = jnp.stack(
        [
            ~(cam.rc > 1e-6),
            jnp.mean(evidence.finite) < config.min_finite_fraction,
            ~jnp.any(evidence.corner_mask),
            evidence.corner_overflow | final.overflow,
            jnp.sum(mask) < jnp.where(manhattan, 4, 3),
            jnp.sum(final.observed) < 2,
            ~solver_ok,
            ~(jnp.all(meet) & finite & plausible),
            scale_unknown,
            explained_fraction < config.min_explained_fraction,
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
        explained_fraction=explained_fraction,
        corner_covariance=jnp.where(
            mask[:, None, None], _undetermined_as_infinite(uncertainty.corner_covariance, config), 0.0
        ),
        height_covariance=_undetermined_as_infinite(uncertainty.height_covariance, config),
        status=status,
        ok=status == LayoutStatus.OK,
    )


def finish_layout(
    cam: NonCentralPanorama,
    evidence: WallEvidence,
    walls: BranchWalls,
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    config: PipelineConfig,
) -> Layout:
    """Steps 5-6 of a branch's walls: the final adjustment and its uncertainty, then :func:`assemble_layout`."""
    final = walls.final
    adjusted, explained, uncertainty = refine(
        cam,
        evidence,
        final,
        ceiling_v,
        floor_v,
        walls.directions,
        walls.distances,
        walls.ceiling_height,
        walls.floor_height,
        walls.labels,
        config,
    )
    return assemble_layout(
        cam, evidence, final, *adjusted[:4], explained, uncertainty, walls.solver_ok, is_manhattan(walls.labels), config
    )


def _undetermined_as_infinite(covariance: Float[Array, "*n 2 2"], config: PipelineConfig) -> Float[Array, "*n 2 2"]:
    """A covariance with a NaN (a degenerate fit, e.g. on a failed layout) as all-infinite: not determined.

    With ``config.covariance`` off the NaN stays, the documented "not computed".
    """
    if not config.covariance:
        return covariance
    undetermined = jnp.any(jnp.isnan(covariance), axis=(-2, -1), keepdims=True)
    return jnp.where(undetermined, jnp.inf, covariance)
