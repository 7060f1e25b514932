"""The path tracer (ncjax.synth.pathtrace) against known physics: the furnace (a closed room of emitting,
reflecting surfaces), the inverse-square law of a small light, the environment seen through a window, the
patch of sunlight a window casts, the ray caster's and the room's analytic depths, and the GGX lobe's
normalisation and energy bound.

Every scene here is built by hand with the same capacities (8 walls, 6 boxes, 2 openings, 2 lights) and
every image has the same size, so that the path tracer compiles once per configuration."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ncjax
from ncjax.synth.elements import FRAME_WIDTH, Boxes, Lights, Openings
from ncjax.synth.materials import Material, Pattern
from ncjax.synth.pathtrace import PathTraceConfig, Sun, camera_ray, environment_radiance, path_trace
from ncjax.synth.pathtrace_bsdf import (
    ggx_brdf,
    ggx_pdf,
    ggx_sample,
    glossy_brdf,
    glossy_pdf,
    sample_cosine,
    sample_glossy,
    tangent_frame,
)
from ncjax.synth.pathtrace_scene import SurfaceKind, intersect
from ncjax.synth.render import synthesize_scene
from ncjax.synth.rooms import Room
from ncjax.synth.scene import Scene

HEIGHT, WIDTH = 16, 32
WALLS, BOXES, OPENINGS, LIGHTS = 8, 6, 2, 2
FLOOR, CEILING = -1.4, 1.2


def _paint(colour, count=None) -> Material:
    """A flat material of one albedo (both pattern colours equal, so the pattern does not show)."""
    colour = np.asarray(colour, np.float32)
    shape = () if count is None else (count,)
    return Material(
        pattern=np.full(shape, int(Pattern.PAINT), np.int32),
        colour_a=np.broadcast_to(colour, shape + (3,)),
        colour_b=np.broadcast_to(colour, shape + (3,)),
        scale=np.ones(shape, np.float32),
    )


def _scene(
    half=(2.0, 1.5),
    albedo=(0.0, 0.0, 0.0),
    floor_albedo=None,
    boxes=(),
    box_albedo=0.0,
    box_emission=0.0,
    windows=(),
    lights=(),
) -> Scene:
    """A rectangular room ``[-half_x, half_x] x [-half_y, half_y]`` between FLOOR and CEILING.

    Args:
        half: the room's half extents.
        albedo: of the walls and ceiling (and floor unless ``floor_albedo``).
        boxes: (centre (3,), half size (3,), yaw) per box, at most BOXES.
        box_albedo, box_emission: of every box.
        windows: (wall, start, end, bottom, top) per window, at most OPENINGS.
        lights: (position (3,), colour (3,)) per light, at most LIGHTS.
    """
    hx, hy = half
    corners = np.zeros((WALLS, 2), np.float32)
    corners[:4] = [[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]]
    room = Room(
        corners=corners,
        mask=np.arange(WALLS) < 4,
        ceiling_height=np.float32(CEILING),
        floor_height=np.float32(FLOOR),
        rc=np.float32(0.0),
        camera_position=np.array([0.3, -0.2, -FLOOR], np.float32),
        is_atlanta=np.bool_(False),
        status=np.int32(0),
    )
    centre, size, rotation = np.zeros((BOXES, 3)), np.ones((BOXES, 3)), np.tile([1.0, 0.0], (BOXES, 1))
    for i, (c, s, yaw) in enumerate(boxes):
        centre[i], size[i], rotation[i] = c, s, [math.cos(yaw), math.sin(yaw)]
    box_set = Boxes(
        centre=centre.astype(np.float32),
        half_size=size.astype(np.float32),
        rotation=rotation.astype(np.float32),
        material=_paint(np.full(3, box_albedo), BOXES),
        emission=np.full((BOXES, 3), box_emission, np.float32),
        mask=np.arange(BOXES) < len(boxes),
    )
    wall, span, z_range = np.zeros(OPENINGS, np.int32), np.zeros((OPENINGS, 2)), np.zeros((OPENINGS, 2))
    for i, (w, start, end, bottom, top) in enumerate(windows):
        wall[i], span[i], z_range[i] = w, [start, end], [bottom, top]
    openings = Openings(
        wall=wall,
        span=span.astype(np.float32),
        z_range=z_range.astype(np.float32),
        is_window=np.ones(OPENINGS, bool),
        colour=np.full((OPENINGS, 3), 0.8, np.float32),
        frame_colour=np.full((OPENINGS, 3), 0.9, np.float32),
        mask=np.arange(OPENINGS) < len(windows),
    )
    position, colour = np.zeros((LIGHTS, 3)), np.zeros((LIGHTS, 3))
    for i, (p, c) in enumerate(lights):
        position[i], colour[i] = p, c
    light_set = Lights(
        position=position.astype(np.float32), colour=colour.astype(np.float32), mask=np.arange(LIGHTS) < len(lights)
    )
    scene = Scene(
        room=room,
        boxes=box_set,
        openings=openings,
        lights=light_set,
        floor=_paint(albedo if floor_albedo is None else floor_albedo),
        ceiling=_paint(albedo),
        walls=_paint(albedo),
        skirting_height=np.float32(0.0),
        skirting_colour=np.zeros(3, np.float32),
        ambient=np.zeros(3, np.float32),
        ambient_direction=np.array([1.0, 0.0, 0.0], np.float32),
        seed=np.int32(7),
    )
    # The containers' annotations ask for JAX arrays (checked at run time in the tests).
    return jax.tree.map(jnp.asarray, scene)


_trace = jax.jit(path_trace, static_argnames="config")


def _camera(rc=0.0):
    return ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=rc)


def _pixel_rays(cam):
    """Origins and directions (H, W, 3) of the pixel centres."""
    v, u = jnp.meshgrid(jnp.arange(HEIGHT, dtype=jnp.float32), jnp.arange(WIDTH, dtype=jnp.float32), indexing="ij")
    return jax.vmap(jax.vmap(camera_ray, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(cam, u, v)


# ------------------------------------------------------------------ the furnace


@pytest.mark.slow
def test_furnace_closed_room_of_emitting_reflecting_surfaces():
    """Six emitting slabs line a closed room; every surface the camera (or a path) meets has albedo rho and
    emits Le, so each path of n bounces brings exactly ``Le (1 + rho + ... + rho^n)`` whatever its
    directions: the image is that constant, without noise. A wrong normal, a missed box or a wrong
    Lambertian weight darkens it (the room's own surfaces, behind the slabs, are black)."""
    rho, emission, bounces = 0.6, 0.5, 5
    slabs = [
        ((1.95, 0, 0), (0.1, 1.6, 1.5), 0.0),
        ((-1.95, 0, 0), (0.1, 1.6, 1.5), 0.0),
        ((0, 1.45, 0), (2.1, 0.1, 1.5), 0.0),
        ((0, -1.45, 0), (2.1, 0.1, 1.5), 0.0),
        ((0, 0, FLOOR + 0.05), (2.1, 1.6, 0.1), 0.0),
        ((0, 0, CEILING - 0.05), (2.1, 1.6, 0.1), 0.0),
    ]
    scene = _scene(boxes=slabs, box_albedo=rho, box_emission=emission)
    config = PathTraceConfig(samples_per_pixel=2, bounces=bounces, floor_specular=0.0)
    image = np.asarray(_trace(scene, _camera(0.3), jax.random.key(0), config))
    expected = emission * (1 - rho ** (bounces + 1)) / (1 - rho)
    np.testing.assert_allclose(image, expected, rtol=2e-4)


# ------------------------------------------------------------------ light and environment

_DIRECT = PathTraceConfig(samples_per_pixel=64, bounces=1, floor_specular=0.0, jitter=False)


@pytest.mark.slow
@pytest.mark.parametrize("specular", [0.0, 0.5])
def test_direct_light_of_a_small_area_light_follows_the_inverse_square_law(specular):
    """A black room with a floor of albedo rho and one small disc light (intensity I straight down): a floor
    point at distance r from it has radiance ``f I cos_light cos_floor / r^2``, ``f = rho / pi`` for a
    Lambertian floor, the glossy BRDF towards the light's centre for a glossy one."""
    rho, intensity = 0.7, np.array([3.0, 2.0, 1.0])
    light = np.array([0.4, -0.3, CEILING - 0.2])
    scene = _scene(half=(3.0, 3.0), floor_albedo=np.full(3, rho), lights=[(light, intensity)])
    cam = _camera(0.2)
    config = dataclasses.replace(_DIRECT, floor_specular=specular)
    image = np.asarray(_trace(scene, cam, jax.random.key(1), config))
    origin, direction = _pixel_rays(cam)
    hits = jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(scene, origin, direction)
    floor = np.asarray(hits.kind) == SurfaceKind.FLOOR
    offset = light - np.asarray(hits.point)
    r2 = np.sum(offset**2, -1)
    to_light = offset / np.sqrt(r2)[..., None]
    # The floor's local frame is the camera frame (normal +z).
    brdf = jax.vmap(jax.vmap(glossy_brdf, in_axes=(0, 0, None, None, None)), in_axes=(0, 0, None, None, None))(
        -direction, jnp.asarray(to_light, jnp.float32), jnp.full(3, rho), config.floor_roughness, specular
    )
    cosine = to_light[..., 2]  # the same for the floor's normal (+z) and the disc's (-z)
    expected = np.asarray(brdf) * intensity * (cosine**2 / r2)[..., None]
    assert floor.sum() > 100
    np.testing.assert_allclose(image[floor], expected[floor], rtol=2e-2)
    assert np.all(image[~floor] == 0)  # the room is black and the light is not in the geometry


@pytest.mark.slow
def test_environment_is_seen_through_a_window_and_lights_the_room():
    """Through a window's glass a ray reads the environment exactly (a constant colour, or a map at the
    ray's direction); the black room itself shows nothing but what the window lets in."""
    window = (0, 0.5, 2.5, -0.6, 0.8)  # wall 0 is x = 2, from y = -1.5 to 1.5
    scene = _scene(albedo=(0.5, 0.5, 0.5), windows=[window])
    cam = _camera(0.3)
    sky = np.array([0.2, 0.5, 1.0], np.float32)
    config = PathTraceConfig(samples_per_pixel=4, bounces=2, floor_specular=0.0, jitter=False)
    image = np.asarray(_trace(scene, cam, jax.random.key(2), config, sky))
    origin, direction = _pixel_rays(cam)
    hits = jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(scene, origin, direction)
    escaped = np.asarray(hits.kind) == SurfaceKind.ESCAPE
    assert escaped.sum() >= 4
    # The holes are the glass: inside the window's frame, on its wall's plane.
    point = np.asarray(hits.point)[escaped]
    np.testing.assert_allclose(point[:, 0], 2.0, atol=1e-5)
    assert np.all((np.abs(point[:, 1]) < 1.0 - 0.05) & (point[:, 2] > -0.6 + 0.05) & (point[:, 2] < 0.8 - 0.05))
    np.testing.assert_allclose(image[escaped], np.broadcast_to(sky, image[escaped].shape), rtol=1e-6)
    assert np.all(np.isfinite(image)) and np.mean(image[~escaped] > 0) > 0.1  # lit through the window

    # An equirectangular map: a smooth gradient, so that the bilinear read is the map's value.
    rows, columns = 32, 64
    v, u = np.meshgrid(np.arange(rows), np.arange(columns), indexing="ij")
    sky_map = np.stack([u / columns, v / rows, 0.5 + 0 * u], -1).astype(np.float32)
    sky_map = jnp.asarray(sky_map)
    image = np.asarray(_trace(scene, cam, jax.random.key(2), config, sky_map))
    read = jax.vmap(jax.vmap(environment_radiance, in_axes=(None, 0)), in_axes=(None, 0))(sky_map, direction)
    np.testing.assert_allclose(image[escaped], np.asarray(read)[escaped], rtol=1e-6)
    # The map's pixel centres are read exactly at their angles.
    cam_map = ncjax.NonCentralPanorama(columns, rows)
    row, column = 11, 40
    centre = np.asarray(camera_ray(cam_map, jnp.float32(column), jnp.float32(row))[1])
    np.testing.assert_allclose(environment_radiance(sky_map, jnp.asarray(centre)), sky_map[row, column], atol=1e-5)


def test_sunlight_through_a_window_lights_the_patch_it_casts():
    """A black room with a floor of albedo rho, one window and the sun: a floor point whose ray towards the sun
    leaves through the window's glass has radiance ``rho / pi E cos``, every other point is black (no other
    light, one bounce). Nothing random reaches the sun's light, so one path a pixel is exact."""
    rho, irradiance = 0.6, np.array([3.0, 2.5, 2.0], np.float32)
    window = (0, 0.5, 2.5, -0.9, 0.9)  # wall 0 is x = 2, from y = -1.5 to 1.5: the window spans y in [-1, 1]
    scene = _scene(floor_albedo=np.full(3, rho), windows=[window])
    towards = np.array([1.0, 0.3, 0.8]) / np.linalg.norm([1.0, 0.3, 0.8])
    sun = Sun(direction=jnp.asarray(towards, jnp.float32), irradiance=jnp.asarray(irradiance))
    cam = _camera(0.2)
    config = PathTraceConfig(samples_per_pixel=1, bounces=1, floor_specular=0.0, jitter=False)
    image = np.asarray(_trace(scene, cam, jax.random.key(3), config, None, sun))
    origin, direction = _pixel_rays(cam)
    hits = jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(scene, origin, direction)
    point = np.asarray(hits.point)
    # Where each point's ray towards the sun crosses the window's wall, and how far inside a pane that is (the
    # glass inside the frame, split by mullions 5 cm wide, upright in the middle and across at 0.6 of its height).
    to_wall = (2.0 - point[..., 0]) / towards[0]
    y, z = point[..., 1] + to_wall * towards[1], point[..., 2] + to_wall * towards[2]
    inside = np.minimum.reduce(
        [
            y - (-1.0 + FRAME_WIDTH),
            (1.0 - FRAME_WIDTH) - y,
            z - (-0.9 + FRAME_WIDTH),
            (0.9 - FRAME_WIDTH) - z,
            np.abs(y) - 0.025,
            np.abs(z - (-0.9 + 0.6 * 1.8)) - 0.025,
        ]
    )
    floor = np.asarray(hits.kind) == SurfaceKind.FLOOR
    lit, shaded = floor & (inside > 0.02), ~floor | (inside < -0.02)
    assert lit.sum() >= 8 and (floor & shaded).sum() >= 8
    expected = np.broadcast_to(rho / math.pi * irradiance * towards[2], image[lit].shape)
    np.testing.assert_allclose(image[lit], expected, rtol=1e-5)
    assert np.all(image[shaded] == 0)


@pytest.mark.slow
def test_sampling_the_holes_estimates_the_light_that_paths_find_by_chance():
    """The light through a window, sampled at every vertex or left to paths that leave through it by chance:
    the same mean radiance, with less noise; emissive boxes that do not light the room are still seen."""
    window = (0, -1.2, 1.2, -0.8, 0.9)
    box = ((-1.2, 0.0, CEILING - 0.05), (0.3, 0.3, 0.05), 0.0)
    scene = _scene(albedo=(0.6, 0.6, 0.6), windows=[window], boxes=[box], box_albedo=0.0, box_emission=3.0)
    cam = _camera(0.0)
    sky = jnp.array([1.0, 1.0, 1.0])
    config = PathTraceConfig(
        samples_per_pixel=64, bounces=2, floor_specular=0.0, jitter=False, emissive_boxes_light=False
    )
    sampled = [np.asarray(_trace(scene, cam, jax.random.key(k), config, sky)) for k in (0, 1)]
    chance = np.asarray(_trace(scene, cam, jax.random.key(0), dataclasses.replace(config, hole_sampling=False), sky))
    origin, direction = _pixel_rays(cam)
    hits = jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(scene, origin, direction)
    room = (np.asarray(hits.kind) != SurfaceKind.ESCAPE) & (np.asarray(hits.kind) != SurfaceKind.BOX)
    np.testing.assert_allclose(chance[room].mean(), sampled[0][room].mean(), rtol=0.05)
    # Two sampled images differ less than a chance image and a sampled one: the sampled noise is the lower.
    assert np.std(sampled[0][room] - sampled[1][room]) < np.std(chance[room] - sampled[1][room])
    seen = np.asarray(hits.kind) == SurfaceKind.BOX
    assert seen.any()
    np.testing.assert_allclose(sampled[0][seen], 3.0, rtol=1e-6)  # a black box: its emission alone


# ------------------------------------------------------------------ geometry


@pytest.mark.parametrize("rc", [0.0, 0.4])
def test_primary_hits_match_the_ray_caster_and_the_analytic_room(rc):
    """Depths of the pixel centres: an empty box room against its planes, and a furnished one (rotated
    boxes, a window) against the ray caster's depth, central and non-central."""
    cam = _camera(rc)
    origin, direction = _pixel_rays(cam)
    intersect_image = jax.jit(jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0)))
    empty = _scene()
    hits = intersect_image(empty, origin, direction)
    bounds = np.array([[-2.0, 2.0], [-1.5, 1.5], [FLOOR, CEILING]])
    with np.errstate(divide="ignore"):
        exits = (np.where(direction > 0, bounds[:, 1], bounds[:, 0]) - origin) / direction
    expected = np.min(np.where(np.isfinite(exits) & (exits > 0), exits, np.inf), -1)
    np.testing.assert_allclose(np.asarray(hits.distance), expected, rtol=2e-5, atol=2e-5)

    boxes = [
        ((1.0, 0.6, FLOOR + 0.4), (0.5, 0.3, 0.4), 0.4),
        ((-1.1, -0.7, FLOOR + 0.8), (0.3, 0.5, 0.8), -0.9),
        ((-0.8, 0.8, CEILING - 0.05), (0.2, 0.2, 0.05), 0.0),
        ((0.0, -1.0, FLOOR + 0.02), (0.8, 0.4, 0.02), 1.2),
    ]
    furnished = _scene(boxes=boxes, windows=[(0, 0.5, 2.5, -0.6, 0.8)])
    hits = intersect_image(furnished, origin, direction)
    rendering = jax.jit(ncjax.synth.render)(furnished, cam)
    np.testing.assert_allclose(np.asarray(hits.distance), np.asarray(rendering.depth), rtol=1e-4, atol=1e-4)
    on_box = np.asarray(hits.kind) == SurfaceKind.BOX
    assert on_box.sum() > 20
    np.testing.assert_array_equal(on_box, np.asarray(rendering.semantic) == ncjax.synth.Semantic.OBJECT)


