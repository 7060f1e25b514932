"""Non-central HorizonNet in Flax NNX (paper Section "Non-central HorizonNet").

The architecture is HorizonNet's (Sun et al., CVPR 2019), as the paper adapts
it, written from its description:

1. a backbone giving four feature maps at strides 4, 8, 16 and 32: a ResNet
   (:mod:`.resnet`; 18, 34 or 50 layers, optional width multiplier, trained from
   scratch) or EfficientNet-Lite0 (:mod:`.efficientnet`, started from its
   ImageNet weights: the way to real photographs);
2. per map a *height compression* (HorizonNet's "global height conv"): four
   3x3 convolutions of stride (2, 1), each with batch norm and ReLU, taking
   ``c`` channels to ``c/2, c/2, c/4, c/8``; the remaining height is folded
   into the channels, so each map becomes one feature vector per column;
3. wrap-aware linear upsampling of the four column sequences to a common
   width ``W / step_cols`` and concatenation: the LSTM input size is
   ``sum_i (c_i / 8) * h_i`` with ``h_i`` the compressed heights, fixed by the
   input shape (:func:`column_feature_size`);
4. a 2-layer bidirectional LSTM over the ``W / step_cols`` positions, each
   position predicting ``step_cols`` consecutive columns (HorizonNet's
   ``step_cols = 4``; the paper keeps HorizonNet unchanged);
5. a linear head giving per column the ceiling-boundary and floor-boundary
   *elevations* in radians and the corner logit.

The panorama is 360 degrees wide, so every convolution (and the stem's max
pool) pads the width circularly and the height with zeros, and the
upsampling wraps around: the convolutional features of a panorama rolled by
a multiple of 32 columns are the rolled features (tested). The LSTM runs from
column 0 to column W - 1 and back, so the final output is only approximately
roll-equivariant, as in HorizonNet.

Boundary encoding: the network predicts elevations ``phi`` (radians, positive
up; HorizonNet's ``bon`` is ``-phi``), so the L1 loss is "in radians" as in
HorizonNet, independent of the image size. :func:`~ncjax.geometry.camera.elevation_to_row` turns them
into pixel rows with the camera's row convention (docs/design.md section 2).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

from ..geometry.camera import elevation_to_row
from .config import NETWORK_STRIDE, HorizonNetConfig, check_views
from .efficientnet import LITE0, LITE0_FEATURE_CHANNELS, EfficientNet, load_efficientnet_lite0
from .resnet import ResNet, WrapConv, batch_norm

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

# EfficientNet-Lite0 as a backbone: wrap-around width padding, no ImageNet classifier.
LITE0_BACKBONE = dataclasses.replace(LITE0, circular_width=True, classifier=False)


# ----------------------------------------------------------------------------- configuration


def stage_channels(config: HorizonNetConfig) -> tuple[int, int, int, int]:
    """Channels of the backbone's four feature maps (strides 4, 8, 16 and 32)."""
    if config.backbone == "efficientnet_lite0":
        return LITE0_FEATURE_CHANNELS
    expansion = 4 if config.depth == 50 else 1
    return tuple(config.width * 2**i * expansion for i in range(4))


def _compressed_height(height: int) -> int:
    """Height after the four stride-(2, 1) 3x3 convolutions with padding 1."""
    for _ in range(4):
        height = (height - 1) // 2 + 1
    return height


