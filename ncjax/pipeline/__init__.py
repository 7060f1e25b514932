"""The geometric pipeline (paper Section 4.4): per-column boundaries -> metric layout.

Read in the order the data flows:

- ``config``: :class:`PipelineConfig`, one part per stage (``settings``: how a part is a pytree);
  ``types``: :class:`Rows`, :class:`Walls`, :class:`Layout`, :class:`LayoutStatus` and the stages' records.
- ``run``: the one path, :func:`fit_walls` (steps 0-4) then :func:`finish` (steps 5-6), for one panorama;
  ``batch``: :func:`layout_from_boundaries`, the same jitted and mapped over a batch.
- ``floor_check`` (step 0), ``corners`` (step 1), ``evidence`` (steps 1-3: RANSAC walls, occlusions).
- ``walls``: the wall loop after merging and insertion; ``manhattan`` and ``atlanta``: the two branches (step 4).
- ``adjust``, ``sparse_normal``, ``normal_solver``, ``uncertainty``, ``refine``: the final least squares and its
  covariance (step 5).
- ``assemble`` (step 6); ``prior``: the scale from a height prior (central panoramas).
"""

from .batch import layout_from_boundaries, panorama_keys
from .config import DEFAULT_WORLD, WORLDS, PipelineConfig
from .prior import HeightPrior
from .run import FittedWalls, finish, fit_walls, layout_of
from .types import Layout, LayoutStatus, Rows, Walls

__all__ = [
    "DEFAULT_WORLD",
    "FittedWalls",
    "HeightPrior",
    "Layout",
    "LayoutStatus",
    "PipelineConfig",
    "Rows",
    "WORLDS",
    "Walls",
    "finish",
    "fit_walls",
    "layout_from_boundaries",
    "layout_of",
    "panorama_keys",
]
