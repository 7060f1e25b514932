"""``ncjax.reconstruction``: panorama -> Non-central HorizonNet -> geometric pipeline -> metric Layout.

The two blocks of the paper's Fig. pipeline in ONE jitted function: the image
is resized to the network's input size, the network's per-column outputs are
brought back to the image's columns and rows (:func:`~ncjax.network.model.prediction_to_rows`)
and snapped to the full image's edges (:func:`~ncjax.network.edges.snap_to_edges`), and the
geometric pipeline (:func:`~ncjax.pipeline.run.layout_for`)
runs on them with each image's own camera radius. Nothing leaves the device
between the two blocks, and a batch of images is one call. With a
``program_cache`` the same computation runs as three saved programs (the
network, the geometry's steps 0-4 and 5-6) that a later process loads at once.

With a height prior (:class:`~ncjax.pipeline.prior.HeightPrior`) the scale of a
central panorama (``rc = 0``) comes from it; a non-central one keeps the scale
its geometry measures and falls back to the prior only where the geometry
cannot fix it (:data:`SCALE_FAILURES`); :class:`Reconstruction` says which
(:data:`SCALE_SOURCES`) and keeps the geometry's own layout for comparison.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, ArrayLike, Float, Int, Key, PRNGKeyArray, Shaped, UInt32

from .geometry.camera import NonCentralPanorama
from .geometry.gravity import panorama_size_error
from .network.checkpoint import ModelWeights, load_model, model_from_weights, model_weights
from .network.edges import EdgeSnap
from .network.model import HorizonNet, check_views
from .network.predict import DEFAULT_MODEL_PATH, DEFAULT_VIEWS, default_model, image_boundaries
from .pipeline.config import DEFAULT_WORLD, WORLDS, PipelineConfig, static_part, traced_part, with_traced
from .pipeline.prior import HeightPrior, scale_conflict
from .pipeline.run import WallsToAdjust, layout_of_walls, panorama_keys, walls_for
from .pipeline.types import Layout, LayoutStatus
from .programs import call_saved, load_saved, result_like

# The pipeline's defaults suit exact and white-noise rows. The network's corner probability has lobes several
# columns wide, in which NMS over +-2 columns leaves spurious second peaks: +-4 columns and a 0.4 threshold keep one
# peak per corner more often. Network rows snapped to the image's edges are exact to a fraction of a pixel in most
# columns, so the noise-scaled part of the occlusion test falls to its floor, but not beside the corners, where two
# walls' edges mix: a jump there must reach 8 px, not 4, to count as an occlusion. Chosen for the shipped model on
# tuning renders, never the test renders (experiments/tune_network_pipeline.py; experiments/RESULTS.md).
# A layout whose room height the rows fix no better than 15% (one sigma of the calibrated covariance below) fails
# with UNCERTAIN_SCALE: on the tuning renders two thirds of the ok layouts this fails were more than 0.3 m off, and
# 0.15 is the smallest threshold at which they were in both worlds (experiments/RESULTS.md).
# Floor rows more than 2 px from the row their column's ceiling row implies are replaced by it for the walls' fits
# (step 0, ncjax.pipeline.floor_check; 2 and 3 px compared on the tuning renders, experiments/RESULTS.md).
# A layout that reprojects fewer than 60% of the usable rows within 3 px is flagged LOW_CONFIDENCE: on the tuning
# renders the fewest was 72% (none flagged), on real photographs 19-79%, and the layouts below 60% there had a mean
# 3D IoU of 0.44 against 0.68 above (experiments/confidence.py; experiments/RESULTS.md).
# A non-central layout whose geometry could not fix its scale (UNCERTAIN_SCALE) takes the height prior's; it is
# flagged SCALE_CONFLICT where the height its parallax measured lies more than 3 standard deviations (the rows' and
# the prior's) from the prior's: on the tuning renders such fallbacks were at most 1.0 sigma away (the rows of one
# room leave the scale free, not wrong), the real capture L101, whose rows run along desks, 4.4 (a 0.25 m camera
# against 1.6 m) (experiments/confidence.py; experiments/RESULTS.md).
# The covariances count two errors of the network's rows that the fit absorbs and its residuals cannot show: an
# offset per wall and boundary (2 times the rows' noise and 1 px, combined) and the corner columns' error (2 px):
# the setting whose 95% ellipses and height intervals covered nearest 93.5% of the truth (the middle of the 90-97%
# goal) on 256 tuning renders per world (experiments/calibrate_uncertainty.py).
NETWORK_PIPELINE_CONFIG = PipelineConfig(
    corner_threshold=0.4,
    nms_radius=4.0,
    occlusion_threshold=8.0,
    max_height_uncertainty=0.15,
    floor_consistency_threshold=2.0,
    min_explained_fraction=0.6,
    max_scale_conflict=3.0,
    wall_offset_ratio=2.0,
    wall_offset_noise=1.0,
    corner_column_noise=2.0,
)


# The saved geometry programs (ncjax.programs, the CLI's) compile with XLA's cheaper backend settings: 21 instead of 37
# CPU seconds of compilation on 2 cores (a first run 28-34 -> 20-24 s, benchmarks/bench_startup.py), for a geometry
# that runs in tens of milliseconds a panorama either way (the same layouts to 1e-5). The network keeps the full
# optimisation: it is most of a run's time.
GEOMETRY_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True}


# Where a layout's scale came from (Reconstruction.scale_source): the rows' non-central parallax, the height
# prior (a central panorama, or no prior asked for... then NO_SCALE), or the prior because the geometry failed.
SCALE_SOURCES = ("non-central geometry", "height prior", "height prior (the geometry could not fix the scale)")
GEOMETRY, PRIOR, PRIOR_FALLBACK = range(3)
# the statuses of a non-central layout after which a height prior, when given, replaces the geometry's scale
SCALE_FAILURES = (
    LayoutStatus.NO_SCALE,
    LayoutStatus.WALL_FIT_FAILED,
    LayoutStatus.SOLVER_FAILED,
    LayoutStatus.DEGENERATE_LAYOUT,
    LayoutStatus.UNCERTAIN_SCALE,
)


class Reconstruction(NamedTuple):
    """What :func:`reconstruct_batch` returns: the layouts and the network's boundaries they came from.

    Attributes:
        layout: :class:`~ncjax.Layout` with a leading batch axis B.
        ceiling_v, floor_v: (B, W) the boundary rows the geometry used, in image
            pixels (the network's, snapped to the image's edges by default).
        corner_prob: (B, W) the network's corner probability.
        scale_source: (B,) index into :data:`SCALE_SOURCES`.
        geometry: the layouts with the scale the non-central geometry measured (B leading), or None when
            it did not run (no prior, then ``layout`` is it, or every ``rc`` 0).
    """

    layout: Layout
    ceiling_v: Float[Array, "B W"]
    floor_v: Float[Array, "B W"]
    corner_prob: Float[Array, "B W"]
    scale_source: Int[Array, " B"]
    geometry: Layout | None = None


def _walls_of_rows(
    ceiling_v: Float[Array, "B W"],
    floor_v: Float[Array, "B W"],
    corner_prob: Float[Array, "B W"],
    image_height: int,
    rc: Float[Array, " B"],
    keys: Key[Array, " B"],
    thresholds: dict[str, Float[Array, ""]],
    prior: HeightPrior | None,
    world: str,
    config: PipelineConfig,
) -> WallsToAdjust:
    """Steps 0-4 of the geometric pipeline on each panorama's rows, with its own radius, key and prior."""
    config = with_traced(config, thresholds)

    def one(ceiling, floor, probability, radius, one_prior, key):
        cam = NonCentralPanorama(ceiling_v.shape[-1], image_height, rc=radius)
        return walls_for(ceiling, floor, probability, cam, one_prior, key, world, config)

    return jax.vmap(one)(ceiling_v, floor_v, corner_prob, rc, prior, keys)


