"""The geometric pipeline on rows from anywhere (labels, another network): :func:`layout_from_boundaries`.

It checks its inputs, gives each panorama its RANSAC key (:func:`panorama_keys`) and runs
:func:`~ncjax.pipeline.run.layout_of` jitted, mapped over any leading batch axes, first with
``config.compact_capacity`` slots and again with ``config.capacity`` for the panoramas that need them.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Key, PRNGKeyArray, UInt32

from ..geometry.camera import NonCentralPanorama
from .config import DEFAULT_WORLD, WORLDS, PipelineConfig
from .prior import HeightPrior
from .run import layout_of
from .types import Layout, LayoutStatus, Rows, pad_layout


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
        config: :class:`PipelineConfig` (the pipeline's defaults, for exact or white-noise rows;
            :data:`ncjax.NETWORK_PIPELINE_CONFIG` is the network's); its thresholds are traced, its static
            fields compile anew.
        key: PRNG key of the RANSAC sampling (default ``jax.random.key(0)``; typed or raw): one key, split
            over the batch, or one key per panorama (the batch's shape): a panorama's RANSAC samples then do
            not depend on the batch it is in.
        prior: a :class:`~ncjax.pipeline.prior.HeightPrior` (a scalar value or one per panorama): the scale
            comes from it instead of the rows' parallax (needed for ``rc = 0``).

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
        return _compact_first(_Inputs(Rows(*arrays), cam, prior, keys), config, world)
    rows = Rows(*(x.reshape(-1, cam.width) for x in arrays))
    cams, prior = jax.tree.map(lambda x: jnp.broadcast_to(x, batch).reshape(-1), (cam, prior))
    layout = _compact_first(_Inputs(rows, cams, prior, keys), config, world)
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


@dataclasses.dataclass(frozen=True)
class _Inputs:
    """One panorama's inputs (1D rows), or a flat batch's (B leading): a pytree."""

    rows: Rows
    cam: NonCentralPanorama
    prior: HeightPrior | None
    key: Array


jax.tree_util.register_dataclass(_Inputs, data_fields=["rows", "cam", "prior", "key"], meta_fields=[])


def _compact_first(inputs: _Inputs, config: PipelineConfig, world: str) -> Layout:
    """One panorama or a flat batch: with ``config.compact_capacity`` slots first where that can help.

    A rerun with ``config.capacity`` slots replaces the compact run's
    ``TOO_MANY_WALLS`` layouts; the checks before that status do not depend
    on the slots, so it is raised exactly when the layout needs more of them.
    Traced inputs run with ``config.capacity`` slots directly.
    """
    batched = inputs.rows.ceiling.ndim == 2
    run = _batched_layout_jit if batched else _layout_jit
    full = dataclasses.replace(config, compact_capacity=0)
    compact = config.compact_capacity
    if not 0 < compact < config.capacity or any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(inputs.rows)):
        return run(inputs, full, world, config.capacity)
    layout = run(inputs, dataclasses.replace(full, capacity=compact), world, config.capacity)
    if not batched:
        return run(inputs, full, world, config.capacity) if layout.status == LayoutStatus.TOO_MANY_WALLS else layout
    rerun = np.flatnonzero(np.asarray(layout.status) == LayoutStatus.TOO_MANY_WALLS)
    if not rerun.size:
        return layout
    # padded to a power of two: few batch sizes, so few compilations
    padding = (1 << (rerun.size - 1).bit_length()) - rerun.size
    picked = jnp.asarray(np.concatenate([rerun, np.full(padding, rerun[0])]))
    destination = jnp.asarray(np.concatenate([rerun, np.full(padding, inputs.rows.ceiling.shape[0])]))
    return _rerun_jit(inputs, layout, (picked, destination), full, world)


def _padded_layout(inputs: _Inputs, config: PipelineConfig, world: str, slots: int) -> Layout:
    layout = layout_of(inputs.rows, inputs.cam, inputs.prior, inputs.key, config, world)
    return pad_layout(layout, slots)


_layout_jit = jax.jit(_padded_layout, static_argnames=("world", "slots"))


def _batched_layout(inputs: _Inputs, config: PipelineConfig, world: str, slots: int) -> Layout:
    def one(panorama):
        return _padded_layout(panorama, config, world, slots)

    if not 0 < config.chunk_size < inputs.rows.ceiling.shape[0]:
        return jax.vmap(one)(inputs)
    # the last, partial chunk (if any) is one more vmap after the loop over the full ones
    return jax.lax.map(one, inputs, batch_size=config.chunk_size)


_batched_layout_jit = jax.jit(_batched_layout, static_argnames=("world", "slots"))


def _rerun(inputs: _Inputs, layout: Layout, indices, config: PipelineConfig, world: str) -> Layout:
    """``layout`` with the panoramas ``picked`` solved again with ``config``: gather, solve and scatter in one call.

    ``indices``: ``(picked, destination)``; result ``i`` goes to panorama ``destination[i]``; out-of-range
    destinations (the padding of ``picked``) are dropped.
    """
    picked, destination = indices
    redone = _batched_layout(jax.tree.map(lambda x: x[picked], inputs), config, world, config.capacity)
    return jax.tree.map(lambda old, new: old.at[destination].set(new, mode="drop"), layout, redone)


_rerun_jit = jax.jit(_rerun, static_argnames=("world",))
