"""Geometry of the non-central camera (paper Section 3).

- ``camera``: :class:`NonCentralPanorama`, the pixel <-> angle <-> ray maps and projection (eqs. 1-3).
- ``plucker``: Plücker lines, the side operator and the horizontal wall lines (Section 3.1).
- ``linalg``: null spaces and safe divisions for the solvers.
- ``reprojection``: a wall's boundary rows in the image, and plan lines through boundary points.
- ``fastmath``: a float32 arctangent that vectorises.
- ``gravity``: roll and pitch of a tilted central panorama, and maps of points and pixels between its
  frame and the levelled frame (numpy); which image sizes are full panoramas.
- ``levelling``: the roll and pitch of a central panorama from its vertical lines (OpenCV), and the
  panorama resampled level.
"""