def _layouts_of_walls(
    walls: WallsToAdjust,
    thresholds: dict[str, Float[Array, ""]],
    prior: HeightPrior | None,
    world: str,
    config: PipelineConfig,
) -> Layout:
    """Steps 5-6 of :func:`_walls_of_rows`' walls."""
    config = with_traced(config, thresholds)
    return jax.vmap(lambda w, p: layout_of_walls(w, p, world, config))(walls, prior)


def _reconstruction(layouts: Layout, rows, rc: Float[Array, " B"], prior: HeightPrior | None) -> Reconstruction:
    """A batch's layouts and rows, each scale from the geometry or, with a prior, from the prior."""
    return Reconstruction(layouts, *rows, jnp.full(rc.shape, GEOMETRY if prior is None else PRIOR))


def _geometry_body(
    rows: tuple[Float[Array, "B W"], Float[Array, "B W"], Float[Array, "B W"]],
    image_height: int,
    rc: Float[Array, " B"],
    keys: Key[Array, " B"],
    thresholds: dict[str, Float[Array, ""]],
    prior: HeightPrior | None,
    world: str,
    config: PipelineConfig,
) -> Layout:
    """The geometric pipeline (steps 0-6) on a batch's rows: :func:`_walls_of_rows`, then :func:`_layouts_of_walls`."""
    walls = _walls_of_rows(*rows, image_height, rc, keys, thresholds, prior, world, config)
    return _layouts_of_walls(walls, thresholds, prior, world, config)


