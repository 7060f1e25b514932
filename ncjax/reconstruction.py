"""``ncjax.reconstruction``: panorama -> Non-central HorizonNet -> geometric pipeline -> metric Layout.

The two blocks of the paper's Fig. pipeline in ONE jitted function: the image
is resized to the network's input size, the network's per-column outputs are
brought back to the image's columns and rows (:func:`~ncjax.network.model.prediction_to_rows`)
and snapped to the full image's edges (:func:`~ncjax.network.edges.snap_to_edges`), and the
geometric pipeline (:func:`~ncjax.pipeline.run.fit_walls`, then :func:`~ncjax.pipeline.run.finish`)
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
from .pipeline.batch import panorama_keys
from .pipeline.config import (
    DEFAULT_WORLD,
    WORLDS,
    ChecksConfig,
    CornerConfig,
    FloorCheckConfig,
    OcclusionConfig,
    PipelineConfig,
    PriorConfig,
    UncertaintyConfig,
)
from .pipeline.prior import HeightPrior, flag_scale_conflicts
from .pipeline.run import FittedWalls, finish, fit_walls
from .pipeline.types import Layout, LayoutStatus, Rows
from .programs import call_saved, load_saved, result_like
from .solvers.ransac import RansacConfig

# The pipeline's settings for the shipped network's rows, chosen on tuning renders, never the test renders (the
# figures behind each value: experiments/RESULTS.md, "The network configuration, chosen on the tuning renders" and the
# sections it points to): one corner peak per lobe
# (threshold 0.4, +-4 columns), occlusion jumps of 8 px beside corners where two walls' edges mix, floor rows more than
# 2 px off their ceiling's replaced (step 0), UNCERTAIN_SCALE beyond 15% of the room height, LOW_CONFIDENCE below 60%
# of the rows explained, SCALE_CONFLICT beyond 3 sigmas from a height prior, and the covariances' share of the errors
# the fit absorbs (experiments/calibrate_uncertainty.py). RANSAC assumes half of a wall's rows may be outliers (69
# random hypotheses besides the 16 deterministic ones): a photograph's rows follow furniture and doorways for long
# stretches, and more hypotheses make the answer depend less on the key (experiments/key_stability.py).
NETWORK_PIPELINE_CONFIG = PipelineConfig(
    floor_check=FloorCheckConfig(threshold=2.0),
    ransac=RansacConfig(outlier_rate=0.5),
    corners=CornerConfig(threshold=0.4, nms_radius=4.0),
    occlusion=OcclusionConfig(threshold=8.0),
    uncertainty=UncertaintyConfig(wall_offset_ratio=2.0, wall_offset_noise=1.0, corner_column_noise=2.0),
    checks=ChecksConfig(max_height_uncertainty=0.15, min_explained_fraction=0.6),
    prior=PriorConfig(max_scale_conflict=3.0),
)


# The saved geometry programs (ncjax.programs, the CLI's) compile with XLA's cheaper backend settings: the geometry runs
# in tens of milliseconds a panorama either way, and its compilation is most of a first run's (experiments/RESULTS.md,
# "Speed"). The network keeps the full optimisation: it is most of a run's time.
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


class _Geometry(NamedTuple):
    """What the geometry of a batch takes besides its rows (B leading): each panorama's radius, RANSAC key and
    height prior (or None), and the pipeline's configuration."""

    rc: Float[Array, " B"]
    keys: Key[Array, " B"]
    prior: HeightPrior | None
    config: PipelineConfig


def _fitted_walls(rows: Rows, image_height: int, arguments: _Geometry, world: str) -> FittedWalls:
    """Steps 0-4 of the geometric pipeline (:func:`~ncjax.pipeline.run.fit_walls`) on each panorama's rows
    (B leading), with its own radius, key and prior."""
    rc, keys, prior, config = arguments

    def one(panorama_rows, radius, one_prior, key):
        cam = NonCentralPanorama(panorama_rows.ceiling.shape[-1], image_height, rc=radius)
        return fit_walls(panorama_rows, cam, one_prior, key, config, world)

    return jax.vmap(one)(rows, rc, prior, keys)