# ------------------------------------------------------------------ rooms behind open doors

DOORS_HEIGHT, DOORS_WIDTH = 64, 128


def _room_with_open_doors(rc: float) -> Scene:
    """A realistic room whose doors all stand open, half of them wide passages, lit by an ambient light alone
    (its lamps, light panels and sun off)."""
    config = ncjax.synth.SynthConfig(
        room=ncjax.synth.RoomConfig(world="mix", rc_range=(rc, rc)),
        scene=ncjax.synth.SceneConfig(
            decor=True, door_probability=1.0, open_door_probability=1.0, passage_probability=0.5
        ),
    )
    scene, _ = jax.jit(synthesize_scene, static_argnums=1)(jax.random.key(2), config)
    decor = scene.decor
    dark = dict(
        lights=dataclasses.replace(scene.lights, mask=jnp.zeros_like(scene.lights.mask)),
        boxes=dataclasses.replace(scene.boxes, emission=jnp.zeros_like(scene.boxes.emission)),
        decor=dataclasses.replace(
            decor,
            panels=dataclasses.replace(decor.panels, mask=jnp.zeros_like(decor.panels.mask)),
            sun=dataclasses.replace(decor.sun, mask=jnp.zeros_like(decor.sun.mask)),
        ),
        ambient=jnp.array([0.5, 0.45, 0.4]),
    )
    return dataclasses.replace(scene, **dark)