_geometry = jax.jit(_geometry_body, static_argnames=("image_height", "world", "config"))


def _reconstruct_body(
    model: HorizonNet,
    images: Shaped[Array, "B H W 3"],
    rc: Float[Array, " B"],
    keys: Key[Array, " B"],
    thresholds: dict[str, Float[Array, ""]],
    prior: HeightPrior | None,
    world: str,
    config: PipelineConfig,
    views: int,
    edge_snap: EdgeSnap | None,
) -> Reconstruction:
    rows = image_boundaries(model, images, views, edge_snap)
    layouts = _geometry_body(rows, images.shape[1], rc, keys, thresholds, prior, world, config)
    return _reconstruction(layouts, rows, rc, prior)


_reconstruct = nnx.jit(_reconstruct_body, static_argnames=("world", "config", "views", "edge_snap"))


def _saved_geometry(
    directory, image_shape: tuple[int, int, int], rc, keys, thresholds, prior, world, config
) -> Callable[[tuple[Array, Array, Array]], Layout]:
    """:func:`_geometry_body` for a batch of ``image_shape`` (B, H, W) through two programs saved in ``directory``
    (:mod:`ncjax.programs`): its steps 0-4 and 5-6, loaded in two threads from this call on, while the caller
    goes on (XLA loads a compiled program on one core, and these are most of the loading). Returns the
    function of the rows (ceiling, floor, corner probability; (B, W) each) that runs them.
    """
    batch, image_height, width = image_shape
    walls_structure = []
    impl = jax.random.key_impl(keys)

    def walls(rows, rc, key_data, thresholds, prior):
        key = jax.random.wrap_key_data(key_data, impl=impl)
        leaves, structure = jax.tree.flatten(
            _walls_of_rows(*rows, image_height, rc, key, thresholds, prior, world, config)
        )
        walls_structure.append(structure)
        return leaves  # a saved program returns plain containers (a pickled result tree)

    def layouts(walls_leaves, thresholds, prior):
        if not walls_structure:  # the walls' program was loaded, not traced: trace its shapes alone
            jax.eval_shape(walls, rows_like, *walls_arguments)
        layout = _layouts_of_walls(
            jax.tree.unflatten(walls_structure[0], walls_leaves), thresholds, prior, world, config
        )
        return {field.name: getattr(layout, field.name) for field in dataclasses.fields(Layout)}

    rows_like = (jax.ShapeDtypeStruct((batch, width), jnp.float32),) * 3
    walls_arguments = (rc, jax.random.key_data(keys), thresholds, prior)
    settings = (image_height, str(impl), world, config)
    walls_key, layouts_key = repr(("walls", *settings)), repr(("layouts", *settings))
    walls_like = result_like(directory, walls_key, walls, rows_like, *walls_arguments)
    cheap = {"compiler_options": GEOMETRY_COMPILER_OPTIONS}
    pool = concurrent.futures.ThreadPoolExecutor(2)
    walls_program = pool.submit(load_saved, directory, walls_key, walls, rows_like, *walls_arguments, **cheap)
    layouts_program = pool.submit(load_saved, directory, layouts_key, layouts, walls_like, thresholds, prior, **cheap)
    pool.shutdown(wait=False)  # the two loads go on; the pool takes no more

    def run(rows):
        walls_leaves = walls_program.result()(tuple(rows), *walls_arguments)
        return Layout(**layouts_program.result()(walls_leaves, thresholds, prior))

    return run


