"""``ncjax.reconstruction``: panorama -> Non-central HorizonNet -> geometric pipeline -> metric Layout.

The two blocks of the paper's Fig. pipeline as three programs: the network (each image
is resized to the network's input size, the network's per-column outputs are
brought back to the image's columns and rows, :func:`~ncjax.network.model.prediction_to_rows`,
and snapped to the full image's edges, :func:`~ncjax.network.edges.snap_to_edges`), and the
geometric pipeline's two halves (:func:`~ncjax.pipeline.run.fit_walls`, then :func:`~ncjax.pipeline.run.finish`),
on chunks of a fixed number of panoramas, each with its own camera radius. The network runs image by image and
the geometry on padded chunks, so that every batch size, and central and non-central panoramas alike, run the
same programs; by default they are saved in the user's cache (:mod:`ncjax.programs`), and a later process loads
them instead of tracing and compiling them again.

With a height prior (:class:`~ncjax.pipeline.prior.HeightPrior`) the scale of a
central panorama (``rc = 0``) comes from it; a non-central one keeps the scale
its geometry measures and falls back to the prior only where the geometry
cannot fix it (:data:`SCALE_FAILURES`); :class:`Reconstruction` says which
(:data:`SCALE_SOURCES`) and keeps the geometry's own layout for comparison.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import dataclasses
import functools
import os
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Key, PRNGKeyArray, Shaped, UInt32

from .geometry.camera import NonCentralPanorama
from .geometry.gravity import panorama_size_error
from .network.config import DEFAULT_VIEWS, AdaptConfig, Network, check_views
from .network.edges import EdgeSnap
from .network.flatness import row_flatness
from .network.weights import DEFAULT_MODEL_PATH, ModelWeights, read_weights
from .pipeline.batch import panorama_keys
from .pipeline.config import (
    DEFAULT_WORLD,
    WORLDS,
    ChecksConfig,
    CornerConfig,
    FloorCheckConfig,
    OcclusionConfig,
    PipelineConfig,
    PlanConfig,
    PriorConfig,
    UncertaintyConfig,
)
from .pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior, flag_scale_conflicts
from .pipeline.run import FittedWalls, finish, fit_walls
from .pipeline.types import Layout, LayoutStatus, Rows
from .programs import compiled_before, load_saved, program_path, result_like, user_program_directory
from .solvers.ransac import RansacConfig

# The pipeline's settings for the shipped network's rows, chosen on tuning renders, never the test renders (the
# figures behind each value: experiments/RESULTS.md, "The network configuration, chosen on the tuning renders" and the
# sections it points to): one corner peak per lobe
# (threshold 0.4, +-4 columns), occlusion jumps of 8 px beside corners where two walls' edges mix, floor rows more than
# 2 px off their ceiling's replaced (step 0), UNCERTAIN_SCALE beyond 15% of the room height, LOW_CONFIDENCE below 60%
# of the rows explained, SCALE_CONFLICT beyond 3 sigmas from a height prior, and the covariances' share of the errors
# the fit absorbs (experiments/calibrate_uncertainty.py). RANSAC's samples are a fixed design, one sample from every
# 3 of 7 stretches of a wall (35 besides the 16 windows), not random ones: a photograph's rows leave a wall for whole
# stretches (furniture, doorways), some sample then lies on the clean ones, and the layout no longer depends on the
# key; on the test renders it is as accurate as 69 random samples (experiments/key_stability.py).
NETWORK_PIPELINE_CONFIG = PipelineConfig(
    floor_check=FloorCheckConfig(threshold=2.0),
    ransac=RansacConfig(strata=7),
    corners=CornerConfig(threshold=0.4, nms_radius=4.0),
    occlusion=OcclusionConfig(threshold=8.0),
    uncertainty=UncertaintyConfig(wall_offset_ratio=2.0, wall_offset_noise=1.0, corner_column_noise=2.0),
    checks=ChecksConfig(max_height_uncertainty=0.15, min_explained_fraction=0.6, max_corner_range_ratio=3.0),
    plan=PlanConfig(fallback=True),
    prior=PriorConfig(max_scale_conflict=3.0),
)


# The saved geometry programs (ncjax.programs, the CLI's) compile with XLA's CPU emitters of before its fusion emitters,
# whose compilation takes half as long for code as fast (experiments/RESULTS.md, "Speed"). A process that finds them
# compiled by none before it compiles them for itself with the cheap settings as well (XLA's backend at level 0: half
# the compilation again, code half as fast), and the optimised ones in the background for the processes after it.
GEOMETRY_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}
CHEAP_GEOMETRY_COMPILER_OPTIONS = GEOMETRY_COMPILER_OPTIONS | {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
}


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
        adapted: (B,) whether the rows are those of the network adapted to the image (``adapt``; all False without
            it); None in a result built otherwise.
    """

    layout: Layout
    ceiling_v: Float[Array, "B W"]
    floor_v: Float[Array, "B W"]
    corner_prob: Float[Array, "B W"]
    scale_source: Int[Array, " B"]
    geometry: Layout | None = None
    adapted: Bool[Array, " B"] | None = None