@pytest.mark.parametrize("rc", [0.0, 0.4])
def test_rooms_behind_open_doors_are_the_ray_casters(rc):
    """Through an open door or passage a ray meets the ray caster's room behind it (the door's lining, then a
    box-shaped room) at the ray caster's depth, and, lit by the ray caster's ambient light, has its radiance:
    the same surfaces, materials, texture coordinates and shading (its tone curve undone)."""
    scene = _room_with_open_doors(rc)
    cam = ncjax.NonCentralPanorama(DOORS_WIDTH, DOORS_HEIGHT, rc=rc)
    v, u = jnp.meshgrid(
        jnp.arange(DOORS_HEIGHT, dtype=jnp.float32), jnp.arange(DOORS_WIDTH, dtype=jnp.float32), indexing="ij"
    )
    origin, direction = jax.vmap(jax.vmap(camera_ray, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(cam, u, v)
    hits = jax.jit(jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0)))(scene, origin, direction)
    rendering = jax.jit(ncjax.synth.render)(scene, cam)
    next_room = np.asarray(hits.kind) == SurfaceKind.NEXT_ROOM
    assert next_room.sum() > 500
    assert np.all(np.asarray(rendering.semantic)[next_room] == ncjax.synth.Semantic.OPENING)
    np.testing.assert_allclose(np.asarray(hits.distance), np.asarray(rendering.depth), rtol=1e-4, atol=1e-4)

    config = PathTraceConfig(samples_per_pixel=1, bounces=0, jitter=False, pixels_per_chunk=2048)
    image = _trace(scene, cam, jax.random.key(0), config, None, None, math.pi * scene.ambient)
    cast = np.asarray(rendering.rgb, np.float64)
    cast_radiance = -np.log1p(-(cast**2.2)) / 1.5  # the ray caster's tone curve undone
    np.testing.assert_allclose(np.asarray(image)[next_room], cast_radiance[next_room], rtol=2e-3, atol=1e-4)
    assert np.all(np.asarray(image)[~next_room] == 0)  # nothing else emits; no bounces


