"""Mitsuba 3 as the reference of the path tracer (:mod:`ncjax.synth.pathtrace`): the same scene and the same
camera rays, rendered by an independent, established renderer, so that both can be compared pixel by pixel.

Mitsuba is a development dependency only: it is imported inside the functions that need it, and nothing
that reconstructs a room depends on this module. Its ``scalar_rgb`` variant is used (no LLVM needed): one
ray at a time through Mitsuba's ``path`` integrator, given the rig's exact rays (rc = 0 or rc > 0), so that
no Mitsuba sensor has to model the non-central camera.

What both renderers support, and so what :func:`mitsuba_scene` translates:

- the room's walls (one rectangle per wall of the plan polygon, floor to ceiling) and its floor and ceiling
  (rectangles over the polygon's bounding box: in a closed room, what lies outside the walls is never
  reached), two-sided Lambertian as in ncjax;
- the boxes, rotated about z, two-sided Lambertian, emitting where their emission is non-zero;
- the ceiling lights as discs of radius ``light_radius`` facing down, one-sided area lights of radiance
  ``colour / (pi r^2)``, black on both sides. ncjax's lights are not in its geometry: Mitsuba's discs also
  block the paths that meet them and shade the ceiling around them, which the pixels near a light show
  (:func:`render_reference` marks them) and which darkens the rest of the image very slightly.

Surfaces must have one albedo each (flat materials, see :func:`flat_albedo`); windows, doors, skirting boards,
decor and the glossy floor are left out (rejected). Camera rays go through the pixels' centres (ncjax's
``jitter=False``), so both renderers average the same rays' paths.

Path lengths: ncjax's ``bounces = n`` holds light that reached the camera after at most n reflections, i.e.
paths of at most n + 1 segments; Mitsuba's ``max_depth`` counts segments (1: only emitters seen), so it is
``n + 1``. Russian roulette is switched off (it would be unbiased but noisier).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool, Float

from ..geometry.camera import NonCentralPanorama
from .elements import Boxes, Lights, Openings
from .materials import Material, Pattern
from .pathtrace import PathTraceConfig, camera_ray
from .rooms import Room
from .scene import Scene

# Mitsuba's variant: CPU, one ray at a time, no JIT compiler to install.
VARIANT = "scalar_rgb"
# Pixels whose ray meets the scene within this many disc radii of a light's centre are not comparable: Mitsuba's
# disc is seen there, or shades the ceiling around it (a disc that lies within a radius of the ceiling).
NEAR_LIGHT = 4.0


def flat_albedo(material: Material) -> np.ndarray:
    """The albedo of a material that has one colour everywhere (both pattern colours equal), (..., 3).

    Raises:
        ValueError: when the pattern's two colours differ (a texture, which the reference does not model).
    """
    colour_a, colour_b = np.asarray(material.colour_a), np.asarray(material.colour_b)
    if not np.array_equal(colour_a, colour_b):
        raise ValueError("the reference renders flat materials only (colour_a == colour_b)")
    return colour_a


def comparison_scene(
    half: tuple[float, float] = (2.0, 1.5),
    floor_height: float = -1.4,
    ceiling_height: float = 1.2,
    albedo: tuple[float, float, float] = (0.7, 0.7, 0.7),
    floor_albedo: tuple[float, float, float] = (0.5, 0.4, 0.3),
    boxes: tuple = (),
    box_albedo: tuple[float, float, float] = (0.3, 0.5, 0.7),
    lights: tuple = (),
) -> Scene:
    """A closed rectangular room ``[-half_x, half_x] x [-half_y, half_y]`` with flat materials: what both
    renderers model alike.

    Args:
        half: the room's half extents, metres.
        floor_height, ceiling_height: camera frame, metres.
        albedo: of the walls and the ceiling.
        floor_albedo: of the floor.
        boxes: (centre (3,), half size (3,), yaw) per box.
        box_albedo: of every box.
        lights: (position (3,), colour (3,)) per ceiling light.
    """
    hx, hy = half
    room = Room(
        corners=jnp.array([[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]], jnp.float32),
        mask=jnp.ones(4, bool),
        ceiling_height=jnp.float32(ceiling_height),
        floor_height=jnp.float32(floor_height),
        rc=jnp.float32(0.0),
        camera_position=jnp.array([hx, hy, -floor_height], jnp.float32),
        is_atlanta=jnp.bool_(False),
        status=jnp.int32(0),
    )
    count = max(len(boxes), 1)
    centre, size, rotation = np.zeros((count, 3)), np.ones((count, 3)), np.tile([1.0, 0.0], (count, 1))
    for i, (c, s, yaw) in enumerate(boxes):
        centre[i], size[i], rotation[i] = c, s, [math.cos(yaw), math.sin(yaw)]
    box_set = Boxes(
        centre=jnp.asarray(centre, jnp.float32),
        half_size=jnp.asarray(size, jnp.float32),
        rotation=jnp.asarray(rotation, jnp.float32),
        material=_paint(box_albedo, count),
        emission=jnp.zeros((count, 3), jnp.float32),
        mask=jnp.arange(count) < len(boxes),
    )
    openings = Openings(
        wall=jnp.zeros(1, jnp.int32),
        span=jnp.zeros((1, 2), jnp.float32),
        z_range=jnp.zeros((1, 2), jnp.float32),
        is_window=jnp.zeros(1, bool),
        colour=jnp.zeros((1, 3), jnp.float32),
        frame_colour=jnp.zeros((1, 3), jnp.float32),
        mask=jnp.zeros(1, bool),
    )
    count = max(len(lights), 1)
    position, colour = np.zeros((count, 3)), np.zeros((count, 3))
    for i, (p, c) in enumerate(lights):
        position[i], colour[i] = p, c
    light_set = Lights(
        position=jnp.asarray(position, jnp.float32),
        colour=jnp.asarray(colour, jnp.float32),
        mask=jnp.arange(count) < len(lights),
    )
    return Scene(
        room=room,
        boxes=box_set,
        openings=openings,
        lights=light_set,
        floor=_paint(floor_albedo),
        ceiling=_paint(albedo),
        walls=_paint(albedo),
        skirting_height=jnp.float32(0.0),
        skirting_colour=jnp.zeros(3, jnp.float32),
        ambient=jnp.zeros(3, jnp.float32),
        ambient_direction=jnp.array([1.0, 0.0, 0.0], jnp.float32),
        seed=jnp.int32(0),
    )


def _paint(colour, count: int | None = None) -> Material:
    """A flat material: both pattern colours equal, so the pattern does not show."""
    shape = () if count is None else (count,)
    colour = jnp.broadcast_to(jnp.asarray(colour, jnp.float32), shape + (3,))
    return Material(
        pattern=jnp.full(shape, int(Pattern.PAINT), jnp.int32),
        colour_a=colour,
        colour_b=colour,
        scale=jnp.ones(shape, jnp.float32),
    )


def _check_supported(scene: Scene, config: PathTraceConfig) -> None:
    """Raise ValueError for what the reference does not model."""
    if scene.decor is not None:
        raise ValueError("the reference renders basic scenes only (no decor)")
    if np.any(np.asarray(scene.openings.mask)):
        raise ValueError("the reference renders closed rooms only (no doors or windows)")
    if float(scene.skirting_height) > 0:
        raise ValueError("the reference renders rooms without skirting boards")
    if config.floor_specular > 0:
        raise ValueError("the reference renders Lambertian floors only (floor_specular = 0)")
    if config.light_radius <= 0:
        raise ValueError("the reference needs area lights (light_radius > 0)")
    if config.jitter:
        raise ValueError("the reference traces the pixels' centres (jitter = False)")
    if not config.emissive_boxes_light and np.any(np.asarray(scene.boxes.emission)[np.asarray(scene.boxes.mask)] > 0):
        raise ValueError("the reference lets emissive boxes light the scene (emissive_boxes_light = True)")


def _lambertian(albedo) -> dict:
    """A two-sided Lambertian BSDF (Mitsuba's diffuse BSDF is black from behind; ncjax's surfaces are not)."""
    reflectance = {"type": "rgb", "value": [float(c) for c in albedo]}
    return {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance": reflectance}}


def _frame(x_axis, y_axis, z_axis, centre) -> list[list[float]]:
    """The 4x4 matrix taking Mitsuba's unit shapes ([-1, 1]^2 rectangles, [-1, 1]^3 cubes) to the world."""
    matrix = np.eye(4)
    matrix[:3, 0], matrix[:3, 1], matrix[:3, 2], matrix[:3, 3] = x_axis, y_axis, z_axis, centre
    return matrix.tolist()