# Images per call of the geometry's programs: a batch is laid out in chunks of this many, the last one padded with
# copies of its last image, so that every batch size runs the same programs. The network runs image by image (its
# views are its batch: on a CPU a larger batch is no faster a panorama). One: on 2 CPU cores a chunk of 4 lays out a
# panorama in 0.03 s against 0.066 s alone (a folder's images 7% faster, their files included), but a process's
# first chunk takes 0.25 s against 0.17 s, and a lone image (a CLI run's first) is padded with 3 copies.
DEFAULT_BATCH_SIZE = 1


class _Chunk(NamedTuple):
    """What the geometry of a chunk takes besides its rows, on the host (B leading): each panorama's radius, the
    data of its RANSAC key and the value of its height prior (a placeholder on the geometry's route)."""

    rc: Float[np.ndarray, " B"]
    key_data: UInt32[np.ndarray, "B 2"]
    prior_value: Float[np.ndarray, " B"]


class _Route(NamedTuple):
    """The static settings of the geometry's programs: the rows' height, the RANSAC keys' implementation, the
    world, and the height prior's kind, or None for the rows' own scale."""

    image_height: int
    key_impl: str
    world: str
    prior_kind: str | None


def _fitted_walls(rows: Rows, chunk: _Chunk, config: PipelineConfig, route: _Route) -> FittedWalls:
    """Steps 0-4 of the geometric pipeline (:func:`~ncjax.pipeline.run.fit_walls`) on each panorama's rows
    (B leading), with its own radius and key, and its prior on a prior's route."""
    key = jax.random.wrap_key_data(chunk.key_data, impl=route.key_impl)

    def one(panorama_rows, radius, prior_value, panorama_key):
        cam = NonCentralPanorama(panorama_rows.ceiling.shape[-1], route.image_height, rc=radius)
        prior = None if route.prior_kind is None else HeightPrior(route.prior_kind, prior_value)
        return fit_walls(panorama_rows, cam, prior, panorama_key, config, route.world)

    return jax.vmap(one)(rows, chunk.rc, chunk.prior_value, key)


def _finished(walls: FittedWalls, prior_value: Float[Array, " B"], config: PipelineConfig, route: _Route) -> Layout:
    """Steps 5-6 (:func:`~ncjax.pipeline.run.finish`) of :func:`_fitted_walls`' walls, on the same route."""

    def one(panorama_walls, value):
        prior = None if route.prior_kind is None else HeightPrior(route.prior_kind, value)
        return finish(panorama_walls, prior, config, route.world)

    return jax.vmap(one)(walls, prior_value)


def _geometry_body(rows: Rows, chunk: _Chunk, config: PipelineConfig, route: _Route) -> Layout:
    """The geometric pipeline (steps 0-6) on a chunk's rows: :func:`_fitted_walls`, then :func:`_finished`."""
    return _finished(_fitted_walls(rows, chunk, config, route), chunk.prior_value, config, route)


_geometry = jax.jit(_geometry_body, static_argnames=("route",))


class _Network(NamedTuple):
    """The network's static settings: how many views it averages, and how its rows are snapped to edges."""

    views: int
    edge_snap: EdgeSnap | None


@functools.cache
def _rows() -> Callable[..., Rows]:
    """The network's rows of a batch, jitted (Flax's ``nnx.jit``; Flax imported on the first call)."""
    from flax import nnx

    from .network.predict import image_boundaries

    def rows(model: Network, images: Shaped[Array, "B H W 3"], network: _Network) -> Rows:
        return Rows(*image_boundaries(model, images, *network))

    return nnx.jit(rows, static_argnames=("network",))


