"""Synthetic rooms and their panoramas with exact labels (paper Section 5.1).

- ``rooms``: random Manhattan and Atlanta rooms and a camera inside; ``labels``: their exact labels.
- ``furniture``, ``scene``, ``materials``: furnished, lit scenes with procedural materials;
  ``placement``: rectangles in the plan, packed without overlap.
- ``decor``: the realistic scenes' decor (``SceneConfig(decor=True)``): ceiling lights and panels, decals,
  sunlight, open doors; ``elements``: the scenes' containers.
- ``render``, ``raycast``, ``render_details``: ray-cast non-central panoramas (RGB, depth, semantics).
- ``pathtrace``, ``pathtrace_scene``, ``pathtrace_bsdf``: path-traced panoramas of the same scenes (linear
  radiance: interreflections, area lights, the environment through openings, a rough-glossy floor);
  ``pathtrace_denoise``: their Monte Carlo noise filtered within each surface the camera's rays first meet;
  ``photograph``: a consumer 360-degree camera's photograph of such radiance; ``photoreal``: the two together, the
  RGB images of ``SynthConfig(photoreal=...)``; ``pathtrace_reference``: the same
  scenes in Mitsuba 3, the reference renderer (a development dependency, imported on use).
- ``augment``: photometric and sensor effects; ``dataset``: the dataset folders on disk.
"""

from .augment import AugmentConfig, add_sensor_noise, adjust_exposure, adjust_gamma, random_augment, white_balance
from .dataset import (
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
from .elements import Boxes, Lights, Openings
from .labels import RoomLabels, room_labels
from .materials import Material, Pattern
from .pathtrace import PathTraceConfig, path_trace
from .photograph import PhotographConfig, photograph
from .photoreal import PhotorealConfig, photoreal_image
from .render import (
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
from .rooms import Room, RoomConfig, RoomStatus, random_room, room_corners_3d, room_walls
from .scene import Scene, SceneConfig, random_scene

__all__ = [
    "add_sensor_noise",
    "adjust_exposure",
    "adjust_gamma",
    "AugmentConfig",
    "box_overflow",
    "Boxes",
    "DatasetSample",
    "labels_from_corners",
    "Lights",
    "list_samples",
    "Material",
    "Openings",
    "path_trace",
    "PathTraceConfig",
    "Pattern",
    "photograph",
    "PhotographConfig",
    "photoreal_image",
    "PhotorealConfig",
    "random_augment",
    "random_room",
    "random_scene",
    "rc_from_name",
    "read_dataset",
    "read_sample",
    "read_split",
    "render",
    "RenderConfig",
    "Rendering",
    "Room",
    "room_corners_3d",
    "room_labels",
    "room_walls",
    "RoomConfig",
    "RoomLabels",
    "RoomStatus",
    "sample_name",
    "Scene",
    "SceneConfig",
    "Semantic",
    "SynthConfig",
    "synthesize",
    "synthesize_batch",
    "synthesize_scene",
    "white_balance",
    "write_dataset",
]
