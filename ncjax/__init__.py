"""ncjax: metric room layouts from single non-central circular panoramas, in JAX.

Modules mirror the paper's pipeline: the camera (Section 3), Plücker geometry
(Section 3.1), synthetic rooms with exact labels, furnished scenes, their
rendering and the dataset files (Section 5.1).
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

# Synthetic data (paper Section 5.1): scenes, rendering, augmentation, dataset files
from ._augment import (
    AugmentConfig,
    add_sensor_noise,
    adjust_exposure,
    adjust_gamma,
    gaussian_blur,
    random_augment,
    to_greyscale,
    white_balance,
)
from ._dataset import (
    DatasetSample,
    labels_from_corners,
    list_samples,
    rc_from_name,
    read_dataset,
    read_sample,
    read_split,
    sample_name,
    write_dataset,
)
from ._materials import Material, Pattern
from ._render import (
    RenderConfig,
    Rendering,
    Semantic,
    SynthConfig,
    box_overflow,
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
    solve_horizontal_lines,
    solve_wall,
    solve_wall_minimal,
)

# Geometric pipeline (paper Section 4.4)
from ._pipeline import Layout, LayoutStatus, PipelineConfig, layout_from_boundaries

# Non-central HorizonNet (paper Section "Non-central HorizonNet", Table netcorExp)
from ._checkpoint import load_model, save_model
from ._network import (
    BoundaryPrediction,
    HorizonNet,
    HorizonNetConfig,
    count_parameters,
    init_model,
)
from ._network_metrics import boundary_pixel_error, corner_confusion, corner_scores, network_table
from ._predict import predict_boundaries
from ._edges import EdgeSnap, snap_to_edges
from ._train import TrainConfig, horizonnet_loss, train

# The whole method: panorama -> network -> geometry (paper Fig. pipeline)
from ._reconstruct import NETWORK_PIPELINE_CONFIG, Reconstruction, reconstruct, reconstruct_batch

__version__ = "0.1.0"

__all__ = [
    "AugmentConfig",
    "BoundaryPrediction",
    "Reconstruction",
    "Boxes",
    "DatasetSample",
    "HorizonNet",
    "HorizonNetConfig",
    "HorizontalLine",
    "Layout",
    "LayoutStatus",
    "Lights",
    "Material",
    "NonCentralPanorama",
    "Openings",
    "Pattern",
    "PipelineConfig",
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
    "TrainConfig",
    "Wall",
    "WallLayout",
    "add_sensor_noise",
    "adjust_exposure",
    "adjust_gamma",
    "angles_to_pixel",
    "angles_to_ray",
    "boundary_pixel_error",
    "box_overflow",
    "closest_point_to_origin",
    "closest_points",
    "corner_confusion",
    "corner_scores",
    "count_parameters",
    "gaussian_blur",
    "horizonnet_loss",
    "horizontal_wall_line",
    "init_model",
    "intersect_coplanar_lines",
    "is_visible",
    "labels_from_corners",
    "layout_corners",
    "layout_from_boundaries",
    "line_from_point_direction",
    "line_through_points",
    "list_samples",
    "load_model",
    "metrics",
    "network_table",
    "normalize_line",
    "null_space",
    "optical_centre",
    "pixel_to_angles",
    "pixel_to_ray",
    "plucker_constraint",
    "point_at",
    "point_to_angles",
    "predict_boundaries",
    "snap_to_edges",
    "EdgeSnap",
    "reconstruct",
    "NETWORK_PIPELINE_CONFIG",
    "reconstruct_batch",
    "project",
    "quarter_turn",
    "random_augment",
    "random_room",
    "random_scene",
    "ray_in_wall_frame",
    "rc_from_name",
    "read_dataset",
    "read_sample",
    "read_split",
    "render",
    "room_corners_3d",
    "room_labels",
    "room_walls",
    "rotate_line_z",
    "rotation_z",
    "safe_norm",
    "sample_name",
    "save_model",
    "scaled_null_space",
    "side",
    "solve_atlanta_layout",
    "solve_horizontal_line",
    "solve_horizontal_lines",
    "solve_manhattan_layout",
    "solve_wall",
    "solve_wall_minimal",
    "synthesize",
    "synthesize_batch",
    "synthesize_scene",
    "to_greyscale",
    "train",
    "translate_line",
    "white_balance",
    "write_dataset",
]
