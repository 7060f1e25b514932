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
1. Corners from the corner probability (:mod:`ncjax.pipeline.corners`); the columns
   between consecutive corners are one wall.
2. Per-wall RANSAC with the single-wall solver (:mod:`ncjax.solvers.ransac`).
3. At each corner, the boundaries of the two walls are compared at the
   corner column (each side's rows extrapolated as a straight wall's, at the
   fitted walls' joint heights, and the two RANSAC walls' reprojections; the
   smaller difference counts): a jump of more than ``occlusion_threshold``
   pixels, and more than ``occlusion_noise_factor`` times the rows' noise about
   their walls (more where a narrow wall's few rows extrapolate less surely),
   means an occlusion (the paper tests the same in 3D for Atlanta rooms; in
   pixels the test does not depend on the single walls' noisy scale).
   Consecutive walls each of which explains the other's pixels may be one wall
   split by a spurious corner.
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
   ``max_corner_offset`` columns from it and whose rows there are more than
   ``stray_noise_factor`` times the rows' noise apart (not in the paper: a
   narrow wall whose two corners gave one peak), and the solver again.
   Both branches' solvers weight the ceiling and floor rows by each
   boundary's noise about the RANSAC walls (not in the paper: a network's
   floor rows are several times noisier than its ceiling rows).
5. Final adjustment (:mod:`ncjax.pipeline.adjust`, optimistix least squares) of both branches, its
   rows weighted likewise: the paper adjusts the Atlanta branch only; the Manhattan branch
   keeps one yaw.
6. Corners where consecutive walls meet.

``world="auto"`` (not in the paper) runs both branches and keeps the one whose
status is more usable (``OK``, then flagged: written with its geometry, then
failed); between equals, the Manhattan layout if it reprojects more of the
boundary rows within the inlier threshold than the Atlanta one less
``manhattan_margin`` (default 0); on a tie
(exact rows), if every RANSAC wall lies within ``manhattan_tolerance`` degrees
of the two perpendicular directions that fit them best (:func:`choose_manhattan`).

Everything has fixed capacity ``K`` (docs/design.md section 4); failures are
status values (:class:`LayoutStatus`), never exceptions, inside traced code.
Repeated stages are traced once, so that the program compiles and loads
faster: the solver passes of step 4 are one ``lax.scan``, and with
``world="auto"`` steps 5-6 run on both branches' walls as one ``vmap``.
Steps 0-4 (:func:`walls_to_adjust`) and 5-6 (:func:`adjusted_layout`) are two
functions, joined by :class:`WallsToAdjust`, so that a program can be saved
in two halves that load at once (:mod:`ncjax.reconstruction`).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Key, PRNGKeyArray, UInt32

from ..geometry.camera import NonCentralPanorama
from .assemble import finish_layout
from .atlanta import atlanta_walls
from .config import DEFAULT_WORLD, WORLDS, PipelineConfig, static_part, traced_part, with_traced
from .evidence import gather_evidence
from .floor_check import ceiling_consistent_floor
from .manhattan import manhattan_frame, manhattan_walls
from .prior import HeightPrior, prior_rows, rescale_to_prior
from .types import FLAGGED_STATUSES, BranchWalls, Layout, LayoutStatus, WallEvidence, pad_layout
from .walls import room_height as solved_room_height
from .walls import scaled_walls


class WallsToAdjust(eqx.Module):
    """One panorama after steps 0-4, before steps 5-6 (internal; traced): what :func:`adjusted_layout` takes.

    The reconstruction's saved programs end and start here (:mod:`ncjax.reconstruction`): XLA loads the
    two halves' compiled programs at once, on two cores.

    Attributes:
        cam: the camera (a height prior's virtual rig).
        evidence: steps 1-3 (:func:`~ncjax.pipeline.evidence.gather_evidence`).
        branches: step 4's walls: one branch's, or with ``world="auto"`` the Manhattan and Atlanta
            branches' stacked on a leading axis.
        ceiling_v: the rows the walls were fitted to.
        floor_v: likewise, after step 0.
        in_frame: every RANSAC wall lies within ``manhattan_tolerance`` of a Manhattan frame (``auto``'s tie).
        prior_room_height: the room height a height prior gives (0: no prior), ``config.prior_room_height``.
    """

    cam: NonCentralPanorama
    evidence: WallEvidence
    branches: BranchWalls
    ceiling_v: Float[Array, " W"]
    floor_v: Float[Array, " W"]
    in_frame: Bool[Array, ""]
    prior_room_height: Float[Array, ""]


