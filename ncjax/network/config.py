"""The network's architecture settings and the options of its use, without the network (no Flax).

What a reconstruction needs before it builds any network: a saved program (:mod:`ncjax.programs`) is named by
the architecture, and ``ncjax reconstruct`` checks its options, so these import in milliseconds; the network
itself is :mod:`ncjax.network.model`.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

# The backbones' coarsest feature map is 1/32 of the image: input sizes are multiples of it, and the
# convolutional features of a panorama rolled by a multiple of it are the features rolled.
NETWORK_STRIDE = 32

BACKBONES = ("resnet", "efficientnet_lite0")
# ResNet blocks per stage for each depth (basic blocks up to 34, bottlenecks at 50)
RESNET_STAGES = {10: (1, 1, 1, 1), 18: (2, 2, 2, 2), 34: (3, 4, 6, 3), 50: (3, 4, 6, 3)}
# A built network, :class:`ncjax.network.model.HorizonNet`, in the signatures of the modules that import Flax
# only to build one (the type itself would import it; checked where it is used)
Network = Any
# views averaged by default (predict_boundaries, reconstruct): 4 cut the shipped model's boundary error by a tenth
DEFAULT_VIEWS = 4


@dataclasses.dataclass(frozen=True)
class HorizonNetConfig:
    """Static architecture of :class:`~ncjax.network.model.HorizonNet` (hashable, JSON round-trippable).

    Attributes:
        backbone: ``"resnet"`` (a ResNet of ``depth`` and ``width``, trained
            from scratch) or ``"efficientnet_lite0"`` (EfficientNet-Lite0,
            :data:`~ncjax.network.model.LITE0_BACKBONE`, which :func:`~ncjax.network.model.init_model` starts from its
            ImageNet weights; ``depth`` and ``width`` are then ignored). Files
            written before this field existed load with ``"resnet"``.
        depth: ResNet depth, 10, 18, 34 (basic blocks) or 50 (bottlenecks).
        width: channels of the ResNet stem; stage ``i`` has ``width * 2**i``
            (times 4 for bottlenecks). 64 is the standard ResNet.
        input_height, input_width: image size the network is built for (both
            multiples of 32; the LSTM input size depends on the height, the
            sequence length on the width).
        lstm_hidden: hidden units per direction of each LSTM layer.
        lstm_layers: stacked bidirectional LSTM layers (2 in HorizonNet).
        step_cols: columns predicted per LSTM position (1, 2 or 4; 4 in HorizonNet).
        dropout: dropout rate between and after the LSTM layers (0.5 in HorizonNet).
        corner_base: the corner output's encoding ``corner_base**d``, ``d`` in
            output columns to the nearest corner. HorizonNet's 0.96 (the
            labels' encoding, docs/design.md section 5) makes lobes 30-70 columns
            wide at our 512 output columns, wider than the gaps between close
            corners; a sharper base separates them. Files written before this
            field existed load with 0.96.
    """

    backbone: str = "resnet"
    depth: int = 18
    width: int = 32
    input_height: int = 256
    input_width: int = 512
    lstm_hidden: int = 128
    lstm_layers: int = 2
    step_cols: int = 4
    dropout: float = 0.5
    corner_base: float = 0.96

    def __post_init__(self):
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {BACKBONES}, got {self.backbone!r}")
        if self.depth not in RESNET_STAGES:
            raise ValueError(f"depth must be one of {sorted(RESNET_STAGES)}, got {self.depth}")
        if self.width < 8 or self.width % 8:
            raise ValueError(
                f"width must be a positive multiple of 8 (channels / 8 after compression), got {self.width}"
            )
        if (
            self.input_height % NETWORK_STRIDE
            or self.input_width % NETWORK_STRIDE
            or self.input_height <= 0
            or self.input_width <= 0
        ):
            raise ValueError(
                f"input size must be positive multiples of {NETWORK_STRIDE}, "
                f"got {self.input_height} x {self.input_width}"
            )
        if self.step_cols not in (1, 2, 4):
            raise ValueError(f"step_cols must be 1, 2 or 4 (so every stage is upsampled), got {self.step_cols}")
        if self.lstm_hidden <= 0 or self.lstm_layers <= 0:
            raise ValueError("lstm_hidden and lstm_layers must be positive")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if not 0.0 < self.corner_base < 1.0:
            raise ValueError(f"corner_base must be in (0, 1), got {self.corner_base}")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> HorizonNetConfig:
        return cls(**json.loads(text))

    @classmethod
    def preset(cls, name: str) -> HorizonNetConfig:
        """A named configuration (:data:`PRESETS`): "paper", "resnet18", "compact", "compact1024" or "lite0-1024"."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
        return PRESETS[name]