def _reconstruct_saved(
    directory, weights: ModelWeights, images, rc, keys, thresholds, prior, world, config, views, edge_snap
):
    """:func:`_reconstruct` through three programs saved in ``directory`` (:mod:`ncjax.programs`): the
    network's and the geometry's two (:func:`_saved_geometry`, loading while the network's loads and runs).
    A later process skips the tracing, and building the network too. The weights are arguments, the
    architecture part of the key; the network's program serves every world and pipeline setting.
    """
    geometry = _saved_geometry(directory, images.shape[:3], rc, keys, thresholds, prior, world, config)

    def network(tensors, images):
        return image_boundaries(model_from_weights(weights._replace(tensors=tensors)), images, views, edge_snap)

    network_key = repr(("network", weights.config, views, edge_snap))
    rows = tuple(
        row.astype(jnp.float32) for row in call_saved(directory, network_key, network, weights.tensors, images)
    )
    return _reconstruction(geometry(rows), rows, rc, prior)


def _with_prior_fallback(
    result: Reconstruction,
    rc: np.ndarray,
    prior: HeightPrior,
    keys: Key[Array, " B"],
    world: str,
    config: PipelineConfig,
    program_cache: str | os.PathLike | None = None,
) -> Reconstruction:
    """``result`` (the geometry's) with the prior's layout where ``rc = 0`` or the status is a :data:`SCALE_FAILURES`.

    The prior's pipeline runs on the same rows and RANSAC keys, for the whole batch (one program per batch
    size), and only when some panorama needs it: the central route's programs (saved in ``program_cache``
    if given, as :func:`_saved_geometry`), flagged where the two scales conflict (:func:`_flag_scale_conflicts`).
    """
    status = np.asarray(result.layout.status)
    needs = (rc == 0) | np.isin(status, np.asarray(SCALE_FAILURES))
    source = np.where(rc == 0, PRIOR, np.where(needs, PRIOR_FALLBACK, GEOMETRY))
    if not needs.any():
        return result._replace(scale_source=jnp.asarray(source), geometry=result.layout)
    rows = (result.ceiling_v, result.floor_v, result.corner_prob)
    batch, width = result.ceiling_v.shape
    height = width // 2  # full panoramas: H = W / 2 (check_panorama)
    arguments = (jnp.asarray(rc), keys, traced_part(config), prior, world, static_part(config))
    if program_cache is None:
        from_prior = _geometry(rows, height, *arguments)
    else:
        from_prior = _saved_geometry(program_cache, (batch, height, width), *arguments)(rows)
    chosen = jax.tree.map(
        lambda a, b: jnp.where(jnp.reshape(needs, needs.shape + (1,) * (a.ndim - 1)), a, b), from_prior, result.layout
    )
    chosen = _flag_scale_conflicts(chosen, result.layout, prior, config.max_scale_conflict)
    return Reconstruction(
        chosen, result.ceiling_v, result.floor_v, result.corner_prob, jnp.asarray(source), result.layout
    )


def _flag_scale_conflicts(
    layout: Layout,
    geometry: Layout,
    prior: HeightPrior,
    max_scale_conflict: Float[ArrayLike, ""],
) -> Layout:
    """``layout`` with ``SCALE_CONFLICT`` where an ``OK`` layout took its scale from ``prior`` because its
    ``geometry`` was ``UNCERTAIN_SCALE`` (only a non-central one can be: a central one is ``NO_SCALE``), and that
    geometry's height lies more than ``max_scale_conflict`` standard deviations from the prior's
    (:func:`~ncjax.pipeline.prior.scale_conflict`).

    Args:
        layout: the layouts written, B leading.
        geometry: the layouts with the scale each panorama's geometry measured, B leading.
        prior: the height prior (a scalar value or one per panorama).
        max_scale_conflict: the flag's threshold (``PipelineConfig.max_scale_conflict``).

    Returns:
        ``layout`` with those panoramas' status ``SCALE_CONFLICT`` and ``ok`` false; the rest unchanged.
    """
    prior = jax.tree.map(lambda x: jnp.broadcast_to(x, geometry.status.shape), prior)
    conflict = jax.vmap(scale_conflict)(geometry, prior)
    flagged = (
        (geometry.status == LayoutStatus.UNCERTAIN_SCALE)
        & (layout.status == LayoutStatus.OK)
        & (conflict > max_scale_conflict)
    )
    return dataclasses.replace(
        layout, status=jnp.where(flagged, LayoutStatus.SCALE_CONFLICT, layout.status), ok=layout.ok & ~flagged
    )