def walls_to_adjust(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    corner_prob: Float[Array, " W"],
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    world: str,
    config: PipelineConfig,
    heights: tuple[Float[Array, ""], Float[Array, ""]] | None = None,
) -> WallsToAdjust:
    """Steps 0-4 of one panorama (no input checks; see :func:`layout_from_boundaries`); ``heights``: a height
    prior's known ``(h_c, h_f)`` for RANSAC's walls (:func:`~ncjax.pipeline.evidence.gather_evidence`)."""
    # step 0 always runs: at the default threshold (inf) it replaces no row
    floor_v, replaced = ceiling_consistent_floor(cam, ceiling_v, floor_v, config.floor_consistency_threshold)
    evidence = gather_evidence(ceiling_v, floor_v, corner_prob, cam, key, config, heights)
    evidence = eqx.tree_at(lambda e: e.floor_measured, evidence, ~replaced)
    in_frame = jnp.asarray(False)
    if world == "manhattan":
        branches = manhattan_walls(evidence, ceiling_v, floor_v, cam, config)
    elif world == "atlanta":
        branches = atlanta_walls(evidence, ceiling_v, floor_v, cam, config)
    else:
        _, deviation = manhattan_frame(evidence.walls.direction, evidence.weights)
        counted = evidence.corner_mask & evidence.walls.ok
        in_frame = jnp.all(jnp.where(counted, deviation, 0.0) < jnp.radians(config.manhattan_tolerance))
        branches = jax.tree.map(
            lambda m, a: jnp.stack([m, a]),
            manhattan_walls(evidence, ceiling_v, floor_v, cam, config),
            atlanta_walls(evidence, ceiling_v, floor_v, cam, config),
        )
    return WallsToAdjust(cam, evidence, branches, ceiling_v, floor_v, in_frame, jnp.asarray(config.prior_room_height))


def adjusted_layout(walls: WallsToAdjust, world: str, config: PipelineConfig) -> Layout:
    """Steps 5-6 of :func:`walls_to_adjust`'s walls, and ``world="auto"``'s choice of a branch."""
    cam, evidence, ceiling_v, floor_v = walls.cam, walls.evidence, walls.ceiling_v, walls.floor_v
    if world != "auto":
        return finish_layout(cam, evidence, walls.branches, ceiling_v, floor_v, config)
    # both branches' walls adjusted as one batch: the program holds steps 5-6 once
    layouts = jax.vmap(finish_layout, in_axes=(None, None, 0, None, None, None))(
        cam, evidence, walls.branches, ceiling_v, floor_v, config
    )
    manhattan, atlanta = (jax.tree.map(lambda x, i=i: x[i], layouts) for i in range(2))
    use_manhattan = choose_manhattan(
        manhattan.status,
        atlanta.status,
        manhattan.explained_fraction,
        atlanta.explained_fraction,
        walls.in_frame,
        config.manhattan_margin,
    )
    return jax.tree.map(lambda m, a: jnp.where(use_manhattan, m, a), manhattan, atlanta)


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
    return layout_for(ceiling_v, floor_v, corner_prob, cam, None, key, world, config)