class _SavedGeometry:
    """:func:`_geometry_body` for chunks of ``shape`` (B, W) through two programs per route saved in ``directory``
    (:mod:`ncjax.programs`): its steps 0-4 and 5-6. :meth:`load` loads (or compiles) a route's two in two
    threads while the caller goes on (XLA loads a compiled program on one core, and these are most of the
    loading); calling runs them. A route's programs are separate, so that a process loads only the route it
    runs; :meth:`prepare_later_processes` compiles, in the background, the optimised programs of the routes this
    machine never compiled so, so that a later process finds them in XLA's cache.
    """

    def __init__(self, directory, shape: tuple[int, int], config: PipelineConfig, route: _Route):
        batch, width = shape
        self.directory, self.route = directory, route
        self.config = jax.tree.map(np.asarray, config)  # a saved program's thresholds are arguments
        self.rows_like = jax.eval_shape(lambda: Rows(*(jnp.zeros((batch, width), jnp.float32),) * 3))
        self.chunk_like = _Chunk(
            jax.ShapeDtypeStruct((batch,), jnp.float32),
            jax.ShapeDtypeStruct((batch, 2), jnp.uint32),
            jax.ShapeDtypeStruct((batch,), jnp.float32),
        )
        self.programs: dict[str | None, tuple[concurrent.futures.Future, concurrent.futures.Future]] = {}

    def _programs(self, prior_kind: str | None) -> list[tuple[str, Callable, tuple]]:
        """The route's two programs: (key, function, arguments) of its walls and of its layouts."""
        route = self.route._replace(prior_kind=prior_kind)
        walls_structure = []

        def walls(rows, chunk, config):
            leaves, structure = jax.tree.flatten(_fitted_walls(rows, _Chunk(*chunk), config, route))
            walls_structure.append(structure)
            return leaves  # a saved program returns plain containers (a pickled result tree)

        def layouts(walls_leaves, prior_value, config):
            if not walls_structure:  # the walls' program was loaded, not traced: trace its shapes alone
                jax.eval_shape(walls, self.rows_like, tuple(self.chunk_like), self.config)
            layout = _finished(jax.tree.unflatten(walls_structure[0], walls_leaves), prior_value, config, route)
            return {field.name: getattr(layout, field.name) for field in dataclasses.fields(Layout)}

        walls_key, layouts_key = repr(("walls", *route)), repr(("layouts", *route))
        walls_arguments = (self.rows_like, tuple(self.chunk_like), self.config)
        walls_like = result_like(self.directory, walls_key, walls, *walls_arguments)
        layouts_arguments = (walls_like, self.chunk_like.prior_value, self.config)
        return [(walls_key, walls, walls_arguments), (layouts_key, layouts, layouts_arguments)]

    def _optimised_before(self, key: str, arguments: tuple) -> bool:
        return compiled_before(self.directory, key, *arguments, compiler_options=GEOMETRY_COMPILER_OPTIONS)

    def load(self, prior_kind: str | None) -> None:
        """Start loading the programs of the route of ``prior_kind`` (None: the rows' own scale), once: each
        optimised where a process compiled it so before, else compiled with the cheap settings."""
        if prior_kind in self.programs:
            return
        pool = concurrent.futures.ThreadPoolExecutor(2)
        futures = []
        for key, function, arguments in self._programs(prior_kind):
            optimised = self._optimised_before(key, arguments)
            options = GEOMETRY_COMPILER_OPTIONS if optimised else CHEAP_GEOMETRY_COMPILER_OPTIONS
            futures.append(pool.submit(load_saved, self.directory, key, function, *arguments, compiler_options=options))
        pool.shutdown(wait=False)  # the two loads go on; the pool takes no more
        self.programs[prior_kind] = tuple(futures)

    def __call__(self, rows: Rows, chunk: _Chunk, prior_kind: str | None) -> Layout:
        self.load(prior_kind)
        walls_program, layouts_program = self.programs[prior_kind]
        # the walls run while the layouts' program may still be loading (XLA runs them asynchronously)
        walls_leaves = walls_program.result()(rows, tuple(chunk), self.config)
        return Layout(**layouts_program.result()(walls_leaves, chunk.prior_value, self.config))

    def prepare_later_processes(self, prior_kinds: tuple[str | None, ...]) -> None:
        """Compile in the background, at the least CPU priority, the optimised programs of the routes of
        ``prior_kinds`` that no process compiled so (none without XLA's persistent cache, where a compilation would
        not outlive the process). Inside :func:`background_compilations_deferred`, they start at its end. The
        process waits for them before it exits (:func:`finish_background_compilations`)."""
        if not jax.config.jax_compilation_cache_dir:
            return
        for prior_kind in prior_kinds:
            for key, function, arguments in self._programs(prior_kind):
                name = program_path(self.directory, key, arguments)
                if name in _STARTED or self._optimised_before(key, arguments):
                    continue
                _STARTED.add(name)
                optimised = {"compiler_options": GEOMETRY_COMPILER_OPTIONS}
                _start_later(functools.partial(load_saved, self.directory, key, function, *arguments, **optimised))


