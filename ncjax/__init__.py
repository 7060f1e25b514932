"""ncjax: metric room layouts from single non-central circular panoramas, in JAX.

Modules mirror the paper's pipeline: the camera (Section 3), Plücker geometry
(Section 3.1), synthetic rooms with exact labels (Section 5.1).
"""

from ._camera import (
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
from ._plucker import (
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
from . import metrics
from ._rooms import (
    Room,
    RoomConfig,
    RoomLabels,
    RoomStatus,
    random_room,
    room_corners_3d,
    room_labels,
    room_walls,
)

# Synthetic data (paper Section 5.1): scenes, rendering, augmentation
from ._materials import Material, Pattern
from ._render import (
    RenderConfig,
    Rendering,
    Semantic,
    SynthConfig,
    render,
    synthesize,
    synthesize_batch,
    synthesize_scene,
)
from ._scene import Boxes, Lights, Openings, Scene, SceneConfig, random_scene

# Geometric solvers (paper Sections 4.1-4.3, 5.3)
from ._layout_solvers import (
    WallLayout,
    layout_corners,
    quarter_turn,
    ray_in_wall_frame,
    solve_atlanta_layout,
    solve_manhattan_layout,
)
from ._linalg import null_space, scaled_null_space
from ._wall import (
    HorizontalLine,
    Wall,
    solve_horizontal_line,
    solve_wall,
    solve_wall_minimal,
)

__version__ = "0.1.0"

__all__ = [
    "Boxes",
    "HorizontalLine",
    "Lights",
    "Material",
    "NonCentralPanorama",
    "Openings",
    "Pattern",
    "RenderConfig",
    "Rendering",
    "Room",
    "RoomConfig",
    "RoomLabels",
    "RoomStatus",
    "Scene",
    "SceneConfig",
    "Semantic",
    "SynthConfig",
    "Wall",
    "WallLayout",
    "angles_to_pixel",
    "angles_to_ray",
    "closest_point_to_origin",
    "closest_points",
    "horizontal_wall_line",
    "intersect_coplanar_lines",
    "is_visible",
    "layout_corners",
    "line_from_point_direction",
    "line_through_points",
    "metrics",
    "normalize_line",
    "null_space",
    "optical_centre",
    "pixel_to_angles",
    "pixel_to_ray",
    "plucker_constraint",
    "point_at",
    "point_to_angles",
    "project",
    "quarter_turn",
    "random_room",
    "random_scene",
    "ray_in_wall_frame",
    "render",
    "room_corners_3d",
    "room_labels",
    "room_walls",
    "rotate_line_z",
    "rotation_z",
    "safe_norm",
    "scaled_null_space",
    "side",
    "solve_atlanta_layout",
    "solve_horizontal_line",
    "solve_manhattan_layout",
    "solve_wall",
    "solve_wall_minimal",
    "synthesize",
    "synthesize_batch",
    "synthesize_scene",
    "translate_line",
]