def prior_config(config: PipelineConfig, prior_room_height: Float[ArrayLike, ""]) -> PipelineConfig:
    """``config`` for a height prior's virtual rig: the height-uncertainty test (``max_height_uncertainty``) off,
    since the prior, not the rows' parallax, fixes the scale, and the size limits (``max_room_height``,
    ``max_corner_distance``) at the prior's scale (``prior_room_height``), not at the virtual rig's."""
    return with_traced(config, {"max_height_uncertainty": jnp.asarray(jnp.inf), "prior_room_height": prior_room_height})


def walls_for(ceiling_v, floor_v, corner_prob, cam, prior, key, world, config) -> WallsToAdjust:
    """:func:`walls_to_adjust`, on a height prior's virtual rig when ``prior`` is not None
    (:mod:`ncjax.pipeline.prior`; its walls then at the prior's room height, :func:`at_room_height`)."""
    if prior is None:
        return walls_to_adjust(ceiling_v, floor_v, corner_prob, cam, key, world, config)
    virtual, ceiling_virtual, floor_virtual, heights = prior_rows(cam, ceiling_v, floor_v, prior)
    room_height = heights[0] - heights[1]
    config = prior_config(config, room_height)
    known = heights if config.prior_wall_heights else None
    walls = walls_to_adjust(ceiling_virtual, floor_virtual, corner_prob, virtual, key, world, config, known)
    return eqx.tree_at(lambda w: w.branches, walls, at_room_height(walls.branches, room_height))


def at_room_height(branches: BranchWalls, room_height: Float[ArrayLike, ""]) -> BranchWalls:
    """The branches' walls (one branch's, or ``world="auto"``'s two stacked) scaled about the axis so that their room
    height is ``room_height`` (a prior's).

    The virtual rig's joint solve takes the scale from the virtual rows' parallax, which noisy rows can leave
    hundreds of times off (a real panorama's: a ceiling 385 units above a camera 1.6 high), where the final
    adjustment stalls. The virtual rows were made at the prior's heights, so the adjustment starts from the same
    shape at that scale.
    """
    return scaled_walls(branches, room_height / solved_room_height(branches))


def layout_of_walls(walls: WallsToAdjust, prior: HeightPrior | None, world: str, config: PipelineConfig) -> Layout:
    """:func:`adjusted_layout` of :func:`walls_for`'s walls, scaled to the height ``prior`` states if not None."""
    if prior is None:
        return adjusted_layout(walls, world, config)
    return rescale_to_prior(adjusted_layout(walls, world, prior_config(config, walls.prior_room_height)), prior)


def layout_for(ceiling_v, floor_v, corner_prob, cam, prior, key, world, config) -> Layout:
    """Steps 0-6 of one panorama: :func:`walls_for`, then :func:`layout_of_walls`. With a height ``prior``
    (not None) the scale comes from it (:mod:`ncjax.pipeline.prior`, any ``rc``, 0 included; configured by
    :func:`prior_config`)."""
    walls = walls_for(ceiling_v, floor_v, corner_prob, cam, prior, key, world, config)
    return layout_of_walls(walls, prior, world, config)


def status_rank(status: Int[Array, ""]) -> Int[Array, ""]:
    """How usable a layout of this :class:`LayoutStatus` is: 2 ``OK``, 1 flagged (written with its geometry,
    :data:`~ncjax.pipeline.types.FLAGGED_STATUSES`), 0 failed."""
    flagged = jnp.isin(status, jnp.array([int(code) for code in FLAGGED_STATUSES]))
    return jnp.where(status == LayoutStatus.OK, 2, jnp.where(flagged, 1, 0))