# The compilations :meth:`_SavedGeometry.prepare_later_processes` started, one thread each at the least CPU priority:
# Python waits for them before it exits, a process that ends with ``os._exit`` (the CLI) must call
# :func:`finish_background_compilations` first. _STARTED: the programs they compile, each started once a process.
_BACKGROUND: list[concurrent.futures.Future] = []
_STARTED: set[os.PathLike] = set()
# Inside background_compilations_deferred: the compilations waiting for its end.
_DEFERRED: list[Callable[[], object]] | None = None


def finish_background_compilations() -> bool:
    """Wait for the programs this process compiles in the background for later processes; returns whether any
    was still compiling (their errors are dropped: a later process only compiles them again)."""
    pending = [future for future in _BACKGROUND if not future.done()]
    concurrent.futures.wait(_BACKGROUND)
    _BACKGROUND.clear()
    return bool(pending)


def _start_later(compile_later: Callable[[], object]) -> None:
    """Start a compilation for later processes in the background, or at the end of the deferred block it is in."""
    if _DEFERRED is None:
        _BACKGROUND.append(_LATER_POOL.submit(compile_later))
    else:
        _DEFERRED.append(compile_later)


@contextlib.contextmanager
def background_compilations_deferred():
    """Start the compilations for later processes that :func:`reconstruct_batch` asks for inside the block only
    at its end: ``ncjax reconstruct`` writes its first image's files before they take the CPU (XLA's compiler
    runs part of its work in threads that do not inherit the least priority)."""
    global _DEFERRED
    if _DEFERRED is not None:  # inside another such block, whose end starts them
        yield
        return
    _DEFERRED = []
    try:
        yield
    finally:
        waiting, _DEFERRED = _DEFERRED, None
        for compile_later in waiting:
            _start_later(compile_later)


def _lowest_priority() -> None:
    """Give the calling thread the least CPU priority (Linux: a thread's own nice value; elsewhere nothing)."""
    with contextlib.suppress(AttributeError, OSError):
        os.setpriority(os.PRIO_PROCESS, 0, 19)


# Where the compilations for later processes run: two threads at the least CPU priority.
_LATER_POOL = concurrent.futures.ThreadPoolExecutor(2, initializer=_lowest_priority)


def _saved_rows(directory: str | os.PathLike, weights: ModelWeights, image_shape: tuple, network: _Network):
    """The network's rows of one image of ``image_shape`` (1, H, W, 3) with given tensors (``weights``' or adapted
    ones), ``rows(tensors, image)``, through its program saved in ``directory``. The weights are arguments, the
    architecture part of the key: a later process builds no network."""
    views, edge_snap = network

    def boundaries(tensors, images):  # traced only when no process saved the program (Flax imported then)
        from .network.checkpoint import model_from_weights
        from .network.predict import image_boundaries

        return image_boundaries(model_from_weights(weights._replace(tensors=tensors)), images, views, edge_snap)

    image_like = jax.ShapeDtypeStruct(image_shape, jnp.uint8)
    network_key = repr(("network", weights.config, views, edge_snap))
    program = load_saved(directory, network_key, boundaries, weights.tensors, image_like)
    return lambda tensors, image: Rows(*program(tensors, image))


def _adapted(model: Network, image: Shaped[np.ndarray, "1 H W 3"], adapt: AdaptConfig | None) -> Network:
    """``model``, or its copy fitted to ``image``'s flat floor and ceiling
    (:func:`~ncjax.network.adapt.adapt_to_panorama`)."""
    if adapt is None:
        return model
    from .network.adapt import adapt_to_panorama

    return adapt_to_panorama(model, np.asarray(image[0]), adapt)[0]


