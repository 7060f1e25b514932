"""The public API as a contract: the names ``ncjax`` exports, their signatures and defaults, and that the
documented array functions trace under ``jax.jit``, map under ``jax.vmap`` and differentiate under ``jax.grad``.

The pipeline's own jit/vmap/grad contract (``layout_from_boundaries`` batched, traced and differentiated)
is tested where its rooms are built, in tests/test_pipeline.py."""

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ncjax

# what the README, docs/design.md and the examples call at the top level
DOCUMENTED = [
    "NonCentralPanorama",
    "read_panorama",
    "predict_boundaries",
    "EdgeSnap",
    "HorizonNet",
    "HorizonNetConfig",
    "load_model",
    "save_model",
    "Rows",
    "fit_walls",
    "finish",
    "layout_from_boundaries",
    "Layout",
    "LayoutStatus",
    "HeightPrior",
    "PipelineConfig",
    "NETWORK_PIPELINE_CONFIG",
    "DEFAULT_WORLD",
    "reconstruct",
    "reconstruct_batch",
    "Reconstruction",
    "SynthConfig",
    "RoomConfig",
    "synthesize_batch",
    "train",
    "TrainConfig",
]
# the namespaces, one per stage, and what the docs call in each
NAMESPACES = {
    "geometry": ["pixel_to_angles", "angles_to_pixel", "pixel_to_ray", "angles_to_ray", "project", "side"],
    "solvers": ["solve_wall", "solve_horizontal_line", "solve_manhattan_layout", "solve_atlanta_layout"],
    "pipeline": ["fit_walls", "finish", "layout_from_boundaries", "PipelineConfig", "Rows", "Walls"],
    "network": ["predict_boundaries", "HorizonNet", "init_model", "snap_to_edges"],
    "io": [],
    "viz": [],
    "synth": ["random_room", "room_labels", "random_scene", "synthesize", "render", "write_dataset"],
    "evaluation": ["evaluate_layout", "network_table", "layout_metrics", "central_metrics"],
    "training": ["train", "TrainConfig", "horizonnet_loss"],
}


def test_every_exported_name_exists_once_and_is_documented():
    assert len(set(ncjax.__all__)) == len(ncjax.__all__) <= 30
    missing = [name for name in ncjax.__all__ if not hasattr(ncjax, name)]
    assert not missing
    assert set(DOCUMENTED) <= set(ncjax.__all__)
    undocumented = [
        name
        for name in ncjax.__all__
        if callable(getattr(ncjax, name)) and not (inspect.getdoc(getattr(ncjax, name)) or "").strip()
    ]
    assert not undocumented


@pytest.mark.parametrize("namespace", sorted(NAMESPACES))
def test_namespaces_hold_their_stage_s_names(namespace):
    module = getattr(ncjax, namespace)
    assert (inspect.getdoc(module) or "").strip(), namespace
    exported = getattr(module, "__all__", [])
    assert len(set(exported)) == len(exported)
    assert not [name for name in exported if not hasattr(module, name)]
    assert set(NAMESPACES[namespace]) <= set(exported) | {name for name in vars(module) if not name.startswith("_")}


def test_one_default_world_everywhere():
    assert ncjax.DEFAULT_WORLD == "auto"
    for function in (ncjax.layout_from_boundaries, ncjax.reconstruct, ncjax.reconstruct_batch):
        assert inspect.signature(function).parameters["world"].default == ncjax.DEFAULT_WORLD, function.__name__


def test_random_functions_take_the_key_first():
    for function in (
        ncjax.synth.random_room,
        ncjax.synth.random_scene,
        ncjax.synth.synthesize,
        ncjax.synth.synthesize_scene,
    ):
        first = next(iter(inspect.signature(function).parameters))
        assert first == "key", function.__name__
    assert next(iter(inspect.signature(ncjax.synthesize_batch).parameters)) == "keys"


@pytest.mark.parametrize(
    ("function", "parameters"),
    [
        (ncjax.layout_from_boundaries, ["ceiling_v", "floor_v", "corner_prob", "cam", "world", "config", "key"]),
        (ncjax.solvers.solve_wall, ["ceiling_rays", "floor_rays", "ceiling_mask", "floor_mask", "method"]),
        (ncjax.geometry.pixel_to_ray, ["cam", "u", "v"]),
        (ncjax.geometry.project, ["cam", "xyz"]),
        (ncjax.predict_boundaries, ["image", "model", "views", "edge_snap"]),
        (ncjax.fit_walls, ["rows", "cam", "prior", "key", "config", "world"]),
        (ncjax.finish, ["walls", "prior", "config", "world"]),
    ],
)
def test_documented_signatures(function, parameters):
    assert list(inspect.signature(function).parameters)[: len(parameters)] == parameters


CAM = ncjax.NonCentralPanorama(width=64, height=32, rc=0.3)


@pytest.mark.slow
def test_camera_maps_jit_vmap_and_grad():
    u = jnp.linspace(0.0, 63.0, 5)
    v = jnp.linspace(4.0, 28.0, 5)
    rays = jax.jit(ncjax.geometry.pixel_to_ray)(CAM, u, v)
    np.testing.assert_allclose(rays, ncjax.geometry.pixel_to_ray(CAM, u, v), atol=1e-6)
    np.testing.assert_allclose(jax.vmap(ncjax.geometry.pixel_to_ray, in_axes=(None, 0, 0))(CAM, u, v), rays, atol=1e-6)

    def row_of_point(rc):
        cam = ncjax.NonCentralPanorama(width=64, height=32, rc=rc)
        return ncjax.geometry.project(cam, jnp.array([2.0, 1.0, 1.2]))[1]

    gradient = jax.grad(row_of_point)(0.3)
    step = 1e-2
    finite_difference = (row_of_point(0.3 + step) - row_of_point(0.3 - step)) / (2 * step)
    assert np.isfinite(gradient) and gradient != 0
    np.testing.assert_allclose(gradient, finite_difference, rtol=2e-2)


def _wall_rays(ceiling_height):
    """Rays of 8 columns to the ceiling (at ``ceiling_height``) and floor lines of the wall y = 2."""
    columns = jnp.linspace(20.0, 44.0, 8)
    azimuth, _ = ncjax.geometry.pixel_to_angles(CAM, columns, jnp.zeros(8))
    centres = ncjax.geometry.optical_centre(CAM, columns)
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    distance = (2.0 - centres[:, 1]) / direction[:, 1]
    points = centres[:, :2] + distance[:, None] * direction

    def rays(height):
        xyz = jnp.concatenate([points, jnp.full((8, 1), height)], -1)
        return ncjax.geometry.line_through_points(centres, xyz)

    return rays(ceiling_height), rays(-1.4)


@pytest.mark.slow
def test_wall_solver_jit_vmap_and_grad():
    mask = jnp.ones(8, bool)
    ceiling, floor = _wall_rays(1.1)
    wall = jax.jit(ncjax.solvers.solve_wall)(ceiling, floor, mask, mask)
    assert bool(wall.ok)
    np.testing.assert_allclose([wall.ceiling_height, wall.floor_height], [1.1, -1.4], atol=1e-3)
    heights = jnp.array([1.0, 1.2])
    batched = jax.vmap(lambda h: ncjax.solvers.solve_wall(*_wall_rays(h), mask, mask).ceiling_height)(heights)
    np.testing.assert_allclose(batched, heights, atol=1e-3)
    gradient = jax.grad(lambda h: ncjax.solvers.solve_wall(*_wall_rays(h), mask, mask).ceiling_height)(1.1)
    np.testing.assert_allclose(gradient, 1.0, atol=1e-2)
