"""Geometry of the non-central camera (paper Section 3).

- ``camera``: :class:`NonCentralPanorama`, the pixel <-> angle <-> ray maps and projection (eqs. 1-3).
- ``plucker``: Plücker lines, the side operator and the horizontal wall lines (Section 3.1).
- ``linalg``: null spaces and safe divisions for the solvers.
- ``reprojection``: a wall's boundary rows in the image, boundary points and their ranges, and plan lines through
  boundary points.
- ``fastmath``: a float32 arctangent that vectorises.
- ``gravity``: roll and pitch of a tilted panorama (read as a central one), and maps of points and pixels between its
  frame and the levelled frame (numpy); which image sizes are full panoramas.
- ``levelling``: the roll and pitch of a panorama from its vertical lines (OpenCV), and the panorama
  resampled level (exactly for a central one, nearly for a rig's).
"""

from .camera import (
    NonCentralPanorama,
    angles_to_pixel,
    angles_to_ray,
    is_visible,
    optical_centre,
    pixel_to_angles,
    pixel_to_ray,
    point_to_angles,
    project,
)
from .linalg import null_space, scaled_null_space
from .plucker import (
    closest_point_to_origin,
    closest_points,
    horizontal_wall_line,
    intersect_coplanar_lines,
    line_from_point_direction,
    line_through_points,
    normalize_line,
    plucker_constraint,
    point_at,
    rotate_line_z,
    rotation_z,
    safe_norm,
    side,
    translate_line,
)

__all__ = [
    "NonCentralPanorama",
    "angles_to_pixel",
    "angles_to_ray",
    "closest_point_to_origin",
    "closest_points",
    "horizontal_wall_line",
    "intersect_coplanar_lines",
    "is_visible",
    "line_from_point_direction",
    "line_through_points",
    "normalize_line",
    "null_space",
    "optical_centre",
    "pixel_to_angles",
    "pixel_to_ray",
    "plucker_constraint",
    "point_at",
    "point_to_angles",
    "project",
    "rotate_line_z",
    "rotation_z",
    "safe_norm",
    "scaled_null_space",
    "side",
    "translate_line",
]