def _saved_adaptation(
    directory: str | os.PathLike, weights: ModelWeights, image_shape: tuple, adapt: AdaptConfig
) -> Callable[[np.ndarray], dict]:
    """The tensors of ``weights``' network fitted to one image of ``image_shape`` (1, H, W, 3)
    (:func:`~ncjax.network.adapt.adapt_model`), through its program saved in ``directory``, the weights its
    arguments."""

    def adapted_tensors(tensors, images):  # traced only when no process saved the program (Flax imported then)
        from .network.adapt import adapt_model
        from .network.checkpoint import model_from_weights, model_weights

        model = model_from_weights(weights._replace(tensors=tensors))
        return model_weights(adapt_model(model, images[0], adapt)[0]).tensors

    image_like = jax.ShapeDtypeStruct(image_shape, jnp.uint8)
    program = load_saved(directory, adaptation_key(weights, adapt), adapted_tensors, weights.tensors, image_like)
    return lambda image: program(weights.tensors, image)


def adaptation_key(weights: ModelWeights, adapt: AdaptConfig) -> str:
    """The key of the adaptation's saved program for ``weights``' architecture: its traced settings only."""
    return repr(("adapt", weights.config, adapt.traced()))


def _network_reader(
    model: Network | ModelWeights | str | os.PathLike | None,
    directory: str | os.PathLike | None,
    image_shape: tuple[int, ...],
    network: _Network,
    adapt: AdaptConfig | None,
) -> Callable[[np.ndarray, float], tuple[Rows, bool]]:
    """``rows(image, rc)``: the rows of one image of ``image_shape`` (1, H, W, 3) and radius ``rc`` read by ``model``
    (:func:`reconstruct_batch`'s), and whether they were read again by the network adapted to the image (``adapt``
    given, ``rc`` at most its ``max_rc`` and the rows' flatness loss at least its ``min_loss``). Through the
    programs saved in ``directory`` (the adaptation's, then the network's with the adapted tensors as its
    arguments), or jitted in this process when ``directory`` is None."""
    if directory is None:
        network_model = _model_of(model)

        def read(image, adapted=False):
            return _rows()(_adapted(network_model, image, adapt if adapted else None), image, network=network)

    else:
        weights = _weights_of(DEFAULT_MODEL_PATH if model is None else model)
        rows_with = _saved_rows(directory, weights, image_shape, network)
        # loaded at the first panorama to adapt: a run whose rows are all flat never loads it
        adaptation = functools.cache(lambda: _saved_adaptation(directory, weights, image_shape, adapt))

        def read(image, adapted=False):
            return rows_with(adaptation()(image) if adapted else weights.tensors, image)

    def rows(image, rc):
        first = read(image)
        if adapt is None or rc > np.float32(adapt.max_rc):  # rc is float32: max_rc itself is adapted
            return first, False
        flatness = row_flatness(first.ceiling[0], first.floor[0], image_shape[1], adapt.huber)
        if not float(flatness) >= adapt.min_loss:  # flat enough (or a non-finite loss: nothing to fit)
            return first, False
        return read(image, adapted=True), True

    return rows


def _chunks(count: int, size: int) -> list[np.ndarray]:
    """The indices of each chunk of ``size`` of ``count`` items, the last padded with its last index."""
    return [np.minimum(np.arange(start, start + size), count - 1) for start in range(0, count, size)]


def _on_host(layout: Layout) -> Layout:
    return jax.tree.map(np.asarray, jax.device_get(layout))


def _chunk_layouts(
    rows: Rows,
    chunk: _Chunk,
    geometry: Callable[[Rows, _Chunk, str | None], Layout],
    route: str,
    prior: tuple[str | None, float],
) -> tuple[Layout, Layout | None]:
    """One chunk's layouts (on the host) and, on the fallback route, the geometry's own.

    ``route``: "geometry" (the rows' non-central scale), "prior" (the height prior's scale: a central batch) or
    "fallback" (the geometry's, replaced by the prior's where ``rc = 0`` or the status is a :data:`SCALE_FAILURES`,
    flagged where the two scales conflict: :func:`~ncjax.pipeline.prior.flag_scale_conflicts`; the prior's route
    runs only when some panorama of the chunk needs it). ``prior``: the height prior's kind and conflict threshold.
    """
    kind, max_conflict = prior
    if route != "fallback":
        return _on_host(geometry(rows, chunk, kind if route == "prior" else None)), None
    own = _on_host(geometry(rows, chunk, None))
    needs = _needs_prior(chunk.rc, own.status)
    if not needs.any():
        return own, own
    from_prior = _on_host(geometry(rows, chunk, kind))
    chosen = jax.tree.map(
        lambda a, b: np.where(np.reshape(needs, needs.shape + (1,) * (a.ndim - 1)), a, b), from_prior, own
    )
    on_device = functools.partial(jax.tree.map, jnp.asarray)
    prior = HeightPrior(kind, chunk.prior_value)
    flagged = flag_scale_conflicts(on_device(chosen), on_device(own), prior, max_conflict)
    return _on_host(flagged), own


