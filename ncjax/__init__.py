"""ncjax: metric room layouts from single non-central circular panoramas, in JAX.

The subpackages follow the data: ``geometry`` (camera, Plücker lines) -> ``network`` (panorama to
per-column boundaries) -> ``pipeline`` (boundaries to a metric layout, with ``solvers``) -> ``io`` and
``viz`` (files and pictures); ``synth`` and ``training`` make the network. Everything a user calls is
exported here; docs/architecture.md maps the stages and the paper's equations to the code.
"""

from . import metrics

# Camera and Plücker geometry (paper Section 3)
from .geometry.camera import (
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
from .geometry.plucker import (
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
from .geometry.linalg import null_space, scaled_null_space

# Wall and layout solvers (paper Sections 4.1-4.3, 5.3)
from .solvers.wall import (
    HorizontalLine,
    Wall,
    solve_horizontal_line,
    solve_horizontal_lines,
    solve_wall,
    solve_wall_minimal,
)
from .solvers.layout import (
    WallLayout,
    layout_corners,
    quarter_turn,
    ray_in_wall_frame,
    solve_atlanta_layout,
    solve_manhattan_layout,
)

# The network (paper Section "Non-central HorizonNet", Table netcorExp)
from .network.model import BoundaryPrediction, HorizonNet, HorizonNetConfig, count_parameters, init_model
from .network.checkpoint import load_model, save_model
from .network.predict import predict_boundaries
from .network.edges import EdgeSnap, snap_to_edges
from .network.denoise import gaussian_blur, to_greyscale
from .network.scores import boundary_pixel_error, corner_confusion, corner_scores, network_table

# The geometric pipeline (paper Section 4.4)
from .pipeline.config import DEFAULT_WORLD, PipelineConfig
from .pipeline.types import Layout, LayoutStatus
from .pipeline.prior import HeightPrior
from .pipeline.run import layout_from_boundaries

# The whole method: panorama -> network -> geometry (paper Fig. pipeline)
from .reconstruction import NETWORK_PIPELINE_CONFIG, Reconstruction, reconstruct, reconstruct_batch

# Synthetic rooms, scenes, renders and datasets (paper Section 5.1)
from .synth.rooms import Room, RoomConfig, RoomStatus, random_room, room_corners_3d, room_walls
from .synth.labels import RoomLabels, room_labels
from .synth.materials import Material, Pattern
from .synth.scene import Boxes, Lights, Openings, Scene, SceneConfig, random_scene
from .synth.render import (
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
from .synth.augment import (
    AugmentConfig,
    add_sensor_noise,
    adjust_exposure,
    adjust_gamma,
    random_augment,
    white_balance,
)
from .synth.dataset import (
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

# Training
from .training.loop import TrainConfig, horizonnet_loss, train

__version__ = "0.1.0"

__all__ = [
    "AugmentConfig",
    "BoundaryPrediction",
    "Boxes",
    "DEFAULT_WORLD",
    "DatasetSample",
    "EdgeSnap",
    "HorizonNet",
    "HorizonNetConfig",
    "HorizontalLine",
    "Layout",
    "LayoutStatus",
    "Lights",
    "Material",
    "NETWORK_PIPELINE_CONFIG",
    "NonCentralPanorama",
    "Openings",
    "Pattern",
    "PipelineConfig",
    "Reconstruction",
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
    "HeightPrior",
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
    "reconstruct",
    "reconstruct_batch",
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
    "snap_to_edges",
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
