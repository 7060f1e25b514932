"""A network's file as it holds it: its architecture and named tensors, read without building the network.

The safetensors format and its metadata are described in :mod:`ncjax.network.checkpoint`, which builds and saves
networks (Flax). Reading a file's weights needs neither: a saved program (:mod:`ncjax.programs`) takes the
tensors as arguments, so ``ncjax reconstruct`` builds no network once its program is saved.
"""

from __future__ import annotations

import functools
import os
import pathlib
from typing import NamedTuple

import jax
import numpy as np
from safetensors import SafetensorError, safe_open
from safetensors.numpy import load_file

from .config import HorizonNetConfig

FORMAT = "ncjax-horizonnet"
FORMAT_VERSION = "1"
WEIGHTS_DTYPES = ("float32", "float16")
SHIPPED_MODELS_DIR = pathlib.Path(__file__).parent.parent / "models"
"""Where the shipped models lie (``ncjax/models/<name>.safetensors``, described in its README)."""
DEFAULT_MODEL_PATH = SHIPPED_MODELS_DIR / "lite0-1024.safetensors"


class ModelWeights(NamedTuple):
    """A network as its file holds it: the architecture and the named tensors, no module built.

    Building the :class:`~ncjax.network.model.HorizonNet` (:func:`~ncjax.network.checkpoint.model_from_weights`)
    traces its constructor, seconds on a CPU; a program that takes the weights as arguments (:mod:`ncjax.programs`)
    needs it only when it is traced.

    Attributes:
        config: the architecture.
        tensors: ``"model/<state path>"`` -> array, the parameters and batch-norm statistics
            (:func:`~ncjax.network.checkpoint.save_checkpoint`'s names; a training checkpoint's optimizer state left
            out).
    """

    config: HorizonNetConfig
    tensors: dict[str, np.ndarray | jax.Array]


def read_weights(source: ModelWeights | str | os.PathLike) -> ModelWeights:
    """The :class:`ModelWeights` of the shipped model or file that ``source`` names (``ModelWeights`` as they are);
    :func:`ncjax.network.checkpoint.model_weights` takes a built network too.

    A file is read once per process while it is unchanged (its size and modification time).

    Raises:
        FileNotFoundError: neither a file nor a shipped model's name.
        ValueError: a folder, or a file that is not an ncjax model (one line).
    """
    if isinstance(source, ModelWeights):
        return source
    path = model_file(source).resolve()
    status = path.stat()
    return _read_weights(path, status.st_size, status.st_mtime_ns)


@functools.cache
def _read_weights(path: pathlib.Path, size: int, modified: int) -> ModelWeights:
    tensors = {name: value for name, value in read_tensors(path).items() if name.startswith("model/")}
    return ModelWeights(stored_config(path, read_metadata(path)), tensors)


def read_metadata(path: str | os.PathLike) -> dict[str, str]:
    """The string metadata of a checkpoint (config, step, ...), without reading the tensors.

    Raises:
        FileNotFoundError: no file at ``path``.
        ValueError: the file is not an ncjax checkpoint (one line that says why).
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        with safe_open(path, framework="numpy") as f:
            metadata = f.metadata() or {}
    except SafetensorError as error:  # a pickle, random bytes, a truncated file, ...
        raise ValueError(f"{path} is not an ncjax .safetensors model: {error}") from None
    if metadata.get("format") != FORMAT:
        raise ValueError(f"{path} is not an ncjax HorizonNet checkpoint (format {metadata.get('format')!r})")
    if metadata.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: unsupported checkpoint version {metadata.get('format_version')!r}")
    return metadata


def stored_config(path: str | os.PathLike, metadata: dict[str, str]) -> HorizonNetConfig:
    """The architecture a checkpoint's metadata records (a one-line ValueError when it is unreadable)."""
    try:
        return HorizonNetConfig.from_json(metadata["config"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: its model configuration is unreadable ({type(error).__name__}: {error})") from None


def read_tensors(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Every tensor of a ``.safetensors`` file, float16 ones as float32 (a one-line ValueError for a damaged
    file)."""
    try:
        tensors = load_file(path)
    except SafetensorError as error:
        raise ValueError(f"{path} is not an ncjax .safetensors model: {error}") from None
    return {name: value.astype(np.float32) if value.dtype == np.float16 else value for name, value in tensors.items()}


def shipped_models() -> tuple[str, ...]:
    """Names of the layout networks that ship with ncjax (:func:`~ncjax.network.checkpoint.load_model` takes them)."""
    return tuple(sorted(path.stem for path in SHIPPED_MODELS_DIR.glob("*.safetensors") if _is_layout_network(path)))


def _is_layout_network(path: pathlib.Path) -> bool:
    try:
        read_metadata(path)
    except ValueError:  # another kind of file, e.g. the ImageNet backbone's weights
        return False
    return True


def model_file(name_or_path: str | os.PathLike) -> pathlib.Path:
    """The file of a model: ``name_or_path`` itself when it exists, else the shipped model of that name.

    Raises:
        FileNotFoundError: neither a file nor a shipped model's name.
        ValueError: a folder.
    """
    path = pathlib.Path(name_or_path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder, not a model file (.safetensors)")
    if path.exists():
        return path
    shipped = SHIPPED_MODELS_DIR / f"{name_or_path}.safetensors"
    if str(name_or_path) in shipped_models():
        return shipped
    raise FileNotFoundError(
        f"{name_or_path}: no such model file, nor a shipped model (shipped: {', '.join(shipped_models())})"
    )
