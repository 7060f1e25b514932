"""ncjax: metric room layouts from single non-central circular panoramas, in JAX.

The top level holds what a user calls: a panorama in (:func:`read_panorama`), the network
(:func:`predict_boundaries`, :class:`HorizonNet`), the geometric pipeline (:func:`layout_from_boundaries`, or its
two steps :func:`fit_walls` and :func:`finish` on :class:`Rows`), the whole method (:func:`reconstruct`,
:func:`reconstruct_batch`), and the training data and loop. Everything else lives in the namespaces, one per stage,
in the order the data flows (docs/architecture.md):

- ``ncjax.geometry``: the camera, pixel <-> angle <-> Plücker ray maps, Plücker lines (paper Section 3).
- ``ncjax.solvers``: single-wall and layout solvers, RANSAC (Sections 4.1-4.3).
- ``ncjax.pipeline``: rows -> walls -> layout, its configuration and types (Section 4.4).
- ``ncjax.network``: HorizonNet in Flax NNX, image -> rows.
- ``ncjax.io``: files in and out; ``ncjax.viz``: pictures of a layout.
- ``ncjax.synth``: synthetic rooms and their renders; ``ncjax.evaluation``: every metric; ``ncjax.training``.
"""

import importlib
from typing import TYPE_CHECKING

# the namespaces, one per stage (``import x as x``: re-exported, not in ``__all__``); those a reconstruction does
# not need are imported on first use (:func:`__getattr__`), so that ``import ncjax`` costs a process less
from . import geometry as geometry
from . import solvers as solvers
from . import pipeline as pipeline
from . import network as network
from .geometry.camera import NonCentralPanorama
from .network.config import HorizonNetConfig
from .network.edges import EdgeSnap
from .pipeline.batch import layout_from_boundaries
from .pipeline.config import DEFAULT_WORLD, PipelineConfig
from .pipeline.prior import HeightPrior
from .pipeline.run import finish, fit_walls
from .pipeline.types import Layout, LayoutStatus, Rows
from .reconstruction import NETWORK_PIPELINE_CONFIG, Reconstruction, reconstruct, reconstruct_batch

# imported on first use: the namespace, or the module a name comes from
_LAZY_NAMESPACES = ("io", "viz", "synth", "evaluation", "training")
_LAZY_NAMES = {
    "HorizonNet": "network.model",  # Flax's: a reconstruction through saved programs builds no network
    "load_model": "network.checkpoint",
    "save_model": "network.checkpoint",
    "predict_boundaries": "network.predict",
    "read_panorama": "io.images",
    "SynthConfig": "synth.render",
    "synthesize_batch": "synth.render",
    "RoomConfig": "synth.rooms",
    "TrainConfig": "training.loop",
    "train": "training.loop",
}

if TYPE_CHECKING:
    from . import evaluation as evaluation
    from . import io as io
    from . import synth as synth
    from . import training as training
    from . import viz as viz
    from .io.images import read_panorama
    from .network.checkpoint import load_model, save_model
    from .network.model import HorizonNet
    from .network.predict import predict_boundaries
    from .synth.render import SynthConfig, synthesize_batch
    from .synth.rooms import RoomConfig
    from .training.loop import TrainConfig, train


def __getattr__(name: str):
    if name in _LAZY_NAMESPACES:
        return importlib.import_module(f"{__name__}.{name}")
    if name in _LAZY_NAMES:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY_NAMESPACES, *_LAZY_NAMES})


__version__ = "0.1.0"

__all__ = [
    "DEFAULT_WORLD",
    "EdgeSnap",
    "HeightPrior",
    "HorizonNet",
    "HorizonNetConfig",
    "Layout",
    "LayoutStatus",
    "NETWORK_PIPELINE_CONFIG",
    "NonCentralPanorama",
    "PipelineConfig",
    "Reconstruction",
    "RoomConfig",
    "Rows",
    "SynthConfig",
    "TrainConfig",
    "finish",
    "fit_walls",
    "layout_from_boundaries",
    "load_model",
    "predict_boundaries",
    "read_panorama",
    "reconstruct",
    "reconstruct_batch",
    "save_model",
    "synthesize_batch",
    "train",
]
