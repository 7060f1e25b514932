"""The network (paper Section "Non-central HorizonNet"): panorama -> per-column boundaries and corners.

- ``config``: the architecture (:class:`HorizonNetConfig`, its presets) and the options of its use, no Flax.
- ``model``: :class:`HorizonNet` in Flax NNX (ResNet or EfficientNet-Lite0, height compression, BiLSTM, heads).
- ``resnet``: the ResNet backbone, trained from scratch, with wrap-around width padding.
- ``efficientnet``: EfficientNet-Lite0 with ImageNet weights, a pretrained backbone.
- ``weights``: a model file's architecture and tensors, read without building the network; ``checkpoint``:
  safetensors models and training checkpoints, saved and built.
- ``denoise``, ``edges``: the image before the network (its greyscale and blur are also training augmentations),
  and the rows snapped to its edges after it.
- ``predict``: :func:`predict_boundaries`, the network's rows on one or many panoramas.

The names that need Flax (the network itself) are imported on first use (:func:`__getattr__`): a reconstruction
through saved programs (:mod:`ncjax.programs`) builds no network, and Flax's import is a fifth of a second of
every new process.
"""

import importlib
from typing import TYPE_CHECKING

from .config import HorizonNetConfig
from .denoise import gaussian_blur, to_greyscale
from .edges import EdgeSnap, snap_to_edges

# imported on first use: name -> the module it comes from
_LAZY_NAMES = {
    "BoundaryPrediction": "model",
    "HorizonNet": "model",
    "count_parameters": "model",
    "init_model": "model",
    "load_model": "checkpoint",
    "save_model": "checkpoint",
    "predict_boundaries": "predict",
}

if TYPE_CHECKING:
    from .checkpoint import load_model, save_model
    from .model import BoundaryPrediction, HorizonNet, count_parameters, init_model
    from .predict import predict_boundaries


def __getattr__(name: str):
    if name in _LAZY_NAMES:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY_NAMES})


__all__ = [
    "BoundaryPrediction",
    "count_parameters",
    "EdgeSnap",
    "gaussian_blur",
    "HorizonNet",
    "HorizonNetConfig",
    "init_model",
    "load_model",
    "predict_boundaries",
    "save_model",
    "snap_to_edges",
    "to_greyscale",
]