def _room_shapes(room: Room, walls: np.ndarray, floor: np.ndarray, ceiling: np.ndarray) -> dict:
    """Mitsuba's rectangles of the walls (floor to ceiling, one per edge of the plan) and of the floor and
    ceiling (over the plan's bounding box)."""
    import mitsuba as mi

    corners = np.asarray(room.corners, np.float64)[np.asarray(room.mask)]
    bottom, top = float(room.floor_height), float(room.ceiling_height)
    half_height = 0.5 * (top - bottom)
    shapes = {}
    for i, start in enumerate(corners):
        end = corners[(i + 1) % len(corners)]
        half_edge = 0.5 * (end - start)
        normal = np.array([-half_edge[1], half_edge[0], 0.0]) / np.linalg.norm(half_edge)
        centre = np.append(0.5 * (start + end), 0.5 * (top + bottom))
        matrix = _frame(np.append(half_edge, 0.0), [0.0, 0.0, half_height], normal, centre)
        shapes[f"wall_{i}"] = {
            "type": "rectangle",
            "to_world": mi.ScalarTransform4f(matrix),
            "bsdf": _lambertian(walls),
        }
    low, high = corners.min(0), corners.max(0)
    half_plan, middle = 0.5 * (high - low) + 0.01, 0.5 * (high + low)
    for name, height, albedo in (("floor", bottom, floor), ("ceiling", top, ceiling)):
        matrix = _frame([half_plan[0], 0, 0], [0, half_plan[1], 0], [0, 0, 1], np.append(middle, height))
        shapes[name] = {"type": "rectangle", "to_world": mi.ScalarTransform4f(matrix), "bsdf": _lambertian(albedo)}
    return shapes


