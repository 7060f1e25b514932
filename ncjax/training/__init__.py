"""Training the network: loss, augmentations, optimiser, resumable loop (``loop``) and its data (``data``)."""

from .loop import TrainConfig, horizonnet_loss, train

__all__ = [
    "horizonnet_loss",
    "train",
    "TrainConfig",
]