def _finished(walls: FittedWalls, prior: HeightPrior | None, config: PipelineConfig, world: str) -> Layout:
    """Steps 5-6 (:func:`~ncjax.pipeline.run.finish`) of :func:`_fitted_walls`' walls."""
    return jax.vmap(lambda w, p: finish(w, p, config, world))(walls, prior)


def _reconstruction(layouts: Layout, rows: Rows, prior: HeightPrior | None) -> Reconstruction:
    """A batch's layouts and rows, each scale from the geometry or, with a prior, from the prior."""
    source = jnp.full(rows.ceiling.shape[:1], GEOMETRY if prior is None else PRIOR)
    return Reconstruction(layouts, rows.ceiling, rows.floor, rows.corner_prob, source)


def _geometry_body(rows: Rows, image_height: int, arguments: _Geometry, world: str) -> Layout:
    """The geometric pipeline (steps 0-6) on a batch's rows: :func:`_fitted_walls`, then :func:`_finished`."""
    walls = _fitted_walls(rows, image_height, arguments, world)
    return _finished(walls, arguments.prior, arguments.config, world)


_geometry = jax.jit(_geometry_body, static_argnames=("image_height", "world"))


class _Network(NamedTuple):
    """The network's static settings: how many views it averages, and how its rows are snapped to edges."""

    views: int
    edge_snap: EdgeSnap | None


def _reconstruct_body(
    model: HorizonNet,
    images: Shaped[Array, "B H W 3"],
    arguments: _Geometry,
    world: str,
    network: _Network,
) -> Reconstruction:
    rows = Rows(*image_boundaries(model, images, network.views, network.edge_snap))
    layouts = _geometry_body(rows, images.shape[1], arguments, world)
    return _reconstruction(layouts, rows, arguments.prior)


_reconstruct = nnx.jit(_reconstruct_body, static_argnames=("world", "network"))


def _saved_geometry(
    directory: str | os.PathLike, image_shape: tuple[int, int, int], arguments, world: str
) -> Callable[[Rows], Layout]:
    """:func:`_geometry_body` for a batch of ``image_shape`` (B, H, W) through two programs saved in ``directory``
    (:mod:`ncjax.programs`): its steps 0-4 and 5-6, loaded in two threads from this call on, while the caller
    goes on (XLA loads a compiled program on one core, and these are most of the loading). Returns the function
    of the rows (B leading) that runs them.
    """
    rc, keys, prior, config = arguments
    config = jax.tree.map(jnp.asarray, config)  # a saved program's arguments are arrays: the thresholds as scalars
    batch, image_height, width = image_shape
    walls_structure = []
    impl = jax.random.key_impl(keys)

    def walls(rows, rc, key_data, prior, config):
        key = jax.random.wrap_key_data(key_data, impl=impl)
        leaves, structure = jax.tree.flatten(
            _fitted_walls(rows, image_height, _Geometry(rc, key, prior, config), world)
        )
        walls_structure.append(structure)
        return leaves  # a saved program returns plain containers (a pickled result tree)

    def layouts(walls_leaves, prior, config):
        if not walls_structure:  # the walls' program was loaded, not traced: trace its shapes alone
            jax.eval_shape(walls, rows_like, *walls_arguments)
        layout = _finished(jax.tree.unflatten(walls_structure[0], walls_leaves), prior, config, world)
        return {field.name: getattr(layout, field.name) for field in dataclasses.fields(Layout)}

    rows_like = jax.eval_shape(lambda: Rows(*(jnp.zeros((batch, width), jnp.float32),) * 3))
    walls_arguments = (rc, jax.random.key_data(keys), prior, config)
    settings = (image_height, str(impl), world)
    walls_key, layouts_key = repr(("walls", *settings)), repr(("layouts", *settings))
    walls_like = result_like(directory, walls_key, walls, rows_like, *walls_arguments)
    cheap = {"compiler_options": GEOMETRY_COMPILER_OPTIONS}
    pool = concurrent.futures.ThreadPoolExecutor(2)
    walls_program = pool.submit(load_saved, directory, walls_key, walls, rows_like, *walls_arguments, **cheap)
    layouts_program = pool.submit(load_saved, directory, layouts_key, layouts, walls_like, prior, config, **cheap)
    pool.shutdown(wait=False)  # the two loads go on; the pool takes no more

    def run(rows):
        walls_leaves = walls_program.result()(rows, *walls_arguments)
        return Layout(**layouts_program.result()(walls_leaves, prior, config))

    return run