def choose_manhattan(
    manhattan_status: Int[Array, ""],
    atlanta_status: Int[Array, ""],
    manhattan_explained: Float[Array, ""],
    atlanta_explained: Float[Array, ""],
    in_frame: Bool[Array, ""],
    margin: Float[ArrayLike, ""] = 0.0,
) -> Bool[Array, ""]:
    """``world="auto"``: whether to keep the Manhattan branch's layout rather than the Atlanta one.

    The branch whose status is more usable wins (:func:`status_rank`: ``OK``, then flagged, then
    failed): a flagged layout is still written, so two flagged branches are compared like two ``OK``
    ones. Between equals the Manhattan layout is kept when it reprojects more of the usable boundary
    rows within the inlier threshold than the Atlanta one less ``margin`` (``manhattan_margin``: the
    Atlanta branch has a free angle per wall, so it rarely loses unless the room is Manhattan, and on
    noisy rows it explains more by following the noise), and on a tie (exact rows: both explain
    everything) when every RANSAC wall lies within ``manhattan_tolerance`` of a Manhattan frame.
    """
    manhattan_rank, atlanta_rank = status_rank(manhattan_status), status_rank(atlanta_status)
    lead = manhattan_explained + margin - atlanta_explained
    better = jnp.where(manhattan_explained == atlanta_explained, in_frame, lead > 0)
    return (manhattan_rank > atlanta_rank) | ((manhattan_rank == atlanta_rank) & better)


def _padded_layout(ceiling_v, floor_v, corner_prob, cam, prior, key, thresholds, world, config, slots):
    config = with_traced(config, thresholds)
    return pad_layout(layout_for(ceiling_v, floor_v, corner_prob, cam, prior, key, world, config), slots)


_layout_jit = jax.jit(_padded_layout, static_argnames=("world", "config", "slots"))


