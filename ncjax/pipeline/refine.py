"""Step 5: the final adjustment in two passes on the trusted rows, and the layout's uncertainty."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..solvers.settings import scaled
from .adjust import BoundaryObservations, adjust_layout, boundary_weights, layout_residuals
from .config import AdjustmentConfig, PipelineConfig
from .types import BranchWalls, FinalWalls, WallEvidence, Walls
from .uncertainty import LayoutUncertainty, layout_uncertainty, not_computed


def _observations(evidence: WallEvidence, final: FinalWalls, stride: int) -> BoundaryObservations:
    """The adjustment's data: every ``stride``-th column (the cost of a step grows with their number)."""
    ceiling_v, floor_v, height = evidence.rows.ceiling, evidence.rows.floor, evidence.cam.height
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


def _row_errors(cam, observations: BoundaryObservations, walls: Walls) -> tuple[Float[Array, " N"], Float[Array, " N"]]:
    """Ceiling and floor row errors (pixels) of the observed columns on ``walls``."""
    errors = layout_residuals(walls, cam, observations, 0.0)
    count = observations.columns.shape[0]
    return errors[:count], errors[count : 2 * count]


def _using(observations: BoundaryObservations, ceiling_used, floor_used) -> BoundaryObservations:
    return eqx.tree_at(lambda o: (o.ceiling_used, o.floor_used), observations, (ceiling_used, floor_used))


def _noise_weighted(cam, observations: BoundaryObservations, errors, config: AdjustmentConfig) -> BoundaryObservations:
    """``observations`` with each boundary's rows weighted by the squared inverse of its noise, from its
    rows' ``errors`` (ceiling, floor) about a layout (:func:`ncjax.pipeline.adjust.boundary_weights`)."""
    weights = boundary_weights(*errors, observations.ceiling_used, observations.floor_used, config.min_noise(cam))
    return eqx.tree_at(lambda o: o.row_weights, observations, weights)


def refine(
    evidence: WallEvidence, branch: BranchWalls, config: PipelineConfig
) -> tuple[Walls, Float[Array, ""], LayoutUncertainty]:
    """Step 5: adjust on the trusted columns, keep the inliers of that layout, adjust again.

    Reads ``config.adjustment``, ``config.uncertainty`` and the inlier threshold ``config.ransac.inlier_threshold``.
    Each pass weights the ceiling and floor rows by the squared inverse of each
    boundary's noise about its starting layout (:func:`ncjax.pipeline.adjust.boundary_weights`).
    The second pass estimates it on its inlier rows, whose errors are cut at
    ``inlier_threshold``: a boundary noisier than about half the threshold reads
    as less noisy than it is, which softens the weighting (it was tuned so, on
    tuning renders). The first pass only has to bring the layout within
    ``inlier_threshold`` of the inlier rows, so it fits a subset of the columns
    (every ``inlier_pass_stride``-th); the second starts next to its optimum.
    Both passes are one traced pass run twice (``lax.scan``), the first with the
    other columns' rows unused: the program compiles and loads faster than with
    a pass of each shape, and each step of the first pass costs as much as the
    second's.

    Returns:
        The adjusted walls (:func:`ncjax.pipeline.adjust.adjust_layout`), the fraction of the rows they explain
        (:func:`explained_fraction`), and their
        :func:`ncjax.pipeline.uncertainty.layout_uncertainty` on the rows of the second adjustment.
    """
    cam, adjustment, labels = evidence.cam, config.adjustment, branch.labels
    observations = _observations(evidence, branch.final, adjustment.stride)
    threshold = config.ransac.inlier_threshold * scaled(1.0, cam.height, 512)
    in_subset = jnp.arange(observations.columns.shape[0]) % adjustment.inlier_pass_stride == 0

    def adjustment_pass(walls, first):
        ceiling_error, floor_error = _row_errors(cam, observations, walls)
        rows = _using(
            observations,
            observations.ceiling_used & jnp.where(first, in_subset, jnp.abs(ceiling_error) < threshold),
            observations.floor_used & jnp.where(first, in_subset, jnp.abs(floor_error) < threshold),
        )
        rows = _noise_weighted(cam, rows, (ceiling_error, floor_error), adjustment)
        adjusted, improved = adjust_layout(cam, rows, walls, labels, adjustment)
        return adjusted, (improved, rows)

    walls, (_, rows) = jax.lax.scan(adjustment_pass, branch.walls, jnp.array([True, False]))
    inliers = jax.tree.map(lambda x: x[1], rows)
    if config.uncertainty.covariance:
        uncertainty = layout_uncertainty(cam, inliers, walls, labels, adjustment, config.uncertainty)
    else:
        uncertainty = not_computed(walls.distances.shape[0], walls.distances.dtype)
    return walls, explained_fraction(evidence, branch.final, walls, config), uncertainty


def explained_fraction(
    evidence: WallEvidence, final: FinalWalls, walls: Walls, config: PipelineConfig
) -> Float[Array, ""]:
    """The fraction of the usable columns' ceiling and floor rows (every ``adjustment.stride``-th column) that
    ``walls`` reproject within the inlier threshold (``Layout.explained_fraction``).

    Every usable column counts, on whichever wall of ``final`` it lies, so that layouts of different walls compare.
    """
    cam, stride = evidence.cam, config.adjustment.stride
    observations = _observations(evidence, final, stride)
    threshold = config.ransac.inlier_threshold * scaled(1.0, cam.height, 512)
    usable = evidence.usable[::stride]
    seen = usable & (observations.column_wall >= 0)
    ceiling_error, floor_error = _row_errors(cam, _using(observations, seen, seen), walls)
    explained = jnp.sum(seen & (jnp.abs(ceiling_error) < threshold)) + jnp.sum(
        seen & (jnp.abs(floor_error) < threshold)
    )
    return explained / jnp.maximum(2 * jnp.sum(usable), 1)