@pytest.mark.slow
def test_the_rooms_behind_open_doors_light_the_room_through_them():
    """The light of the rooms behind, sampled through their doors at every vertex or left to the paths that
    leave through them by chance: the same mean radiance."""
    scene = _room_with_open_doors(0.0)
    cam = _camera(0.0)
    config = PathTraceConfig(samples_per_pixel=64, bounces=2, jitter=False, emissive_boxes_light=False)
    light = math.pi * scene.ambient
    sampled = np.asarray(_trace(scene, cam, jax.random.key(0), config, None, None, light))
    chance = np.asarray(
        _trace(scene, cam, jax.random.key(1), dataclasses.replace(config, hole_sampling=False), None, None, light)
    )
    origin, direction = _pixel_rays(cam)
    hits = jax.vmap(jax.vmap(intersect, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))(scene, origin, direction)
    kind = np.asarray(hits.kind)
    room = (kind == SurfaceKind.FLOOR) | (kind == SurfaceKind.CEILING) | (kind == SurfaceKind.WALL)
    assert room.sum() > 100 and sampled[room].mean() > 0
    np.testing.assert_allclose(chance[room].mean(), sampled[room].mean(), rtol=0.05)


# ------------------------------------------------------------------ the GGX lobe


def _sphere_grid(n=1024):
    """Midpoint quadrature of the sphere in (cos theta, phi): directions (n, 2n, 3) and the cell's solid angle."""
    cos_theta = -1 + (np.arange(n) + 0.5) * 2 / n
    phi = (np.arange(2 * n) + 0.5) * math.pi / n
    c, p = np.meshgrid(cos_theta, phi, indexing="ij")
    s = np.sqrt(1 - c**2)
    return np.stack([s * np.cos(p), s * np.sin(p), c], -1).astype(np.float32), (2 / n) * (math.pi / n)


