"""The geometric pipeline (paper Section 4.4): per-column boundaries -> metric layout.

Read in the order the data flows:

- ``config``: :class:`PipelineConfig`; ``types``: :class:`Layout`, :class:`LayoutStatus` and the stages' records.
- ``floor_check`` (step 0), ``corners`` (step 1), ``evidence`` (steps 1-3: RANSAC walls, occlusions).
- ``walls``: the wall loop after merging and insertion; ``manhattan`` and ``atlanta``: the two branches (step 4).
- ``adjust``, ``sparse_normal``, ``uncertainty``, ``refine``: the final least squares and its covariance (step 5).
- ``assemble`` (step 6) and ``run``: :func:`layout_from_boundaries`, the whole pipeline, jitted and batched.
"""