def _box_shapes(boxes: Boxes) -> dict:
    """Mitsuba's cubes of the boxes, with an area emitter where a box emits."""
    import mitsuba as mi

    albedo = flat_albedo(boxes.material)
    shapes = {}
    for i in np.flatnonzero(np.asarray(boxes.mask)):
        (cos, sin), half_size = np.asarray(boxes.rotation[i], np.float64), np.asarray(boxes.half_size[i], np.float64)
        matrix = _frame(
            half_size[0] * np.array([cos, sin, 0.0]),
            half_size[1] * np.array([-sin, cos, 0.0]),
            [0.0, 0.0, half_size[2]],
            np.asarray(boxes.centre[i], np.float64),
        )
        shape = {"type": "cube", "to_world": mi.ScalarTransform4f(matrix), "bsdf": _lambertian(albedo[i])}
        emission = np.asarray(boxes.emission[i], np.float64)
        if np.any(emission > 0):
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": emission.tolist()}}
        shapes[f"box_{i}"] = shape
    return shapes


def _light_shapes(lights: Lights, radius: float) -> dict:
    """Mitsuba's discs of the ceiling lights: facing down, radiance ``colour / (pi r^2)``, black."""
    import mitsuba as mi

    shapes = {}
    for i in np.flatnonzero(np.asarray(lights.mask)):
        colour = np.asarray(lights.colour[i], np.float64)
        if not np.any(colour > 0):
            continue
        # The disc's normal is its local +z: the x axis mirrored too keeps the frame right-handed.
        matrix = _frame([-radius, 0.0, 0.0], [0.0, radius, 0.0], [0.0, 0.0, -1.0], np.asarray(lights.position[i]))
        radiance = (colour / (math.pi * radius**2)).tolist()
        shapes[f"light_{i}"] = {
            "type": "disk",
            "to_world": mi.ScalarTransform4f(matrix),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": radiance}},
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}},
        }
    return shapes


def mitsuba_scene(scene: Scene, config: PathTraceConfig):
    """The Mitsuba scene (``scalar_rgb``) of one ncjax scene, with the ``path`` integrator of the same path
    lengths (``max_depth = bounces + 1``, see the module's docstring).

    Args:
        scene: one scene (camera frame), with flat materials.
        config: the path tracer's settings: ``bounces`` and ``light_radius`` are used; the others must be
            those the reference models (``floor_specular = 0``, ``jitter = False``).

    Raises:
        ValueError: for what the reference does not model (see the module's docstring).
    """
    import mitsuba as mi

    mi.set_variant(VARIANT)
    _check_supported(scene, config)
    max_depth = config.bounces + 1
    description = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": max_depth + 1},
        **_room_shapes(scene.room, flat_albedo(scene.walls), flat_albedo(scene.floor), flat_albedo(scene.ceiling)),
        **_box_shapes(scene.boxes),
        **_light_shapes(scene.lights, config.light_radius),
    }
    return mi.load_dict(description)


def pixel_rays(cam: NonCentralPanorama) -> tuple[Float[np.ndarray, "H W 3"], Float[np.ndarray, "H W 3"]]:
    """The origins and unit directions of the pixels' centres, as the path tracer casts them
    (:func:`~ncjax.synth.pathtrace.camera_ray`)."""
    v, u = jnp.meshgrid(
        jnp.arange(cam.height, dtype=jnp.float32), jnp.arange(cam.width, dtype=jnp.float32), indexing="ij"
    )
    rays = jax.vmap(jax.vmap(camera_ray, in_axes=(None, 0, 0)), in_axes=(None, 0, 0))
    origin, direction = rays(cam, u, v)
    return np.asarray(origin, np.float64), np.asarray(direction, np.float64)