def _scale_sources(route: str, rc: np.ndarray, own: Layout | None) -> np.ndarray:
    """Each layout's :data:`SCALE_SOURCES` index on ``route`` (:func:`_chunk_layouts`)."""
    if route != "fallback":
        return np.full(rc.shape, GEOMETRY if route == "geometry" else PRIOR)
    needs = _needs_prior(rc, np.asarray(own.status))
    return np.where(rc == 0, PRIOR, np.where(needs, PRIOR_FALLBACK, GEOMETRY))


def _needs_prior(rc: np.ndarray, status: np.ndarray) -> np.ndarray:
    """Where a layout takes its prior's scale beside a non-central one: central, or the geometry's scale failed."""
    return (rc == 0) | np.isin(status, np.asarray(SCALE_FAILURES))


# the default key's panorama key, key_data(panorama_keys(key(0), (1,))), under jax's default PRNG settings: a new
# process skips compiling jax's PRNG for it (a quarter of a second; the key tests check the value)
_DEFAULT_PANORAMA_KEY = np.array([1797259609, 2579123966], np.uint32)
_DEFAULT_KEY_CONFIG = ("threefry2x32", True)


def _image_key_data(key, count: int) -> tuple[UInt32[np.ndarray, "B 2"], str]:
    """Each image's RANSAC key, as its data and the keys' implementation: one key gives every image the key a
    batch of one gets, so that an image's samples depend neither on its batch nor on its place in it; one key
    per image is kept."""
    if key is None and _DEFAULT_KEY_CONFIG == (jax.config.jax_default_prng_impl, jax.config.jax_threefry_partitionable):
        return np.tile(_DEFAULT_PANORAMA_KEY, (count, 1)), _DEFAULT_KEY_CONFIG[0]
    key = jax.random.key(0) if key is None else key
    if not jax.dtypes.issubdtype(jnp.asarray(key).dtype, jax.dtypes.prng_key):
        key = jax.random.wrap_key_data(jnp.asarray(key, jnp.uint32))
    keys = jnp.broadcast_to(panorama_keys(key, (1,)), (count,)) if key.shape == () else panorama_keys(key, (count,))
    return np.asarray(jax.random.key_data(keys)), str(jax.random.key_impl(keys))


def _program_folder(program_cache: str | os.PathLike | bool | None) -> str | os.PathLike | None:
    """The folder of the saved programs ``program_cache`` asks for (True: the user's, XLA's cache switched on
    beside it; None where ``NCJAX_CACHE=off``), or None for none."""
    if program_cache is True:
        return user_program_directory(enable_compilation_cache=True)
    return program_cache or None


def _weights_of(model: Network | ModelWeights | str | os.PathLike) -> ModelWeights:
    """The :class:`~ncjax.network.weights.ModelWeights` that ``model`` is, holds or names (Flax imported only for a
    built network)."""
    if isinstance(model, ModelWeights | str | os.PathLike):
        return read_weights(model)
    from .network.checkpoint import model_weights

    return model_weights(model)


def _model_of(model: Network | ModelWeights | str | os.PathLike | None) -> Network:
    """The :class:`~ncjax.HorizonNet` that ``model`` is, holds or names (None: the shipped one), in eval mode."""
    from .network.checkpoint import load_model, model_from_weights
    from .network.model import HorizonNet
    from .network.predict import default_model

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


def _check_batch_settings(images: np.ndarray, world: str, views: int, batch_size: int, adapt) -> None:
    """Raise :func:`reconstruct_batch`'s one-line errors for its images and settings."""
    check_panorama(images)
    if images.ndim != 4:
        raise ValueError(f"reconstruct_batch takes a batch (B, H, W, 3), got {images.shape}; use reconstruct")
    if world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {world!r}")
    check_views(views)
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if adapt is not None and not isinstance(adapt, AdaptConfig):
        raise TypeError(f"adapt must be an ncjax.network.config.AdaptConfig or None, got {adapt!r}")


