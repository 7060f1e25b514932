"""Checkpoints of :class:`~ncjax.network.model.HorizonNet` in safetensors (no pickle).

One ``.safetensors`` file holds named raw tensors plus string metadata, so a
round trip is bit-exact and loading never executes code. Tensor names are the
``/``-joined NNX state paths, prefixed ``model/`` (parameters and batch-norm
statistics) and ``optimizer/`` (the optax state and step of an
``nnx.Optimizer``, training checkpoints only). Metadata: ``format``
(``"ncjax-horizonnet"``), ``format_version``, ``config`` (the
:class:`HorizonNetConfig` as JSON), ``step`` and, for training checkpoints,
``train_config`` (JSON). A model file may hold its floating-point tensors in float16 (:func:`save_model`'s
``dtype``, metadata ``weights_dtype``): half the size, read back as float32.
"""

from __future__ import annotations

import dataclasses
import os
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from safetensors.numpy import save_file

from .config import HorizonNetConfig
from .model import HorizonNet, abstract_model
from .weights import (
    FORMAT,
    FORMAT_VERSION,
    WEIGHTS_DTYPES,
    ModelWeights,
    model_file,
    read_metadata,
    read_tensors,
    read_weights,
    stored_config,
)

_MODEL_STATE = nnx.Any(nnx.Param, nnx.BatchStat)
_OPTIMIZER_STATE = nnx.OptState


def _flat_values(state, prefix: str) -> dict:
    """``state``'s values by their tensor names in a file: ``prefix`` + the ``/``-joined state path."""
    return {prefix + "/".join(map(str, path)): variable.get_value() for path, variable in nnx.to_flat_state(state)}


def _flat_arrays(state, prefix: str) -> dict[str, np.ndarray]:
    return {name: np.asarray(value) for name, value in _flat_values(state, prefix).items()}


def _restore(node, state_filter, tensors: dict[str, np.ndarray | jax.Array], prefix: str, path: str) -> None:
    """Copy ``tensors[prefix + ...]`` into ``node``'s state, checking names, shapes and dtypes."""
    state = nnx.state(node, state_filter)
    flat = nnx.to_flat_state(state)
    names = list(_flat_values(state, prefix))
    stored = {name for name in tensors if name.startswith(prefix)}
    if set(names) != stored:
        missing, unexpected = sorted(set(names) - stored), sorted(stored - set(names))
        raise ValueError(
            f"{path}: checkpoint does not match the model; missing {missing[:5]}, unexpected {unexpected[:5]}"
        )
    for name, (_, variable) in zip(names, flat, strict=True):
        value, current = tensors[name], variable.get_value()
        if value.shape != current.shape or value.dtype != current.dtype:
            raise ValueError(
                f"{path}: {name} is {value.dtype}{value.shape}, the model expects {current.dtype}{current.shape}"
            )
        variable.set_value(jnp.asarray(value))
    nnx.update(node, nnx.from_flat_state(flat))


def save_checkpoint(
    path: str | os.PathLike,
    model: HorizonNet,
    optimizer: nnx.Optimizer | None = None,
    *,
    step: int = 0,
    train_config_json: str | None = None,
    weights_dtype: str = "float32",
) -> None:
    """Write ``model`` (and ``optimizer``) to ``path`` atomically (temporary file, then rename).

    ``weights_dtype``: ``"float16"`` stores the model's floating-point tensors at half precision (half the size).
    """
    if weights_dtype not in WEIGHTS_DTYPES:
        raise ValueError(f"weights_dtype must be one of {', '.join(WEIGHTS_DTYPES)}, got {weights_dtype!r}")
    path = pathlib.Path(path)
    tensors = _flat_arrays(nnx.state(model, _MODEL_STATE), "model/")
    for name, value in tensors.items():
        if np.issubdtype(value.dtype, np.floating):
            with np.errstate(over="ignore"):  # reported below, by name
                tensors[name] = value.astype(weights_dtype)
            if not np.all(np.isfinite(tensors[name]) | ~np.isfinite(value)):
                raise ValueError(f"{name} holds values beyond {weights_dtype}'s range; save it as float32")
    metadata = {"format": FORMAT, "format_version": FORMAT_VERSION, "config": model.config.to_json(), "step": str(step)}
    metadata["weights_dtype"] = weights_dtype
    if optimizer is not None:
        tensors |= _flat_arrays(nnx.state(optimizer, _OPTIMIZER_STATE), "optimizer/")
    if train_config_json is not None:
        metadata["train_config"] = train_config_json
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(path.suffix + ".tmp")
    save_file(tensors, temporary, metadata=metadata)
    os.replace(temporary, path)