def _outgoing(theta):
    return jnp.array([math.sin(theta), 0.0, math.cos(theta)], jnp.float32)


@pytest.mark.parametrize("alpha", [0.15, 0.4, 0.8])
@pytest.mark.parametrize("theta", [0.0, 0.7, 1.3])
def test_ggx_pdf_integrates_to_one_and_its_white_furnace_is_at_most_one(alpha, theta):
    directions, cell = _sphere_grid()
    flat = jnp.asarray(directions.reshape(-1, 3))
    o = _outgoing(theta)
    pdf = jax.vmap(ggx_pdf, in_axes=(None, 0, None))(o, flat, alpha)
    np.testing.assert_allclose(float(jnp.sum(pdf)) * cell, 1.0, atol=3e-3)
    # White furnace: the lobe reflects at most what it receives. The missing part is the light masked or
    # shadowed by the microfacets, small for smooth lobes (60% lost at alpha = 0.8: single scattering only).
    albedo = jax.vmap(ggx_brdf, in_axes=(None, 0, None))(o, flat, alpha) * jnp.maximum(flat[:, 2], 0)
    albedo = float(jnp.sum(albedo)) * cell
    assert 0.0 < albedo <= 1.0 + 2e-3
    if alpha == 0.15 and theta < 1.0:
        assert albedo > 0.93
    # The sampler draws from that pdf: the mean of its weights f cos / pdf is the quadrature's albedo.
    uniform = jax.random.uniform(jax.random.key(3), (200000, 2))
    samples = jax.vmap(ggx_sample, in_axes=(None, None, 0))(o, alpha, uniform)
    weights = jax.vmap(
        lambda i: jnp.where(
            ggx_pdf(o, i, alpha) > 0, ggx_brdf(o, i, alpha) * jnp.maximum(i[2], 0) / ggx_pdf(o, i, alpha), 0
        )
    )(samples)
    np.testing.assert_allclose(float(jnp.mean(weights)), albedo, atol=5e-3)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(samples), axis=-1), 1.0, atol=1e-5)