def column_feature_size(config: HorizonNetConfig) -> int:
    """LSTM input size: the compressed channels times compressed heights, summed over stages."""
    heights = [config.input_height // 2 ** (i + 2) for i in range(4)]
    return sum(c // 8 * _compressed_height(h) for c, h in zip(stage_channels(config), heights, strict=True))


# ----------------------------------------------------------------------------- wrap-aware ops


def resample_columns(x: Float[Array, "*batch W C"], width: int) -> Float[Array, "*batch {width} C"]:
    """Linear resampling of a 360-degree sequence of columns (axis -2) to ``width`` columns.

    Column ``j`` of the output has its centre at ``(j + 0.5) * W / width - 0.5``
    input columns (pixel centres aligned, like ``align_corners=False``) and
    interpolates its two neighbours modulo ``W``, so the seam is treated like
    any other column. For integer upsampling factors this is HorizonNet's
    "pad one column each side, interpolate, crop".
    """
    source_width = x.shape[-2]
    position = (jnp.arange(width) + 0.5) * (source_width / width) - 0.5
    left = jnp.floor(position)
    weight = (position - left)[:, None]
    left = left.astype(jnp.int32) % source_width
    right = (left + 1) % source_width
    return jnp.take(x, left, axis=-2) * (1.0 - weight) + jnp.take(x, right, axis=-2) * weight


# ----------------------------------------------------------------------------- layers


class HeightCompression(nnx.Module):
    """HorizonNet's global height conv: four (3x3 / (2, 1) conv, BN, ReLU), c -> c/8 channels.

    The output ``(B, h, W, c/8)`` is folded into one feature vector per
    column, ordered channel-major (``c * h + row``, PyTorch's ``reshape`` of
    an NCHW tensor, so that HorizonNet weights could be mapped one to one).
    """

    def __init__(self, channels: int, *, rngs: nnx.Rngs):
        widths = [channels, channels // 2, channels // 2, channels // 4, channels // 8]
        self.convs = nnx.List(
            [WrapConv(a, b, 3, (2, 1), use_bias=True, rngs=rngs) for a, b in zip(widths[:-1], widths[1:], strict=True)]
        )
        self.norms = nnx.List([batch_norm(b, rngs) for b in widths[1:]])

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B W F"]:
        for conv, norm in zip(self.convs, self.norms, strict=True):
            x = nnx.relu(norm(conv(x)))
        batch, height, width, channels = x.shape
        return jnp.transpose(x, (0, 2, 3, 1)).reshape(batch, width, channels * height)


class BidirectionalLSTM(nnx.Module):
    """Stacked bidirectional LSTM over the column sequence, dropout between and after layers.

    Each layer runs one LSTM left to right and one right to left from zero
    states and concatenates their outputs (PyTorch's ``bidirectional=True``).
    """

    def __init__(self, in_features: int, hidden: int, layers: int, dropout: float, *, rngs: nnx.Rngs):
        self.hidden = hidden
        self.forward = nnx.List()
        self.backward = nnx.List()
        for i in range(layers):
            size = in_features if i == 0 else 2 * hidden
            self.forward.append(nnx.RNN(nnx.OptimizedLSTMCell(size, hidden, rngs=rngs), rngs=False))
            self.backward.append(
                nnx.RNN(nnx.OptimizedLSTMCell(size, hidden, rngs=rngs), reverse=True, keep_order=True, rngs=False)
            )
        self.dropout = nnx.Dropout(dropout)

    def __call__(self, x: Float[Array, "B S F"], dropout_key: Array | None = None) -> Float[Array, "B S H2"]:
        layers = len(self.forward)
        keys = [None] * layers if dropout_key is None else list(jax.random.split(dropout_key, layers))
        zero_state = (jnp.zeros((x.shape[0], self.hidden), x.dtype),) * 2
        for forward, backward, key in zip(self.forward, self.backward, keys, strict=True):
            both = [forward(x, initial_carry=zero_state), backward(x, initial_carry=zero_state)]
            x = self.dropout(jnp.concatenate(both, axis=-1), rngs=key)
        return x


class BoundaryPrediction(NamedTuple):
    """Raw network output per column (a pytree).

    Attributes:
        ceiling_elevation, floor_elevation: (B, W) boundary elevations, radians (up positive).
        corner_logit: (B, W) logit of the corner probability (target ``config.corner_base**d``).
    """

    ceiling_elevation: Float[Array, "B W"]
    floor_elevation: Float[Array, "B W"]
    corner_logit: Float[Array, "B W"]


class HorizonNet(nnx.Module):
    """Non-central HorizonNet (see the module docstring).

    The backbone is ``config.backbone``'s: a :class:`ResNet` or an
    :class:`~.efficientnet.EfficientNet` built from :data:`LITE0_BACKBONE`
    (its feature maps only). Both take RGB images in [0, 1]: the ResNet's
    input is normalised with ImageNet's mean and standard deviation here,
    EfficientNet normalises its input itself.

    State: ``nnx.Param`` (weights, trained) and ``nnx.BatchStat`` (batch-norm
    running statistics, updated in train mode). ``model.train()`` uses batch
    statistics and dropout, ``model.eval()`` the running statistics and no
    dropout. The network was built for ``config.input_height x input_width``
    but accepts any height and width that keep :func:`column_feature_size`
    (same height) and are multiples of 32.
    """

    def __init__(self, config: HorizonNetConfig, *, rngs: nnx.Rngs):
        self.config = config
        if config.backbone == "efficientnet_lite0":
            self.backbone = EfficientNet(LITE0_BACKBONE, rngs=rngs)
        else:
            self.backbone = ResNet(config.depth, config.width, rngs=rngs)
        self.compressions = nnx.List([HeightCompression(c, rngs=rngs) for c in stage_channels(config)])
        self.lstm = BidirectionalLSTM(
            column_feature_size(config), config.lstm_hidden, config.lstm_layers, config.dropout, rngs=rngs
        )
        # Start near typical boundaries (ceiling above, floor below the horizon, few corners).
        initial = jnp.repeat(jnp.array([0.5, -0.6, -1.0]), config.step_cols)
        self.head = nnx.Linear(2 * config.lstm_hidden, 3 * config.step_cols, bias_init=lambda *_: initial, rngs=rngs)

    def backbone_features(self, images: Float[Array, "B H W 3"]) -> list[Array]:
        """The backbone's feature maps at strides 4, 8, 16 and 32 of RGB images in [0, 1]."""
        if self.config.backbone == "efficientnet_lite0":
            return list(self.backbone.features(images))
        return self.backbone((images - jnp.asarray(IMAGENET_MEAN)) / jnp.asarray(IMAGENET_STD))

    def column_features(self, images: Float[Array, "B H W 3"]) -> Float[Array, "B S F"]:
        """Convolutional features per LSTM position, ``S = W / step_cols`` (roll-equivariant part)."""
        return self.compressed_columns(self.backbone_features(images), images.shape[-2])

    def compressed_columns(self, features: list[Array], width: int) -> Float[Array, "B S F"]:
        """:meth:`column_features` of the backbone's feature maps of images ``width`` columns wide (a frozen
        backbone's maps can be computed once and kept: ``experiments/frozen_backbone.py``)."""
        sequence_length = width // self.config.step_cols
        columns = [
            resample_columns(compress(f), sequence_length)
            for compress, f in zip(self.compressions, features, strict=True)
        ]
        return jnp.concatenate(columns, axis=-1)

    def __call__(self, images: Float[Array, "B H W 3"], *, dropout_key: Array | None = None) -> BoundaryPrediction:
        """Per-column boundaries and corner logits of RGB images in [0, 1].

        Args:
            images: (B, H, W, 3) float in [0, 1], H and W multiples of 32.
            dropout_key: a ``jax.random`` key, required in train mode when
                ``config.dropout > 0`` (explicit keys keep training reproducible
                from (seed, step) alone).
        """
        return self.sequence_head(self.column_features(images), dropout_key=dropout_key)

    def sequence_head(self, features: Float[Array, "B S F"], *, dropout_key: Array | None = None) -> BoundaryPrediction:
        """The LSTM and the linear head on :meth:`column_features` (the part that reads the columns from an edge).

        Args:
            features: (B, S, F) column features, ``S = W / step_cols`` positions.
            dropout_key: as in :meth:`__call__`.
        """
        batch, positions, _ = features.shape
        out = self.head(self.lstm(features, dropout_key)).reshape(batch, positions, 3, self.config.step_cols)
        out = jnp.moveaxis(out, 2, 0).reshape(3, batch, positions * self.config.step_cols)
        return BoundaryPrediction(out[0], out[1], out[2])


@functools.cache
def _initialiser(config: HorizonNetConfig):
    return nnx.jit(lambda key: HorizonNet(config, rngs=nnx.Rngs(key)))


def init_model(config: HorizonNetConfig, seed: int = 0) -> HorizonNet:
    """A freshly initialised :class:`HorizonNet` (train mode), a pure function of ``seed``.

    With the ``"efficientnet_lite0"`` backbone, the backbone starts from the
    shipped ImageNet weights and batch-norm statistics
    (:func:`~.efficientnet.load_efficientnet_lite0`; its classifier is left
    out), the rest from ``seed``; the ResNet backbone starts from ``seed``.

    The initialisation runs as one compiled program from an ``"rbg"`` key
    (XLA's random bit generator): on a CPU this compiles several times faster
    than eager or threefry initialisation of the ~100 weight tensors. The
    random values depend on the backend (CPU and GPU give different, equally
    valid, initialisations).
    """
    model = _initialiser(config)(jax.random.key(seed, impl="rbg"))
    if config.backbone == "efficientnet_lite0":
        use_imagenet_backbone(model)
    return model


def use_imagenet_backbone(model: HorizonNet) -> None:
    """Set an ``"efficientnet_lite0"`` model's backbone to the shipped ImageNet weights and batch-norm statistics
    (:func:`~.efficientnet.load_efficientnet_lite0`, without its classifier), in place."""
    pretrained = nnx.state(load_efficientnet_lite0(circular_width=True))
    nnx.update(model.backbone, nnx.State({name: pretrained[name] for name in nnx.state(model.backbone)}))


def abstract_model(config: HorizonNetConfig) -> HorizonNet:
    """A :class:`HorizonNet` whose arrays are ``jax.ShapeDtypeStruct`` (nothing allocated)."""
    # Built through the same (jitted) path as init_model so that both give equal
    # graph definitions (nnx.jit would otherwise recompile for a loaded model).
    return nnx.eval_shape(lambda: _initialiser(config)(jax.random.key(0, impl="rbg")))


def count_parameters(config: HorizonNetConfig) -> int:
    """Number of trainable parameters (``nnx.Param``), computed without allocating them."""
    return sum(math.prod(x.shape) for x in jax.tree.leaves(nnx.state(abstract_model(config), nnx.Param)))


# ----------------------------------------------------------------------------- encoding


@functools.partial(jax.jit, static_argnames=("height", "width"))
def prediction_to_rows(
    prediction: BoundaryPrediction, height: int, width: int
) -> tuple[Float[Array, "B {width}"], Float[Array, "B {width}"], Float[Array, "B {width}"]]:
    """Network output -> (ceiling_v, floor_v, corner_prob) for an image of ``height x width``.

    The per-column values are resampled wrap-aware to ``width`` columns and the
    elevations converted to sub-pixel rows of a ``height``-row image.
    """
    stacked = jnp.stack(
        [prediction.ceiling_elevation, prediction.floor_elevation, jax.nn.sigmoid(prediction.corner_logit)], -1
    )
    ceiling, floor, corner_prob = jnp.moveaxis(resample_columns(stacked, width), -1, 0)
    return elevation_to_row(ceiling, height), elevation_to_row(floor, height), corner_prob


def predict_views(model: HorizonNet, images: Float[Array, "B H W 3"], views: int) -> BoundaryPrediction:
    """The network's output averaged over ``views`` symmetric views of each panorama (test-time augmentation).

    Rotating the rig about its vertical axis rolls the columns of a circular
    panorama, and mirroring the room mirrors them (the rig is symmetric), so
    every rolled and mirrored copy is a valid panorama of the same room: the
    network's outputs on them, mapped back to the original columns, are
    averaged (elevations and corner logits). ``views`` is 1 (the image alone)
    or even: ``views / 2`` rolls evenly spaced over the width, each also
    mirrored. The network has circular padding but its LSTM reads the columns
    from a starting edge, so the views do differ; averaging them cuts the
    boundary error (experiments/RESULTS.md).

    The convolutional features of a panorama rolled by a multiple of
    :data:`NETWORK_STRIDE` columns are its features rolled, so when every roll is
    such a multiple the backbone runs on the image and its mirror image only, and
    the LSTM and head on the rolled features of each view: the same outputs for
    two backbone passes per panorama instead of ``views``.

    Args:
        images: (B, H, W, 3) at the network's input size, values in [0, 1].
        views: static, 1 or an even number.
    """
    check_views(views)
    width = images.shape[2]
    if views == 1:
        return model(images)
    shifts = [width * i // (views // 2) for i in range(views // 2)]
    if all(shift % NETWORK_STRIDE == 0 for shift in shifts):
        # a mirrored rolled image is the mirror image rolled the other way
        plain, mirrored = jnp.split(model.column_features(jnp.concatenate([images, images[:, :, ::-1]])), 2)
        step = model.config.step_cols  # columns per LSTM position
        features = jnp.concatenate(
            [
                view
                for shift in shifts
                for view in (jnp.roll(plain, shift // step, axis=1), jnp.roll(mirrored, -(shift // step), axis=1))
            ]
        )
        predicted = model.sequence_head(features)
    else:
        rolled = [jnp.roll(images, shift, axis=2) for shift in shifts]
        predicted = model(jnp.concatenate([view for image in rolled for view in (image, image[:, :, ::-1])]))
    outputs = jax.tree.map(lambda x: x.reshape(views, images.shape[0], *x.shape[1:]), predicted)

    def back(view, x):
        x = x[:, ::-1] if view % 2 else x
        return jnp.roll(x, -shifts[view // 2] * x.shape[1] // width, axis=1)

    return jax.tree.map(lambda x: jnp.mean(jnp.stack([back(view, x[view]) for view in range(views)]), 0), outputs)