def _network(model: HorizonNet | ModelWeights | str | os.PathLike | None) -> HorizonNet:
    """The :class:`~ncjax.HorizonNet` that ``model`` is, holds or names (None: the shipped one), in eval mode."""
    if model is None:
        model = default_model()
    elif isinstance(model, ModelWeights):
        model = model_from_weights(model)
    elif not isinstance(model, HorizonNet):
        model = load_model(model)
    model.eval()
    return model


def check_panorama(images: np.ndarray) -> None:
    """Raise ValueError unless ``images`` is RGB uint8 (H, W, 3) or (B, H, W, 3) of a full panorama."""
    if images.dtype != np.uint8 or images.ndim not in (3, 4) or images.shape[-1] != 3:
        raise ValueError(
            f"expected an RGB uint8 image (H, W, 3) or batch (B, H, W, 3), got {images.dtype}{images.shape}"
        )
    size_error = panorama_size_error(images.shape[-2], images.shape[-3])
    if size_error:
        raise ValueError(size_error)


def reconstruct_batch(
    images: Shaped[np.ndarray, "B H W 3"],
    rc: Float[ArrayLike, " B"],
    world: str = DEFAULT_WORLD,
    *,
    model: HorizonNet | ModelWeights | str | os.PathLike | None = None,
    config: PipelineConfig = NETWORK_PIPELINE_CONFIG,
    key: PRNGKeyArray | Key[Array, " B"] | UInt32[Array, "B 2"] | None = None,
    views: int = DEFAULT_VIEWS,
    edge_snap: EdgeSnap | None = EdgeSnap(),
    prior: HeightPrior | None = None,
    program_cache: str | os.PathLike | None = None,
) -> Reconstruction:
    """Metric layouts of a batch of panoramas of one size, each with its own radius.

    Args:
        images: RGB uint8 (B, H, W, 3), W = 2 H.
        rc: (B,) radius of each panorama's circle of optical centres, metres.
        world: static: "manhattan", "atlanta" or "auto".
        model: a :class:`~ncjax.HorizonNet`, its :class:`~ncjax.network.checkpoint.ModelWeights`, or the
            name of a shipped model or a model file (:func:`~ncjax.load_model`'s argument; default: the shipped
            model). With ``program_cache`` a named model's weights are only read (no network is built once its
            program is saved); without it, a named model is loaded at every call: load it once with
            :func:`~ncjax.load_model` to call often.
        config: :class:`~ncjax.PipelineConfig`, thresholds traced, the rest static (default:
            :data:`NETWORK_PIPELINE_CONFIG`, the pipeline's defaults with the corner and occlusion settings for
            the network's output).
        key: RANSAC key (default ``jax.random.key(0)``; typed or raw): one key, split over the batch, or one
            key per image (shape (B,)): an image's RANSAC samples then do not depend on the batch it is in.
        views: static, rolled and mirrored views the network's output is
            averaged over (1 or even, :func:`ncjax.predict_boundaries`).
        edge_snap: static; how the network's rows are moved onto the image's
            edges before the geometry (:func:`~ncjax.network.edges.snap_to_edges`);
            None keeps the network's rows.
        prior: a :class:`~ncjax.HeightPrior` (value scalar or (B,)): the scale of the
            central panoramas (``rc = 0``), and of the non-central ones whose geometry
            fails with one of :data:`SCALE_FAILURES`. None: metric scale from the geometry only.
        program_cache: a folder where the traced programs are kept (:mod:`ncjax.programs`): a later
            process with the same settings and shapes skips the tracing (about 10 s on 2 CPU
            cores; with XLA's persistent compilation cache the compiler too). None: traced in
            each process, as any jitted function.

    Returns:
        :class:`Reconstruction` (check ``layout.ok`` per image).

    Raises:
        ValueError: bad image array, world, rc (negative or not finite; rc = 0
            without a prior is accepted and gives ``LayoutStatus.NO_SCALE``) or prior, or a model file that is
            not an ncjax model.
        FileNotFoundError: the model named is neither a file nor a shipped model, or no model given and the
            shipped weights are missing.
    """
    images = np.asarray(images)
    check_panorama(images)
    if images.ndim != 4:
        raise ValueError(f"reconstruct_batch takes a batch (B, H, W, 3), got {images.shape}; use reconstruct")
    if world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {world!r}")
    check_views(views)
    rc = np.broadcast_to(np.asarray(rc, np.float32), images.shape[:1])
    if not np.all(np.isfinite(rc)) or np.any(rc < 0):
        raise ValueError(f"rc must be finite radii >= 0 in metres, got {rc}")
    if prior is not None:
        if np.ndim(prior.value) not in (0, 1) or np.size(prior.value) not in (1, images.shape[0]):
            raise ValueError(f"the prior's value must be a scalar or one per image ({images.shape[0]})")
        prior = jax.tree.map(lambda x: jnp.broadcast_to(x, rc.shape), prior)
    keys = panorama_keys(jax.random.key(0) if key is None else key, images.shape[:1])
    central = prior is not None and not np.any(rc > 0)
    arguments = (jnp.asarray(images), jnp.asarray(rc), keys, traced_part(config), prior if central else None)
    settings = (world, static_part(config), views, edge_snap)
    if program_cache is None:
        result = _reconstruct(_network(model), *arguments, *settings)
    else:
        weights = model_weights(DEFAULT_MODEL_PATH if model is None else model)
        result = _reconstruct_saved(program_cache, weights, *arguments, *settings)
    if prior is None or central:
        return result
    return _with_prior_fallback(result, rc, prior, keys, world, config, program_cache)