@pytest.mark.slow
def test_glossy_floor_brdf_is_energy_bounded_and_sampled_consistently():
    directions, cell = _sphere_grid(512)
    flat = jnp.asarray(directions.reshape(-1, 3))
    white = jnp.ones(3)
    for theta in (0.2, 1.2):
        o = _outgoing(theta)
        pdf = jax.vmap(glossy_pdf, in_axes=(None, 0, None, None))(o, flat, 0.3, 0.4)
        np.testing.assert_allclose(float(jnp.sum(pdf)) * cell, 1.0, atol=3e-3)
        f = jax.vmap(glossy_brdf, in_axes=(None, 0, None, None, None))(o, flat, white, 0.3, 0.4)
        albedo = np.asarray(jnp.sum(f * jnp.maximum(flat[:, 2:], 0), 0)) * cell
        assert np.all(albedo <= 1.0 + 2e-3) and np.all(albedo > 0.9)
        uniform = jax.random.uniform(jax.random.key(4), (100000, 3))
        _, factor = jax.vmap(sample_glossy, in_axes=(None, None, None, None, 0))(o, white, 0.3, 0.4, uniform)
        np.testing.assert_allclose(np.asarray(jnp.mean(factor, 0)), albedo, atol=6e-3)
        assert float(jnp.max(factor)) <= 1.0 + 1e-5  # the mixed pdf bounds f cos / pdf by the lobes' G2 / G1


