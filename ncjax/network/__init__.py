"""The network (paper Section "Non-central HorizonNet"): panorama -> per-column boundaries and corners.

- ``model``: :class:`HorizonNet` in Flax NNX (ResNet or EfficientNet-Lite0, height compression, BiLSTM, heads).
- ``resnet``: the ResNet backbone, trained from scratch, with wrap-around width padding.
- ``efficientnet``: EfficientNet-Lite0 with ImageNet weights, a pretrained backbone.
- ``checkpoint``: safetensors models and training checkpoints.
- ``denoise``, ``edges``: the image before the network (its greyscale and blur are also training augmentations),
  and the rows snapped to its edges after it.
- ``predict``: :func:`predict_boundaries`, the network's rows on one or many panoramas.
"""

from .checkpoint import load_model, save_model
from .denoise import gaussian_blur, to_greyscale
from .edges import EdgeSnap, snap_to_edges
from .model import BoundaryPrediction, HorizonNet, HorizonNetConfig, count_parameters, init_model
from .predict import predict_boundaries

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