def render_reference(
    scene: Scene, cam: NonCentralPanorama, config: PathTraceConfig, samples_per_pixel: int, seed: int
) -> tuple[Float[np.ndarray, "H W 3"], Bool[np.ndarray, "H W"]]:
    """Mitsuba's radiance of the camera's pixels: ``samples_per_pixel`` paths along each pixel's centre ray.

    Args:
        scene, config: see :func:`mitsuba_scene` (``config.samples_per_pixel`` is not used).
        cam: the panorama; its rays are :func:`pixel_rays` (the path tracer's).
        samples_per_pixel: paths averaged per pixel.
        seed: of Mitsuba's sampler: different seeds give independent images.

    Returns:
        ``(radiance, near_light)``: (H, W, 3) linear radiance, and (H, W) where the centre ray first meets the
        scene within :data:`NEAR_LIGHT` disc radii of a light's centre, to be left out of comparisons: there
        Mitsuba's disc is seen, or shades the ceiling just above it, and ncjax's light has no body.
    """
    import mitsuba as mi

    reference = mitsuba_scene(scene, config)
    integrator = reference.integrator()
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed)
    origins, directions = pixel_rays(cam)
    lights = np.asarray(scene.lights.position)[np.asarray(scene.lights.mask)]
    radiance = np.zeros(origins.shape)
    near_light = np.zeros(origins.shape[:2], bool)
    for row, column in np.ndindex(*origins.shape[:2]):
        ray = mi.Ray3f(mi.Point3f(*origins[row, column]), mi.Vector3f(*directions[row, column]))
        point = np.array(reference.ray_intersect(ray).p)
        near_light[row, column] = np.any(np.linalg.norm(lights - point, axis=-1) < NEAR_LIGHT * config.light_radius)
        total = mi.Color3f(0.0)
        for _ in range(samples_per_pixel):
            value, _, _ = integrator.sample(reference, sampler, ray)
            total += value
            sampler.advance()
        radiance[row, column] = np.array(total) / samples_per_pixel
    return radiance, near_light


def mean_and_error(
    batches: Float[np.ndarray, "K H W *channel"],
) -> tuple[Float[np.ndarray, "H W *channel"], Float[np.ndarray, "H W *channel"]]:
    """The mean of K independent images (K >= 2; radiance or one channel) and its standard error, from their
    spread."""
    batches = np.asarray(batches, np.float64)
    return batches.mean(0), batches.std(0, ddof=1) / math.sqrt(batches.shape[0])


def agreement(
    mean_a: Float[np.ndarray, "H W 3"],
    error_a: Float[np.ndarray, "H W 3"],
    mean_b: Float[np.ndarray, "H W 3"],
    error_b: Float[np.ndarray, "H W 3"],
    valid: Bool[np.ndarray, "H W"],
) -> dict[str, float]:
    """Agreement of two Monte Carlo images of the same pixels, over the ``valid`` pixels.

    Returns:
        ``within_3_sigma``: share of pixel channels whose difference is within 3 combined standard errors
        ``sqrt(error_a^2 + error_b^2)`` (about 0.99 for unbiased estimates with well-estimated errors);
        ``z_rms``: the root mean square of those normalised differences (about 1);
        ``mean_ratio``: the ratio of the image means ``a / b``;
        ``mean_relative_difference``: the mean over pixel channels of ``|a - b| / ((a + b) / 2)``;
        ``relative_noise``: what the noise alone makes of it: the mean over pixel channels of the expected
        ``|a - b|`` of a normal difference, ``sqrt(2 / pi)`` combined standard errors, over the same mean.
    """
    a, b = mean_a[valid], mean_b[valid]
    combined = np.sqrt(error_a[valid] ** 2 + error_b[valid] ** 2)
    z = (a - b) / np.maximum(combined, 1e-12)
    middle = np.maximum(0.5 * (a + b), 1e-12)
    return {
        "within_3_sigma": float(np.mean(np.abs(z) < 3)),
        "z_rms": float(np.sqrt(np.mean(z**2))),
        "mean_ratio": float(a.mean() / b.mean()),
        "mean_relative_difference": float(np.mean(np.abs(a - b) / middle)),
        "relative_noise": float(np.mean(math.sqrt(2 / math.pi) * combined / middle)),
    }