def test_cosine_sampling_and_tangent_frames():
    uniform = jax.random.uniform(jax.random.key(5), (4000, 2))
    local = jax.vmap(sample_cosine)(uniform)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(local), axis=-1), 1.0, atol=1e-5)
    assert np.all(np.asarray(local[:, 2]) >= 0)
    np.testing.assert_allclose(float(jnp.mean(local[:, 2])), 2 / 3, atol=1.5e-2)  # E[cos] under cos / pi
    normals = jax.random.normal(jax.random.key(6), (200, 3))
    normals = jnp.concatenate([normals, jnp.array([[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]])])
    normals = normals / jnp.linalg.norm(normals, axis=-1, keepdims=True)
    frames = np.asarray(jax.vmap(tangent_frame)(normals))
    np.testing.assert_allclose(frames @ frames.transpose(0, 2, 1), np.broadcast_to(np.eye(3), frames.shape), atol=1e-5)
    np.testing.assert_allclose(frames[:, 2], np.asarray(normals), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(frames), 1.0, atol=1e-5)


# ------------------------------------------------------------------ determinism and batching

_SMALL = PathTraceConfig(samples_per_pixel=2, bounces=2, pixels_per_chunk=200)


def _lit_scene(shift):
    return _scene(
        albedo=(0.6, 0.5, 0.4),
        boxes=[((0.8 + shift, 0.4, FLOOR + 0.4), (0.4, 0.3, 0.4), 0.3)],
        box_albedo=0.5,
        windows=[(1, 0.6, 2.0 + shift, -0.5, 0.7)],
        lights=[((0.0, shift, CEILING - 0.2), (2.0, 2.0, 2.0))],
    )