def layout_from_boundaries(
    ceiling_v: Float[ArrayLike, "*batch W"],
    floor_v: Float[ArrayLike, "*batch W"],
    corner_prob: Float[ArrayLike, "*batch W"],
    cam: NonCentralPanorama,
    world: str = DEFAULT_WORLD,
    config: PipelineConfig = PipelineConfig(),
    key: PRNGKeyArray | Key[Array, "*batch"] | UInt32[Array, "*batch 2"] | None = None,
    prior: HeightPrior | None = None,
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
        world: static: "manhattan", "atlanta" or "auto" (the default, :data:`DEFAULT_WORLD`).
        config: :class:`PipelineConfig`; its thresholds (:data:`~ncjax.pipeline.config.TRACED_FIELDS`)
            are traced, the rest static.
        key: PRNG key of the RANSAC sampling (default ``jax.random.key(0)``; typed or raw): one key, split
            over the batch, or one key per panorama (the batch's shape): a panorama's RANSAC samples then do
            not depend on the batch it is in.
        prior: a :class:`~ncjax.pipeline.prior.HeightPrior` (a scalar value or one per panorama): the scale
            comes from it instead of the rows' parallax (:func:`layout_for`; needed for ``rc = 0``).

    Returns:
        A :class:`Layout`; check ``ok`` / ``status``.

    Raises:
        ValueError: for an unknown ``world``, arrays whose shapes do not match
            the camera, camera fields or keys of another shape than the batch's.
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
    if prior is not None and jnp.shape(prior.value) not in ((), batch):
        raise ValueError(f"the prior's value must be a scalar or of the batch's shape {batch}")
    keys = panorama_keys(jax.random.key(0) if key is None else key, batch)
    if not batch:
        return _layout_with_fallback(*arrays, cam, prior, keys, world, config)
    flat = [x.reshape(-1, cam.width) for x in arrays]
    cams, prior = jax.tree.map(lambda x: jnp.broadcast_to(x, batch).reshape(-1), (cam, prior))
    layout = _layout_with_fallback(*flat, cams, prior, keys, world, config)
    return jax.tree.map(lambda x: x.reshape(batch + x.shape[1:]), layout)


def panorama_keys(key: Array, batch: tuple[int, ...]) -> Array:
    """The RANSAC key of each panorama of ``batch``, flat: ``key`` split over the batch, or ``key`` itself
    when it holds one key per panorama (the batch's shape); ``key`` unchanged when ``batch`` is ``()``.

    Raw ``uint32`` keys (``jax.random.PRNGKey``, shape ``(..., 2)``) are wrapped first.

    Raises:
        ValueError: a key of another shape.
    """
    if not jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.wrap_key_data(jnp.asarray(key, jnp.uint32))
    if jnp.shape(key) not in ((), batch):
        raise ValueError(f"key must be one PRNG key or one per panorama {batch}, got shape {jnp.shape(key)}")
    if not batch:
        return key
    return jax.random.split(key, math.prod(batch)) if jnp.shape(key) == () else jnp.reshape(key, (-1,))


def _layout_with_fallback(ceiling_v, floor_v, corner_prob, cam, prior, key, world, config) -> Layout:
    """One panorama (1D rows) or a flat batch: with ``config.compact_capacity`` slots first where that can help.

    A rerun with ``config.capacity`` slots replaces the compact run's
    ``TOO_MANY_WALLS`` layouts; the checks before that status do not depend
    on the slots, so it is raised exactly when the layout needs more of them.
    Traced inputs run with ``config.capacity`` slots directly.
    """
    batched = ceiling_v.ndim == 2
    thresholds = traced_part(config)
    run = functools.partial(
        _batched_layout_jit if batched else _layout_jit, thresholds=thresholds, world=world, slots=config.capacity
    )
    full = static_part(dataclasses.replace(config, compact_capacity=0))
    compact = config.compact_capacity
    if not 0 < compact < config.capacity or any(
        isinstance(x, jax.core.Tracer) for x in (ceiling_v, floor_v, corner_prob)
    ):
        return run(ceiling_v, floor_v, corner_prob, cam, prior, key, config=full)
    layout = run(ceiling_v, floor_v, corner_prob, cam, prior, key, config=dataclasses.replace(full, capacity=compact))
    if not batched:
        return (
            run(ceiling_v, floor_v, corner_prob, cam, prior, key, config=full)
            if layout.status == LayoutStatus.TOO_MANY_WALLS
            else layout
        )
    rerun = np.flatnonzero(np.asarray(layout.status) == LayoutStatus.TOO_MANY_WALLS)
    if not rerun.size:
        return layout
    # padded to a power of two: few batch sizes, so few compilations
    padding = (1 << (rerun.size - 1).bit_length()) - rerun.size
    picked = jnp.asarray(np.concatenate([rerun, np.full(padding, rerun[0])]))
    destination = jnp.asarray(np.concatenate([rerun, np.full(padding, ceiling_v.shape[0])]))
    return _rerun_jit(
        ceiling_v,
        floor_v,
        corner_prob,
        cam,
        prior,
        key,
        layout,
        picked,
        destination,
        thresholds,
        world=world,
        config=full,
    )


def _batched_layout(ceiling_v, floor_v, corner_prob, cams, priors, keys, thresholds, world, config, slots):
    def one(c, f, p, cam, prior, k):
        return _padded_layout(c, f, p, cam, prior, k, thresholds, world, config, slots)

    inputs = (ceiling_v, floor_v, corner_prob, cams, priors, keys)
    if not 0 < config.chunk_size < ceiling_v.shape[0]:
        return jax.vmap(one)(*inputs)
    # the last, partial chunk (if any) is one more vmap after the loop over the full ones
    return jax.lax.map(lambda args: one(*args), inputs, batch_size=config.chunk_size)


_batched_layout_jit = jax.jit(_batched_layout, static_argnames=("world", "config", "slots"))


def _rerun(ceiling_v, floor_v, corner_prob, cams, priors, keys, layout, picked, destination, thresholds, world, config):
    """``layout`` with the panoramas ``picked`` solved again with ``config``: gather, solve and scatter in one call.

    Result ``i`` goes to panorama ``destination[i]``; out-of-range
    destinations (the padding of ``picked``) are dropped.
    """
    inputs = jax.tree.map(lambda x: x[picked], (ceiling_v, floor_v, corner_prob, cams, priors, keys))
    redone = _batched_layout(*inputs, thresholds, world, config, config.capacity)
    return jax.tree.map(lambda old, new: old.at[destination].set(new, mode="drop"), layout, redone)


_rerun_jit = jax.jit(_rerun, static_argnames=("world", "config"))