def reconstruct(
    image: Shaped[np.ndarray, "H W 3"],
    cam: NonCentralPanorama,
    world: str = DEFAULT_WORLD,
    *,
    model: HorizonNet | ModelWeights | str | os.PathLike | None = None,
    config: PipelineConfig = NETWORK_PIPELINE_CONFIG,
    key: PRNGKeyArray | None = None,
    views: int = DEFAULT_VIEWS,
    edge_snap: EdgeSnap | None = EdgeSnap(),
    prior: HeightPrior | None = None,
    program_cache: str | os.PathLike | None = None,
) -> Layout:
    """Metric room layout of one RGB panorama: network, then geometry (paper Fig. pipeline).

    Args:
        image: RGB uint8 (H, W, 3), a full panorama (W = 2 H).
        cam: its camera; ``cam.width`` and ``cam.height`` must be the image's.
        world: "manhattan", "atlanta" or "auto".
        model: a :class:`~ncjax.HorizonNet`, or a shipped model's name or a model file (default: the shipped
            model; see :func:`reconstruct_batch`).
        config: :class:`~ncjax.PipelineConfig` (default: :data:`NETWORK_PIPELINE_CONFIG`).
        key: RANSAC key (default ``jax.random.key(0)``).
        views: rolled and mirrored views the network averages (1 or even).
        edge_snap: rows snapped to the image's edges (None: the network's rows).
        prior: a :class:`~ncjax.HeightPrior` for the scale (needed when ``cam.rc`` is 0; see
            :func:`reconstruct_batch`).
        program_cache: a folder that keeps the traced programs for later processes (see
            :func:`reconstruct_batch`).

    Returns:
        An unbatched :class:`~ncjax.Layout`; check ``ok`` / ``status``.
    """
    image = np.asarray(image)
    check_panorama(image)
    if image.ndim != 3:
        raise ValueError(f"reconstruct takes one image (H, W, 3), got {image.shape}; use reconstruct_batch")
    if (cam.width, cam.height) != image.shape[1::-1]:
        raise ValueError(f"the camera is {cam.width} x {cam.height} but the image {image.shape[1]} x {image.shape[0]}")
    result = reconstruct_batch(
        image[None],
        jnp.reshape(cam.rc, (1,)),
        world,
        model=model,
        config=config,
        key=key,
        views=views,
        edge_snap=edge_snap,
        prior=prior,
        program_cache=program_cache,
    )
    return jax.tree.map(lambda x: x[0], result.layout)
