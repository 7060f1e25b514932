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

Where the kept layout is flagged ``LOW_CONFIDENCE`` (the network's configuration), the plan layout
(:mod:`ncjax.pipeline.plan`, not in the paper: walls read robustly off the floor rows' plan) replaces it.

``world="auto"`` (not in the paper) runs both branches and keeps the one whose
status is more usable (``OK``, then flagged: written with its geometry, then
failed); between equals, the Manhattan layout if it reprojects more of the
boundary rows within the inlier threshold than the Atlanta one less
``manhattan_margin`` (default 0); on a tie
(exact rows), if every RANSAC wall lies within ``manhattan_tolerance`` degrees
of the two perpendicular directions that fit them best (:func:`choose_manhattan`).

The one path through the pipeline, for one panorama: :func:`fit_walls` (steps
0-4; on a height prior's virtual rig when a prior is given) returns
:class:`FittedWalls`, :func:`finish` (steps 5-6, ``world="auto"``'s choice and
the prior's scale) the :class:`Layout`; :func:`layout_of` is the two. Batches
map them with ``jax.vmap`` (:mod:`ncjax.pipeline.batch`:
:func:`~ncjax.pipeline.batch.layout_from_boundaries`; :mod:`ncjax.reconstruction`
after the network). They are two functions so that a program can be saved in
two halves that load at once (:mod:`ncjax.reconstruction`).

Everything has fixed capacity ``K`` (docs/design.md section 4); failures are
status values (:class:`LayoutStatus`), never exceptions, inside traced code.
Repeated stages are traced once, so that the program compiles and loads
faster: the solver passes of step 4 are one ``lax.scan``, and with
``world="auto"`` steps 5-6 run on both branches' walls as one ``vmap``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama
from ..geometry.polygon import is_simple, point_in_polygon
from .assemble import finish_layout
from .atlanta import atlanta_walls
from .config import PipelineConfig
from .evidence import gather_evidence
from .floor_check import ceiling_consistent_floor
from .manhattan import manhattan_frame, manhattan_walls
from .plan import plan_layout
from .prior import HeightPrior, prior_rows, rescale_to_prior
from .types import FLAGGED_STATUSES, BranchWalls, Layout, LayoutStatus, Rows, WallEvidence
from .walls import room_height as solved_room_height
from .walls import scaled_walls


class FittedWalls(eqx.Module):
    """One panorama after steps 0-4, before steps 5-6 (traced): what :func:`finish` takes.

    The reconstruction's saved programs end and start here (:mod:`ncjax.reconstruction`): XLA loads the
    two halves' compiled programs at once, on two cores.

    Attributes:
        evidence: steps 1-3 (:func:`~ncjax.pipeline.evidence.gather_evidence`), with the camera (a height
            prior's virtual rig) and the rows the walls were fitted to (after step 0).
        branches: step 4's walls: one branch's, or with ``world="auto"`` the Manhattan and Atlanta
            branches' stacked on a leading axis.
        in_frame: every RANSAC wall lies within ``manhattan_tolerance`` of a Manhattan frame (``auto``'s tie).
        prior_heights: the ``(h_c, h_f)`` a height prior gives, at which its virtual rig's rows are the
            image's boundary points (zeros: no prior).
    """

    evidence: WallEvidence
    branches: BranchWalls
    in_frame: Bool[Array, ""]
    prior_heights: Float[Array, " 2"]

    @property
    def prior_room_height(self) -> Float[Array, ""]:
        """The room height a height prior gives (0: no prior), ``config.prior.room_height``."""
        return self.prior_heights[0] - self.prior_heights[1]


def _branch_walls(evidence: WallEvidence, config: PipelineConfig, world: str) -> tuple[BranchWalls, Bool[Array, ""]]:
    """Step 4: the ``world``'s branch, or both stacked for ``"auto"``, and whether the RANSAC walls lie in a
    Manhattan frame (``auto``'s tie)."""
    limits = (config.ransac.sample_size, config.checks.max_room_height)
    if world == "manhattan":
        return manhattan_walls(evidence, config.branches, *limits), jnp.asarray(False)
    if world == "atlanta":
        return atlanta_walls(evidence, config.branches, *limits), jnp.asarray(False)
    _, deviation = manhattan_frame(evidence.walls.direction, evidence.weights)
    counted = evidence.corner_mask & evidence.walls.ok
    in_frame = jnp.all(jnp.where(counted, deviation, 0.0) < jnp.radians(config.branches.manhattan_tolerance))
    branches = jax.tree.map(
        lambda m, a: jnp.stack([m, a]),
        manhattan_walls(evidence, config.branches, *limits),
        atlanta_walls(evidence, config.branches, *limits),
    )
    return branches, in_frame


def _fit_walls_of_rows(
    rows: Rows,
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    config: PipelineConfig,
    world: str,
    heights: tuple[Float[Array, ""], Float[Array, ""]] | None = None,
) -> FittedWalls:
    """Steps 0-4 of these rows; ``heights``: a height prior's known ``(h_c, h_f)`` for RANSAC's walls
    (:func:`~ncjax.pipeline.evidence.gather_evidence`)."""
    # step 0 always runs: at the default threshold (inf) it replaces no row
    floor_v, replaced = ceiling_consistent_floor(cam, rows.ceiling, rows.floor, config.floor_check.threshold)
    evidence = gather_evidence(Rows(rows.ceiling, floor_v, rows.corner_prob), cam, key, config, heights)
    evidence = eqx.tree_at(lambda e: (e.floor_measured, e.input_floor), evidence, (~replaced, rows.floor))
    branches, in_frame = _branch_walls(evidence, config, world)
    return FittedWalls(evidence, branches, in_frame, jnp.zeros(2, floor_v.dtype))


def prior_config(config: PipelineConfig, prior_room_height: Float[ArrayLike, ""]) -> PipelineConfig:
    """``config`` for a height prior's virtual rig: the height-uncertainty test (``max_height_uncertainty``) off,
    since the prior, not the rows' parallax, fixes the scale, and the size limits (``max_room_height``,
    ``max_corner_distance``) at the prior's scale (``prior.room_height``), not at the virtual rig's."""
    return eqx.tree_at(
        lambda c: (c.checks.max_height_uncertainty, c.prior.room_height),
        config,
        (jnp.asarray(jnp.inf), prior_room_height),
    )


def fit_walls(
    rows: Rows,
    cam: NonCentralPanorama,
    prior: HeightPrior | None,
    key: PRNGKeyArray,
    config: PipelineConfig,
    world: str,
) -> FittedWalls:
    """Steps 0-4 of one panorama (no input checks; see :func:`~ncjax.pipeline.batch.layout_from_boundaries`).

    With a height ``prior`` (not None) they run on the prior's virtual rig (:mod:`ncjax.pipeline.prior`),
    its walls then at the prior's room height (:func:`at_room_height`).

    Args:
        rows: the panorama's rows (``W`` columns).
        cam: its camera.
        prior: a height prior, or None (the scale from the rows' parallax).
        key: the RANSAC key.
        config: the pipeline's configuration (traced thresholds).
        world: static: ``"manhattan"``, ``"atlanta"`` or ``"auto"``.
    """
    if prior is None:
        return _fit_walls_of_rows(rows, cam, key, config, world)
    virtual, ceiling_virtual, floor_virtual, heights = prior_rows(cam, rows.ceiling, rows.floor, prior)
    room_height = heights[0] - heights[1]
    config = prior_config(config, room_height)
    known = heights if config.prior.wall_heights else None
    virtual_rows = Rows(ceiling_virtual, floor_virtual, rows.corner_prob)
    walls = _fit_walls_of_rows(virtual_rows, virtual, key, config, world, known)
    return eqx.tree_at(
        lambda w: (w.branches, w.prior_heights),
        walls,
        (at_room_height(walls.branches, room_height), jnp.stack(heights).astype(walls.prior_heights.dtype)),
    )


def at_room_height(branches: BranchWalls, room_height: Float[ArrayLike, ""]) -> BranchWalls:
    """The branches' walls (one branch's, or ``world="auto"``'s two stacked) scaled about the axis so that their room
    height is ``room_height`` (a prior's).

    The virtual rig's joint solve takes the scale from the virtual rows' parallax, which noisy rows can leave
    hundreds of times off (a real panorama's: a ceiling 385 units above a camera 1.6 high), where the final
    adjustment stalls. The virtual rows were made at the prior's heights, so the adjustment starts from the same
    shape at that scale.
    """
    return scaled_walls(branches, room_height / solved_room_height(branches))


def _finish_branches(walls: FittedWalls, config: PipelineConfig, world: str) -> Layout:
    """Steps 5-6 of :func:`fit_walls`'s walls, and ``world="auto"``'s choice of a branch."""
    evidence = walls.evidence
    if world != "auto":
        layout = finish_layout(evidence, walls.branches, config)
    else:
        # both branches' walls adjusted as one batch: the program holds steps 5-6 once
        layouts = jax.vmap(finish_layout, in_axes=(None, 0, None))(evidence, walls.branches, config)
        manhattan, atlanta = (jax.tree.map(lambda x, i=i: x[i], layouts) for i in range(2))
        use_manhattan = choose_manhattan(
            (manhattan.status, atlanta.status),
            (manhattan.explained_fraction, atlanta.explained_fraction),
            walls.in_frame,
            config.branches.manhattan_margin,
        )
        layout = jax.tree.map(lambda m, a: jnp.where(use_manhattan, m, a), manhattan, atlanta)
    if not config.plan.fallback:
        return layout
    # a prior's virtual rows are the image's boundary points at the prior's heights only
    with_prior = walls.prior_heights[1] < 0
    heights = jnp.where(with_prior, walls.prior_heights, jnp.stack([layout.ceiling_height, layout.floor_height]))
    return plan_fallback(evidence, layout, heights, config)


def plan_fallback(
    evidence: WallEvidence, layout: Layout, heights: Float[Array, " 2"], config: PipelineConfig
) -> Layout:
    """``layout``, or where it is flagged ``LOW_CONFIDENCE`` the plan layout (:mod:`ncjax.pipeline.plan`) at
    ``heights`` (``h_c``, ``h_f``) when that one has geometry (:func:`status_rank`): the rows the branch's walls do
    not explain, read robustly (carrying no gradient). A plan layout whose walls cross (where two walls' lines meet
    beyond a narrow wall between them), with a corner on or inside the circle of optical centres (where walls
    inserted through the axis meet a wall whose line passes near it) or that leaves the camera's axis outside (the
    camera stands in the room it sees) is no room and is not used."""
    # no gradient: medians and reweighting are not the least squares the pipeline differentiates, and a plan
    # layout that is not chosen must not put NaNs into the chosen one's gradient
    plan = plan_layout(*jax.lax.stop_gradient((evidence, heights, layout.height_covariance)), config)
    plan_corners = plan.floor_corners[:, :2]
    room = is_simple(plan_corners, plan.mask) & point_in_polygon(
        jnp.zeros(2, plan_corners.dtype), plan_corners, plan.mask
    )
    room &= jnp.all(~plan.mask | (jnp.linalg.norm(plan_corners, axis=-1) > evidence.cam.rc))
    use_plan = (layout.status == LayoutStatus.LOW_CONFIDENCE) & (status_rank(plan.status) > 0) & room
    return jax.tree.map(lambda p, b: jnp.where(use_plan, p, b), plan, layout)


def finish(walls: FittedWalls, prior: HeightPrior | None, config: PipelineConfig, world: str) -> Layout:
    """Steps 5-6 of :func:`fit_walls`'s walls (with the same ``prior``, ``config`` and ``world``): the final
    adjustment, its uncertainty and the layout, scaled to the height ``prior`` states if not None."""
    if prior is None:
        return _finish_branches(walls, config, world)
    layout = _finish_branches(walls, prior_config(config, walls.prior_room_height), world)
    return rescale_to_prior(layout, prior)


def layout_of(
    rows: Rows,
    cam: NonCentralPanorama,
    prior: HeightPrior | None,
    key: PRNGKeyArray,
    config: PipelineConfig,
    world: str,
) -> Layout:
    """Steps 0-6 of one panorama: :func:`fit_walls`, then :func:`finish`. With a height ``prior`` (not None)
    the scale comes from it (:mod:`ncjax.pipeline.prior`, any ``rc``, 0 included)."""
    return finish(fit_walls(rows, cam, prior, key, config, world), prior, config, world)


def status_rank(status: Int[Array, ""]) -> Int[Array, ""]:
    """How usable a layout of this :class:`LayoutStatus` is: 2 ``OK``, 1 flagged (written with its geometry,
    :data:`~ncjax.pipeline.types.FLAGGED_STATUSES`), 0 failed."""
    flagged = jnp.isin(status, jnp.array([int(code) for code in FLAGGED_STATUSES]))
    return jnp.where(status == LayoutStatus.OK, 2, jnp.where(flagged, 1, 0))


def choose_manhattan(
    statuses: tuple[Int[Array, ""], Int[Array, ""]],
    explained: tuple[Float[Array, ""], Float[Array, ""]],
    in_frame: Bool[Array, ""],
    margin: Float[ArrayLike, ""] = 0.0,
) -> Bool[Array, ""]:
    """``world="auto"``: whether to keep the Manhattan branch's layout rather than the Atlanta one.

    ``statuses`` and ``explained`` (fractions of the rows) are the Manhattan and the Atlanta layout's. The
    branch whose status is more usable wins (:func:`status_rank`: ``OK``, then flagged, then
    failed): a flagged layout is still written, so two flagged branches are compared like two ``OK``
    ones. Between equals the Manhattan layout is kept when it reprojects more of the usable boundary
    rows within the inlier threshold than the Atlanta one less ``margin`` (``manhattan_margin``: the
    Atlanta branch has a free angle per wall, so it rarely loses unless the room is Manhattan, and on
    noisy rows it explains more by following the noise), and on a tie (exact rows: both explain
    everything) when every RANSAC wall lies within ``manhattan_tolerance`` of a Manhattan frame.
    """
    (manhattan_status, atlanta_status), (manhattan_explained, atlanta_explained) = statuses, explained
    manhattan_rank, atlanta_rank = status_rank(manhattan_status), status_rank(atlanta_status)
    lead = manhattan_explained + margin - atlanta_explained
    better = jnp.where(manhattan_explained == atlanta_explained, in_frame, lead > 0)
    return (manhattan_rank > atlanta_rank) | ((manhattan_rank == atlanta_rank) & better)
