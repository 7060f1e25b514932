"""Evaluation: every metric of a layout or of the network, and the real-panorama benchmark's scoring.

- ``layout_metrics``: 3D and 2D IoU, corner error, CEN, heights and line errors of a layout against ground truth
  in metres (paper Sections 5.3-5.5), on the host in numpy.
- ``central_metrics``: the central-panorama papers' metrics from two corner sets of one image (``ncjax evaluate``).
- ``network_metrics``: the boundary pixel error and corner precision/recall of Table netcorExp.
- ``panorama_labels``: labelled real panoramas (label_cor and side json) read and checked, and the room each
  label describes.
- ``panorama_scores``: the network's rows, corners and raw layout on them scored against their labels, and the
  benchmark's table and CSV; ``contact_sheet``: its picture of every panorama.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from . import network_metrics
from .network_metrics import boundary_pixel_error, corner_confusion, corner_scores, network_table

# imported on first use: the layouts' metrics need shapely, which the training (the network's metrics only) does
# without, as on an accelerator's image that lacks it
_LAZY_MODULES = ("central_metrics", "layout_metrics")
_LAZY_NAMES = {"evaluate_layout": "layout_metrics"}  # a name, and the module it comes from

if TYPE_CHECKING:
    from . import central_metrics as central_metrics
    from . import layout_metrics as layout_metrics
    from .layout_metrics import evaluate_layout


def __getattr__(name: str):
    if name in _LAZY_MODULES:
        return importlib.import_module(f"{__name__}.{name}")
    if name in _LAZY_NAMES:
        return getattr(importlib.import_module(f"{__name__}.{_LAZY_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY_MODULES, *_LAZY_NAMES})


__all__ = [
    "boundary_pixel_error",
    "central_metrics",
    "corner_confusion",
    "corner_scores",
    "evaluate_layout",
    "layout_metrics",
    "network_metrics",
    "network_table",
]