def reconstruct_batch(
    images: Shaped[np.ndarray, "B H W 3"],
    rc: Float[ArrayLike, " B"],
    world: str = DEFAULT_WORLD,
    *,
    model: Network | ModelWeights | str | os.PathLike | None = None,
    config: PipelineConfig = NETWORK_PIPELINE_CONFIG,
    key: PRNGKeyArray | Key[Array, " B"] | UInt32[Array, "B 2"] | None = None,
    views: int = DEFAULT_VIEWS,
    edge_snap: EdgeSnap | None = EdgeSnap(),
    prior: HeightPrior | None = None,
    program_cache: str | os.PathLike | bool | None = True,
    batch_size: int = DEFAULT_BATCH_SIZE,
    adapt: AdaptConfig | None = None,
) -> Reconstruction:
    """Metric layouts of a batch of panoramas of one size, each with its own radius.

    The network reads each image (its views are its batch), then the geometry lays out chunks of ``batch_size``
    rows; both run as programs saved in the user's cache by default, so that a later process starts in seconds.

    Args:
        images: RGB uint8 (B, H, W, 3), W = 2 H.
        rc: (B,) radius of each panorama's circle of optical centres, metres.
        world: static: "manhattan", "atlanta" or "auto".
        model: a :class:`~ncjax.HorizonNet`, its :class:`~ncjax.network.weights.ModelWeights`, or the
            name of a shipped model or a model file (:func:`~ncjax.load_model`'s argument; default: the shipped
            model). With ``program_cache`` a named model's weights are only read (no network is built once its
            program is saved); without it, a named model is loaded at every call: load it once with
            :func:`~ncjax.load_model` to call often.
        config: :class:`~ncjax.PipelineConfig`, thresholds traced, the rest static (default:
            :data:`NETWORK_PIPELINE_CONFIG`, the pipeline's defaults with the corner and occlusion settings for
            the network's output).
        key: RANSAC key (default ``jax.random.key(0)``; typed or raw): one key, which every image gets as a batch
            of one would, or one key per image (shape (B,)). An image's layout depends neither on its batch nor
            on its place in it. The default configuration's RANSAC samples do not depend on the key at all
            (:attr:`~ncjax.solvers.ransac.RansacConfig.strata`).
        views: static, rolled and mirrored views the network's output is
            averaged over (1 or even, :func:`ncjax.predict_boundaries`).
        edge_snap: static; how the network's rows are moved onto the image's
            edges before the geometry (:func:`~ncjax.network.edges.snap_to_edges`);
            None keeps the network's rows.
        prior: a :class:`~ncjax.HeightPrior` (value scalar or (B,)): the scale of the
            central panoramas (``rc = 0``), and of the non-central ones whose geometry
            fails with one of :data:`SCALE_FAILURES`. None: metric scale from the geometry only.
        program_cache: where the traced programs are kept (:mod:`ncjax.programs`), so that a later process
            with the same settings and image size skips the tracing and, with XLA's persistent compilation cache,
            the compiler. True (default): the user's cache folder (:func:`~ncjax.programs.user_cache_directory`,
            ``~/.cache/ncjax/xla``), and XLA's cache switched on there unless jax's
            ``jax_compilation_cache_dir`` is already set; the environment variable ``NCJAX_CACHE=off`` switches
            both off. A first call on a machine compiles the geometry's programs for itself with XLA's cheap
            settings, then, in the background, their optimised versions for both routes (central against
            non-central, the default camera-height prior), which later processes load; the process waits for them
            before it exits. A folder: the programs there (XLA's cache as it is set, nothing compiled in the
            background). False or None: traced in each
            process, as any jitted function.
        batch_size: images per call of the geometry's programs: the batch runs in chunks of this many, the last
            one padded, so that any number of images runs the same programs (the network runs image by image).
        adapt: an :class:`ncjax.network.config.AdaptConfig` (``AdaptConfig()``: its defaults, as ``ncjax
            reconstruct``'s) to read a panorama again with the network fitted to its own flat floor and ceiling
            (:func:`~ncjax.network.adapt.adapt_model`, from ``model``'s weights for every image, no labels) where
            the rows read first are not flat (its ``min_loss``) and the panorama is central (its ``max_rc``): on
            real photographs the rows come 2-3 px nearer their labels (experiments/RESULTS.md, "Real
            photographs"), for about 3 s more a 1024 x 512 image on 2 CPU cores (a saved program, as the network's
            with ``program_cache``); ``Reconstruction.adapted`` says which were. None (default): the network as
            trained.

    Returns:
        :class:`Reconstruction` (check ``layout.ok`` per image).

    Raises:
        TypeError: ``adapt`` neither an AdaptConfig nor None.
        ValueError: bad image array, world, rc (negative or not finite; rc = 0
            without a prior is accepted and gives ``LayoutStatus.NO_SCALE``) or prior, or a model file that is
            not an ncjax model.
        FileNotFoundError: the model named is neither a file nor a shipped model, or no model given and the
            shipped weights are missing.
    """
    images = np.asarray(images)
    _check_batch_settings(images, world, views, batch_size, adapt)
    rc = np.broadcast_to(np.asarray(rc, np.float32), images.shape[:1])
    if not np.all(np.isfinite(rc)) or np.any(rc < 0):
        raise ValueError(f"rc must be finite radii >= 0 in metres, got {rc}")
    if prior is not None:
        if np.ndim(prior.value) not in (0, 1) or np.size(prior.value) not in (1, images.shape[0]):
            raise ValueError(f"the prior's value must be a scalar or one per image ({images.shape[0]})")
        prior = jax.tree.map(lambda x: jax.device_put(np.broadcast_to(np.asarray(x), rc.shape)), prior)
    count, image_height, width = images.shape[:3]
    key_data, key_impl = _image_key_data(key, count)
    # without a prior the programs still take a value (a placeholder the geometry's route never reads)
    prior_value = np.broadcast_to(np.float32(DEFAULT_CAMERA_HEIGHT if prior is None else prior.value), (count,))
    arguments = _Chunk(rc, key_data, np.asarray(prior_value, np.float32))
    prior_kind = None if prior is None else prior.kind
    route = "geometry" if prior is None else ("prior" if not np.any(rc > 0) else "fallback")
    settings = _Route(image_height, key_impl, world, None)
    network = _Network(views, edge_snap)
    directory = _program_folder(program_cache)
    if directory is None:

        def geometry(rows, chunk, kind):
            return _geometry(rows, chunk, config, settings._replace(prior_kind=kind))
    else:  # the geometry's programs load while the network's loads and runs
        geometry = _SavedGeometry(directory, (batch_size, width), config, settings)
        geometry.load(prior_kind if route == "prior" else None)
    rows_of = _network_reader(model, directory, (1, *images.shape[1:]), network, adapt)
    image_rows, adapted = zip(*(jax.device_get(rows_of(images[i : i + 1], rc[i])) for i in range(count)), strict=True)
    rows = jax.tree.map(lambda *r: np.concatenate(r).astype(np.float32), *image_rows)
    prior_settings = (prior_kind, float(config.prior.max_scale_conflict))
    laid_out = []
    for indices in _chunks(count, batch_size):
        chunk_rows, chunk = (jax.tree.map(lambda x, i=indices: x[i], tree) for tree in (rows, arguments))
        laid_out.append(_chunk_layouts(chunk_rows, _Chunk(*chunk), geometry, route, prior_settings))

    def joined(*parts):
        return jax.device_put(np.concatenate(parts)[:count])

    layouts, own = (jax.tree.map(joined, *parts) for parts in zip(*laid_out, strict=True))
    if program_cache is True and directory is not None:  # a later process may need the routes this one did not run
        geometry.prepare_later_processes((None, "camera_height"))
    # device_put, not jnp.asarray: the latter compiles a copy per shape, a few milliseconds each in a new process
    source = jax.device_put(_scale_sources(route, rc, own))
    ceiling, floor, corner_prob = (jax.device_put(x) for x in (rows.ceiling, rows.floor, rows.corner_prob))
    return Reconstruction(layouts, ceiling, floor, corner_prob, source, own, jax.device_put(np.array(adapted)))


def reconstruct(
    image: Shaped[np.ndarray, "H W 3"],
    cam: NonCentralPanorama,
    world: str = DEFAULT_WORLD,
    *,
    model: Network | ModelWeights | str | os.PathLike | None = None,
    config: PipelineConfig = NETWORK_PIPELINE_CONFIG,
    key: PRNGKeyArray | None = None,
    views: int = DEFAULT_VIEWS,
    edge_snap: EdgeSnap | None = EdgeSnap(),
    prior: HeightPrior | None = None,
    program_cache: str | os.PathLike | bool | None = True,
    adapt: AdaptConfig | None = None,
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
        program_cache: where the traced programs are kept for later processes (default: the user's cache folder;
            see :func:`reconstruct_batch`).
        adapt: an :class:`ncjax.network.config.AdaptConfig` to read the panorama again with the network fitted to
            its flat floor and ceiling where its rows need it (see :func:`reconstruct_batch`); None: the network as
            trained.

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
        adapt=adapt,
    )
    return jax.tree.map(lambda x: x[0], result.layout)