PRESETS: dict[str, HorizonNetConfig] = {
    # The paper's network: HorizonNet with ResNet-50 at 512 x 1024.
    "paper": HorizonNetConfig(depth=50, width=64, input_height=512, input_width=1024, lstm_hidden=512),
    # HorizonNet's lighter variant, same input.
    "resnet18": HorizonNetConfig(depth=18, width=64, input_height=512, input_width=1024, lstm_hidden=512),
    # Half-width ResNet-18 at 256 x 512, small LSTM (<= 4M parameters): the earlier shipped model.
    "compact": HorizonNetConfig(depth=18, width=32, input_height=256, input_width=512, lstm_hidden=96),
    # The shipped default: the compact network at the full 512 x 1024 input, rows and
    # corners at the panorama's own resolution for four times the convolution work.
    "compact1024": HorizonNetConfig(depth=18, width=32, input_height=512, input_width=1024, lstm_hidden=96),
    # compact1024's LSTM and heads on EfficientNet-Lite0 started from ImageNet: towards real photographs.
    "lite0-1024": HorizonNetConfig(backbone="efficientnet_lite0", input_height=512, input_width=1024, lstm_hidden=96),
}


def check_views(views: int) -> None:
    """Raise ValueError unless ``views`` is 1 or an even number (see :func:`~ncjax.network.model.predict_views`)."""
    if not (isinstance(views, int) and (views == 1 or (views >= 2 and views % 2 == 0))):
        raise ValueError(f"views must be 1 or an even number >= 2, got {views!r}")


@dataclasses.dataclass(frozen=True)
class AdaptConfig:
    """Settings of the test-time adaptation, :func:`~ncjax.network.adapt.adapt_model` (set once, not chosen on the
    photographs it is measured on).

    The loss has degenerate minimisers (any rows of one constant ratio, both boundaries at the horizon included):
    what keeps the network near its trained rows is the small budget, ``steps`` times ``learning_rate`` (5e-3 on
    each parameter by default).

    Where a panorama's rows, as they are read (views, edge snap), already see one flat floor and ceiling, there is
    little to correct and the adaptation's time is spared: only a panorama whose rows' flatness loss
    (:func:`~ncjax.network.flatness.row_flatness`) is at least ``min_loss`` is adapted. Its default, ``huber^2 / 2``
    for the default ``huber``, is the loss of rows whose every column puts its wall the Huber threshold (5%) off
    the others' distance: derived from the loss, not chosen on photographs. By default only central panoramas
    are adapted (``max_rc`` 0): the gains were measured on central photographs, and the rig's one real capture
    measured was laid out worse adapted (experiments/RESULTS.md, "Real photographs").

    Attributes:
        steps: Adam steps on the panorama.
        learning_rate: Adam's step size.
        huber: the Huber loss's threshold, in natural log of the distance ratio (0.05: 5% of the distance).
        min_loss: the rows' flatness loss from which a panorama is adapted (0: every panorama).
        max_rc: the largest radius of a panorama's circle of optical centres (metres) adapted (inf: any).
    """

    steps: int = 5
    learning_rate: float = 1e-3
    huber: float = 0.05
    min_loss: float = 0.5 * 0.05**2
    max_rc: float = 0.0

    def __post_init__(self):
        if self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if not self.learning_rate > 0 or not self.huber > 0:
            raise ValueError(f"learning_rate and huber must be > 0, got {self.learning_rate}, {self.huber}")
        if not (self.min_loss >= 0 and self.max_rc >= 0):
            raise ValueError(f"min_loss and max_rc must be >= 0, got {self.min_loss}, {self.max_rc}")

    def traced(self) -> AdaptConfig:
        """The settings the adaptation's program depends on, as Python numbers (``min_loss`` and ``max_rc`` only
        choose the panoramas): its jit and saved program are keyed by them, so that no choice of panoramas traces
        it again."""
        return AdaptConfig(int(self.steps), float(self.learning_rate), float(self.huber))