def _reconstruct_saved(
    directory, weights: ModelWeights, images, arguments, world: str, network: _Network
) -> Reconstruction:
    """:func:`_reconstruct` through three programs saved in ``directory`` (:mod:`ncjax.programs`): the
    network's and the geometry's two (:func:`_saved_geometry`, loading while the network's loads and runs).
    A later process skips the tracing, and building the network too. The weights are arguments, the
    architecture part of the key; the network's program serves every world and pipeline setting.
    """
    geometry = _saved_geometry(directory, images.shape[:3], arguments, world)
    views, edge_snap = network

    def boundaries(tensors, images):
        return image_boundaries(model_from_weights(weights._replace(tensors=tensors)), images, views, edge_snap)

    network_key = repr(("network", weights.config, views, edge_snap))
    saved_rows = call_saved(directory, network_key, boundaries, weights.tensors, images)
    rows = Rows(*(row.astype(jnp.float32) for row in saved_rows))
    return _reconstruction(geometry(rows), rows, arguments.prior)


def _with_prior_fallback(
    result: Reconstruction,
    arguments: _Geometry,
    world: str,
    program_cache: str | os.PathLike | None = None,
) -> Reconstruction:
    """``result`` (the geometry's) with the prior's layout where ``rc = 0`` or the status is a :data:`SCALE_FAILURES`.

    ``arguments``: the batch's ``rc`` (numpy), keys, the prior to fall back on and the configuration. The prior's
    pipeline runs on the same rows and RANSAC keys, for the whole batch (one program per batch size), and only
    when some panorama needs it: the central route's programs (saved in ``program_cache`` if given, as
    :func:`_saved_geometry`), flagged where the two scales conflict
    (:func:`~ncjax.pipeline.prior.flag_scale_conflicts`).
    """
    rc, keys, prior, config = arguments
    status = np.asarray(result.layout.status)
    needs = (rc == 0) | np.isin(status, np.asarray(SCALE_FAILURES))
    source = np.where(rc == 0, PRIOR, np.where(needs, PRIOR_FALLBACK, GEOMETRY))
    if not needs.any():
        return result._replace(scale_source=jnp.asarray(source), geometry=result.layout)
    rows = Rows(result.ceiling_v, result.floor_v, result.corner_prob)
    batch, width = result.ceiling_v.shape
    height = width // 2  # full panoramas: H = W / 2 (check_panorama)
    if program_cache is None:
        from_prior = _geometry(rows, height, _Geometry(jnp.asarray(rc), keys, prior, config), world)
    else:
        geometry = _Geometry(jnp.asarray(rc), keys, prior, config)
        from_prior = _saved_geometry(program_cache, (batch, height, width), geometry, world)(rows)
    chosen = jax.tree.map(
        lambda a, b: jnp.where(jnp.reshape(needs, needs.shape + (1,) * (a.ndim - 1)), a, b), from_prior, result.layout
    )
    chosen = flag_scale_conflicts(chosen, result.layout, prior, config.prior.max_scale_conflict)
    return Reconstruction(
        chosen, result.ceiling_v, result.floor_v, result.corner_prob, jnp.asarray(source), result.layout
    )


def _model_of(model: HorizonNet | ModelWeights | str | os.PathLike | None) -> HorizonNet:
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
    arguments = _Geometry(jnp.asarray(rc), keys, prior if central else None, config)
    network = _Network(views, edge_snap)
    if program_cache is None:
        result = _reconstruct(_model_of(model), jnp.asarray(images), arguments, world, network)
    else:
        weights = model_weights(DEFAULT_MODEL_PATH if model is None else model)
        result = _reconstruct_saved(program_cache, weights, jnp.asarray(images), arguments, world, network)
    if prior is None or central:
        return result
    return _with_prior_fallback(result, _Geometry(rc, keys, prior, config), world, program_cache)


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
