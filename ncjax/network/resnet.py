"""The ResNet backbone of :class:`~.model.HorizonNet` (He et al. 2016), wrap-aware, in Flax NNX (NHWC).

Every convolution and the stem's max pool pad the width circularly (a panorama
is 360 degrees wide) and the height with zeros, so the feature maps of a
panorama rolled by a multiple of 32 columns are the rolled feature maps.
"""

from __future__ import annotations

import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

from .config import RESNET_STAGES

# Blocks per stage of the ResNets of He et al. (2016); 10 is the one-block-per-stage
# basic-block variant (cheap to compile: tests and small models).


def circular_pad_width(x: Float[Array, "*batch H W C"], pad: int) -> Float[Array, "*batch H _ C"]:
    """Pad the width (axis -2) with the opposite edge of the 360-degree panorama."""
    if pad == 0:
        return x
    return jnp.concatenate([x[..., -pad:, :], x, x[..., :pad, :]], axis=-2)


# torchvision's ResNet initialisation (He et al. 2015, fan-out).
_he_fan_out = nnx.initializers.variance_scaling(2.0, "fan_out", "normal")


class WrapConv(nnx.Module):
    """Square convolution, circular padding along the width, zero padding along the height.

    Padding ``kernel // 2`` on each side (odd kernels), like PyTorch's
    ``padding=k//2`` except that the width wraps around.
    """

    def __init__(
        self, in_channels: int, out_channels: int, kernel: int, strides=(1, 1), *, use_bias: bool, rngs: nnx.Rngs
    ):
        self.pad = kernel // 2
        self.conv = nnx.Conv(
            in_channels,
            out_channels,
            (kernel, kernel),
            strides=strides,
            padding=((self.pad, self.pad), (0, 0)),
            use_bias=use_bias,
            kernel_init=_he_fan_out,
            rngs=rngs,
        )

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B h w D"]:
        return self.conv(circular_pad_width(x, self.pad))


def batch_norm(channels: int, rngs: nnx.Rngs, zero_scale: bool = False) -> nnx.BatchNorm:
    # PyTorch's BatchNorm2d defaults (momentum 0.1 there is 1 - 0.9 here).
    return nnx.BatchNorm(
        channels,
        momentum=0.9,
        epsilon=1e-5,
        scale_init=nnx.initializers.zeros if zero_scale else nnx.initializers.ones,
        rngs=rngs,
    )


class ConvBatchNorm(nnx.Module):
    """WrapConv (no bias) followed by batch norm."""

    def __init__(self, in_channels, out_channels, kernel, strides=(1, 1), *, zero_scale=False, rngs: nnx.Rngs):
        self.conv = WrapConv(in_channels, out_channels, kernel, strides, use_bias=False, rngs=rngs)
        self.norm = batch_norm(out_channels, rngs, zero_scale)

    def __call__(self, x):
        return self.norm(self.conv(x))


class BasicBlock(nnx.Module):
    """Two 3x3 convolutions with a residual connection (ResNet-18/34).

    The last batch norm scale starts at zero so every block starts as the
    identity (Goyal et al. 2017), which helps training from scratch.
    """

    expansion = 1

    def __init__(self, in_channels: int, channels: int, stride: int, *, rngs: nnx.Rngs):
        self.first = ConvBatchNorm(in_channels, channels, 3, (stride, stride), rngs=rngs)
        self.second = ConvBatchNorm(channels, channels, 3, zero_scale=True, rngs=rngs)
        needs_projection = stride != 1 or in_channels != channels
        self.shortcut = (
            ConvBatchNorm(in_channels, channels, 1, (stride, stride), rngs=rngs) if needs_projection else None
        )

    def __call__(self, x):
        residual = x if self.shortcut is None else self.shortcut(x)
        return nnx.relu(self.second(nnx.relu(self.first(x))) + residual)


class Bottleneck(nnx.Module):
    """1x1, 3x3 (strided, torchvision's "ResNet v1.5"), 1x1 x4 with a residual connection (ResNet-50)."""

    expansion = 4

    def __init__(self, in_channels: int, channels: int, stride: int, *, rngs: nnx.Rngs):
        out_channels = channels * self.expansion
        self.reduce = ConvBatchNorm(in_channels, channels, 1, rngs=rngs)
        self.spatial = ConvBatchNorm(channels, channels, 3, (stride, stride), rngs=rngs)
        self.expand = ConvBatchNorm(channels, out_channels, 1, zero_scale=True, rngs=rngs)
        needs_projection = stride != 1 or in_channels != out_channels
        self.shortcut = (
            ConvBatchNorm(in_channels, out_channels, 1, (stride, stride), rngs=rngs) if needs_projection else None
        )

    def __call__(self, x):
        residual = x if self.shortcut is None else self.shortcut(x)
        y = nnx.relu(self.spatial(nnx.relu(self.reduce(x))))
        return nnx.relu(self.expand(y) + residual)


class ResNet(nnx.Module):
    """ResNet trunk (no pooling head) returning the four stage outputs, strides 4 to 32."""

    def __init__(self, depth: int, width: int, *, rngs: nnx.Rngs):
        block = Bottleneck if depth == 50 else BasicBlock
        self.stem = ConvBatchNorm(3, width, 7, (2, 2), rngs=rngs)
        in_channels = width
        self.stages = nnx.List()
        for i, blocks in enumerate(RESNET_STAGES[depth]):
            channels = width * 2**i
            stage = nnx.List()
            for j in range(blocks):
                stride = 2 if i > 0 and j == 0 else 1
                stage.append(block(in_channels, channels, stride, rngs=rngs))
                in_channels = channels * block.expansion
            self.stages.append(stage)

    def __call__(self, x: Float[Array, "B H W 3"]) -> list[Array]:
        x = nnx.relu(self.stem(x))
        # Max pool 3x3 / 2: circular in width, -inf padding in height.
        x = nnx.max_pool(circular_pad_width(x, 1), (3, 3), strides=(2, 2), padding=((1, 1), (0, 0)))
        features = []
        for stage in self.stages:
            for block in stage:
                x = block(x)
            features.append(x)
        return features