def load_checkpoint(path: str | os.PathLike, optimizer_factory=None) -> tuple[HorizonNet, nnx.Optimizer | None, int]:
    """Read a checkpoint written by :func:`save_checkpoint`.

    Args:
        path: the ``.safetensors`` file.
        optimizer_factory: ``(model, train_config_json) -> nnx.Optimizer`` building an
            optimizer of the same structure, whose state is then restored; None
            to load the model only.

    Returns:
        ``(model, optimizer or None, step)``; the model is in eval mode.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: the file is not an ncjax checkpoint of a model that can be built (one line).
    """
    metadata = read_metadata(path)
    tensors = read_tensors(path)
    model = model_from_weights(ModelWeights(stored_config(path, metadata), tensors), str(path))
    optimizer = None
    if optimizer_factory is not None:
        if not any(name.startswith("optimizer/") for name in tensors):
            raise ValueError(f"{path} holds no optimizer state (a model file, not a training checkpoint)")
        optimizer = nnx.eval_shape(lambda m: optimizer_factory(m, metadata.get("train_config")), model)
        _restore(optimizer, _OPTIMIZER_STATE, tensors, "optimizer/", str(path))
    return model, optimizer, int(metadata.get("step", "0"))


def model_weights(model: HorizonNet | ModelWeights | str | os.PathLike) -> ModelWeights:
    """The :class:`~ncjax.network.weights.ModelWeights` of a built network (its current parameters), or of the
    shipped model or file that ``model`` names (:func:`~ncjax.network.weights.read_weights`).

    Raises:
        FileNotFoundError: neither a file nor a shipped model's name.
        ValueError: a folder, or a file that is not an ncjax model (one line).
    """
    if isinstance(model, HorizonNet):
        return ModelWeights(model.config, _flat_values(nnx.state(model, _MODEL_STATE), "model/"))
    return read_weights(model)


def model_from_weights(weights: ModelWeights, source: str = "the weights") -> HorizonNet:
    """The :class:`HorizonNet` of ``weights`` in eval mode (the tensors may be traced).

    Raises:
        ValueError: the tensors are not the architecture's (names, shapes or dtypes; ``source`` names them).
    """
    model = abstract_model(weights.config)
    _restore(model, _MODEL_STATE, weights.tensors, "model/", source)
    model.eval()
    return model


def save_model(model: HorizonNet, path: str | os.PathLike, dtype: str = "float32") -> None:
    """Save the weights and batch statistics of ``model`` (no optimizer) to a ``.safetensors`` file.

    ``dtype="float16"`` halves the file (a preset ``lite0-1024`` model: 8.7 instead of 17.4 MB); it is read back
    as float32, each value rounded to float16's 11 significant bits.
    """
    save_checkpoint(path, model, weights_dtype=dtype)


def load_model(name_or_path: str | os.PathLike) -> HorizonNet:
    """Load a model saved by :func:`save_model` (or a training checkpoint), or a shipped one by name
    (:func:`shipped_models`, e.g. ``"compact1024"``), in eval mode."""
    return load_checkpoint(model_file(name_or_path))[0]


def check_warm_start(path: str | os.PathLike, config: HorizonNetConfig) -> None:
    """Raise ValueError unless the file's architecture is ``config``'s, the corner encoding aside (metadata only).

    ``corner_base`` may differ: that is how a trained model is fine-tuned to a
    sharper corner target.
    """
    stored = stored_config(path, read_metadata(path))
    if dataclasses.replace(stored, corner_base=config.corner_base) != config:
        raise ValueError(f"{path} holds a {stored}, which cannot start a {config}")


def load_weights(path: str | os.PathLike, config: HorizonNetConfig) -> HorizonNet:
    """The weights of a model or checkpoint file in a model built from ``config`` (train mode): a warm start.

    Raises:
        ValueError: the file was written for another architecture (:func:`check_warm_start`).
    """
    check_warm_start(path, config)
    model = abstract_model(config)
    _restore(model, _MODEL_STATE, read_tensors(path), "model/", str(path))
    model.train()
    return model