@pytest.mark.slow
def test_same_key_same_image_and_a_vmapped_batch_equals_single_renders():
    scenes = [_lit_scene(0.0), _lit_scene(0.3)]
    cam = _camera(0.25)
    keys = jax.random.split(jax.random.key(7), 2)
    sky = jnp.array([0.3, 0.4, 0.6])
    single = [np.asarray(_trace(s, cam, k, _SMALL, sky)) for s, k in zip(scenes, keys, strict=True)]
    np.testing.assert_array_equal(np.asarray(_trace(scenes[0], cam, keys[0], _SMALL, sky)), single[0])
    assert np.all(np.isfinite(single[0])) and single[0].mean() > 0
    assert not np.array_equal(np.asarray(_trace(scenes[0], cam, keys[1], _SMALL, sky)), single[0])
    batch = jax.tree.map(lambda *x: jnp.stack(x), *scenes)
    batched = jax.jit(jax.vmap(lambda scene, key: path_trace(scene, cam, key, _SMALL, sky)))(batch, keys)
    np.testing.assert_allclose(np.asarray(batched), np.stack(single), rtol=1e-5, atol=1e-6)
    # The image does not depend on how it is cut into chunks (one random stream per pixel).
    other = dataclasses.replace(_SMALL, pixels_per_chunk=512)
    np.testing.assert_allclose(np.asarray(_trace(scenes[0], cam, keys[0], other, sky)), single[0], rtol=1e-5, atol=1e-6)


def test_negative_environment_texels_bring_no_light():
    """A resampled HDR photograph rings below zero around the sun: such texels are dark, not negative light."""
    ringing = jnp.full((8, 16, 3), -5.0).at[2:5, ::2].set(2.0)
    directions = jax.random.normal(jax.random.key(0), (256, 3))
    directions = directions / jnp.linalg.norm(directions, axis=-1, keepdims=True)
    radiance = jax.vmap(environment_radiance, (None, 0))(ringing, directions)
    assert float(radiance.min()) == 0.0 and float(radiance.max()) > 0.0
    np.testing.assert_array_equal(environment_radiance(jnp.array([-1.0, 0.5, 2.0]), directions[0]), [0.0, 0.5, 2.0])


def test_configuration_rejects_bad_values():
    for bad in (
        dict(samples_per_pixel=0),
        dict(bounces=-1),
        dict(pixels_per_chunk=0),
        dict(floor_roughness=0.0),
        dict(floor_specular=1.5),
        dict(light_radius=-0.1),
    ):
        with pytest.raises(ValueError):
            PathTraceConfig(**bad)
