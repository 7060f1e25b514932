"""A Monte Carlo path tracer for the synthetic scenes, in pure JAX: linear radiance panoramas with
interreflections, soft shadows and a rough-glossy floor, for the scenes :mod:`ncjax.synth.scene` builds.

The ray caster (:mod:`ncjax.synth.render`) shades each hit locally; here every pixel averages light paths:

- Geometry: :func:`~ncjax.synth.pathtrace_scene.intersect` (the room's prism, the boxes, holes in the walls
  where windows and open doors are, the rooms behind those doors), with the ray caster's materials and colours.
- Light: the scene's ceiling lights become small area lights, discs of radius ``light_radius`` facing down
  at the lights' positions, whose radiance ``colour / (pi r^2)`` gives them the point light's intensity
  ``colour`` straight down (and ``colour cos`` at an angle, as any Lambertian emitter). They are sampled by
  area at every path vertex (next-event estimation with a shadow ray); they are not in the geometry, so a
  path's own bounces never meet them and no light is counted twice. The environment lights the room
  through the windows' glass, and with decor the rooms behind open doors (seen, lit as the ray caster lights
  them: paths end there)
  light it through the doors: both are sampled at every vertex (a uniform point of a hole, by area, and the
  light that arrives through it); a path that leaves the room after a reflection then adds nothing. The
  sun, optionally, is a directional light (:class:`Sun`) sampled at every vertex too: a shadow ray towards it
  that leaves the room through a window's glass brings its irradiance, so a window casts its patch of
  sunlight on the floor and walls. Emissive surfaces (the lamps' shades; with decor, the light panels) are
  seen, and light the scene through the bounces unless ``PathTraceConfig.emissive_boxes_light`` is False:
  the ceiling light under each of them then stands for its light alone, and paths that find a small bright
  shade by chance make no speckle.
- Surfaces: Lambertian with the material's albedo; the room's floor has a GGX lobe over its diffuse base
  (:mod:`ncjax.synth.pathtrace_bsdf`). Directions are drawn by importance (cosine, visible normals).
- Paths have a fixed number of bounces (static), so every path of a batch does the same work in lock-step;
  with ``bounces = n`` the image holds all light that reached the camera after at most n reflections.

Each function is written for ONE ray or pixel and batched with ``jax.vmap``; :func:`path_trace` renders
a panorama chunk by chunk (``jax.lax.map``) so that memory stays bounded. Random numbers come only from the
key, one stream per pixel (``fold_in`` of its index), so an image does not depend on the chunk size.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama, angles_to_pixel, optical_centre, pixel_to_ray
from ..geometry.fastmath import arctan2
from ..geometry.polygon import perpendicular
from .elements import FRAME_WIDTH
from .pathtrace_bsdf import glossy_brdf, sample_cosine, sample_glossy, tangent_frame
from .pathtrace_scene import (
    Hit,
    SurfaceKind,
    intersect,
    leaves_through_a_window,
    next_room_radiance,
    surface_appearance,
    surface_emission,
)
from .rooms import room_walls
from .scene import Scene

# How far a new ray starts off the surface it leaves (metres): clear of float32 rounding at room scale.
_OFFSET = 1e-4
# Uniform numbers a path draws: 2 for the pixel position, then per bounce 3 for the light sample, 3 for the
# hole sample and 3 for the reflection.
_PER_BOUNCE = 9


@dataclasses.dataclass(frozen=True)
class PathTraceConfig:
    """Static settings of :func:`path_trace` (hashable: a jit static argument).

    Attributes:
        samples_per_pixel: paths averaged per pixel.
        bounces: reflections per path (0: only what emits is seen).
        pixels_per_chunk: pixels traced together (bounds memory: a chunk holds
            ``pixels_per_chunk * samples_per_pixel`` paths, each testing every wall and box).
        light_radius: radius of the ceiling lights' discs, metres.
        floor_roughness: GGX ``alpha`` of the floor's glossy lobe.
        floor_specular: weight of that lobe over the diffuse base, in [0, 1] (0: a Lambertian floor).
        jitter: spread each pixel's paths uniformly over its area (antialiasing); False traces its centre.
        hole_sampling: sample the light through the holes (the environment's through windows' glass, the rooms
            behind's through open doors) at every path vertex (next-event estimation); False leaves it to the
            paths that leave the room by chance.
        emissive_boxes_light: emissive surfaces light the scene through the paths' bounces; False: they are
            only seen (by camera rays), and the ceiling lights alone light the room.
    """

    samples_per_pixel: int = 16
    bounces: int = 4
    pixels_per_chunk: int = 1024
    light_radius: float = 0.05
    floor_roughness: float = 0.3
    floor_specular: float = 0.1
    jitter: bool = True
    hole_sampling: bool = True
    emissive_boxes_light: bool = True

    def __post_init__(self):
        for name in ("samples_per_pixel", "pixels_per_chunk"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if int(self.bounces) != self.bounces or self.bounces < 0:
            raise ValueError(f"bounces must be an integer >= 0, got {self.bounces!r}")
        if not self.light_radius >= 0:
            raise ValueError(f"light_radius must be >= 0, got {self.light_radius}")
        if not 0 < self.floor_roughness <= 1:
            raise ValueError(f"floor_roughness must be in (0, 1], got {self.floor_roughness}")
        if not 0 <= self.floor_specular <= 1:
            raise ValueError(f"floor_specular must be in [0, 1], got {self.floor_specular}")


class Sun(eqx.Module):
    """A directional light seen through the windows (all fields traced).

    Attributes:
        direction: (3,) unit direction towards the sun, camera frame.
        irradiance: (3,) the sun's irradiance on a surface facing it (its radiance integrated over its disc);
            0 for none.
    """

    direction: Float[Array, 3]
    irradiance: Float[Array, 3]


def environment_radiance(
    environment: Float[Array, "He We 3"] | Float[Array, 3], direction: Float[Array, 3]
) -> Float[Array, 3]:
    """Radiance arriving from far away along ``-direction`` (a ray travelling along ``direction``).

    Args:
        environment: an equirectangular map (He, We, 3) in the panorama's own pixel<->angle convention
            (:func:`~ncjax.geometry.camera.angles_to_pixel` of a full central panorama of that size: azimuth
            decreasing to the right, the top row looking up), read bilinearly, wrapping around in azimuth;
            or a constant colour (3,). Negative values count as 0: no light is negative, but a resampled HDR
            photograph's texels ring below zero around the sun.
        direction: (3,) unit direction of the ray.
    """
    if environment.ndim == 1:
        return jnp.maximum(environment, 0.0)
    rows, columns = environment.shape[:2]
    azimuth = arctan2(direction[1], direction[0])
    elevation = arctan2(direction[2], jnp.sqrt(direction[0] ** 2 + direction[1] ** 2))
    u, v = angles_to_pixel(NonCentralPanorama(width=columns, height=rows), azimuth, elevation)
    u0, v0 = jnp.floor(u), jnp.floor(v)
    fu, fv = u - u0, v - v0
    column = (u0.astype(jnp.int32) + jnp.arange(2)) % columns
    row = jnp.clip(v0.astype(jnp.int32) + jnp.arange(2), 0, rows - 1)
    texels = jnp.maximum(environment[row[:, None], column[None, :]], 0.0)  # (2, 2, 3)
    weights = jnp.stack([1 - fv, fv])[:, None] * jnp.stack([1 - fu, fu])[None, :]
    return jnp.sum(weights[..., None] * texels, (0, 1))


def sample_light(
    scene: Scene, point: Float[Array, 3], uniform: Float[Array, 3], radius: float
) -> tuple[Float[Array, 3], Float[Array, ""], Float[Array, 3]]:
    """Next-event estimation towards the ceiling lights: one light chosen in proportion to its power, a
    point of its disc (facing down) chosen uniformly by area.

    Returns:
        ``(direction, distance, intensity)``: the unit direction from ``point`` to the light's point, its
        distance, and the light's contribution before the receiver's BRDF, cosine and visibility:
        ``Le cos_light / distance^2 / pdf_area / P(light)`` with ``Le = colour / (pi r^2)`` and
        ``pdf_area = 1 / (pi r^2)``, i.e. ``colour cos_light / (distance^2 P(light))``. Zero without lights.
    """
    lights = scene.lights
    power = jnp.where(lights.mask, jnp.sum(lights.colour, -1), 0.0)
    total = jnp.sum(power)
    cumulative = jnp.cumsum(power) / jnp.maximum(total, 1e-30)
    index = jnp.minimum(jnp.sum(cumulative <= uniform[0]), power.shape[0] - 1)
    chance = power[index] / jnp.maximum(total, 1e-30)
    offset_radius, angle = radius * jnp.sqrt(uniform[1]), 2.0 * math.pi * uniform[2]
    target = lights.position[index] + jnp.stack([offset_radius * jnp.cos(angle), offset_radius * jnp.sin(angle), 0.0])
    offset = target - point
    distance = jnp.maximum(jnp.linalg.norm(offset), 1e-6)
    direction = offset / distance
    # The disc faces down: the light leaves it at angle theta from -z, and cos(theta) is the direction's z.
    cos_light = jnp.maximum(direction[2], 0.0)
    scale = jnp.where(chance > 0, cos_light / (distance**2 * jnp.maximum(chance, 1e-30)), 0.0)
    return direction, distance, scale * lights.colour[index]


def sample_hole(
    scene: Scene, point: Float[Array, 3], uniform: Float[Array, 3]
) -> tuple[Float[Array, 3], Float[Array, ""], Float[Array, ""]]:
    """Next-event estimation towards the holes in the walls: one hole (a window's glass inside its frame;
    with decor, an open door's aperture) chosen in proportion to its area, a point of it chosen uniformly
    by area.

    Returns:
        ``(direction, distance, scale)``: the unit direction from ``point`` to the hole's point, its distance,
        and the factor on the environment's radiance in that direction before the receiver's BRDF, cosine and
        visibility: ``cos_hole / distance^2 / pdf_area / P(hole)``, i.e. ``cos_hole A / distance^2`` with
        ``A`` the area of all holes. Zero without holes.
    """
    openings = scene.openings
    wall_direction, _, _, _ = room_walls(scene.room)
    width = jnp.maximum(openings.span[:, 1] - openings.span[:, 0] - 2 * FRAME_WIDTH, 0.0)
    # A window's glass is inside its frame on all four sides, a door's aperture on three (none at the sill).
    sill = jnp.where(openings.is_window, FRAME_WIDTH, 0.0)
    tall = jnp.maximum(openings.z_range[:, 1] - openings.z_range[:, 0] - FRAME_WIDTH - sill, 0.0)
    is_hole = openings.is_window
    if scene.decor is not None:
        is_hole = is_hole | scene.decor.doorways.is_open
    area = jnp.where(openings.mask & is_hole, width * tall, 0.0)
    total = jnp.sum(area)
    cumulative = jnp.cumsum(area) / jnp.maximum(total, 1e-30)
    index = jnp.minimum(jnp.sum(cumulative <= uniform[0]), area.shape[0] - 1)
    wall = openings.wall[index]
    along = openings.span[index, 0] + FRAME_WIDTH + uniform[1] * width[index]
    target = jnp.append(
        scene.room.corners[wall] + along * wall_direction[wall],
        openings.z_range[index, 0] + sill[index] + uniform[2] * tall[index],
    )
    offset = target - point
    distance = jnp.maximum(jnp.linalg.norm(offset), 1e-6)
    direction = offset / distance
    cos_hole = jnp.abs(jnp.dot(direction[:2], perpendicular(wall_direction[wall])))
    return direction, distance, jnp.where(total > 0, cos_hole * total / distance**2, 0.0)


def _arriving(
    scene: Scene,
    hit: Hit,
    direction: Float[Array, 3],
    environment: Float[Array, "He We 3"] | Float[Array, 3],
    next_room: Float[Array, 3],
    seen: bool,
) -> Float[Array, 3]:
    """The light that arrives along a ray that left the room: the environment's through a window, the room
    behind's through an open door (:func:`~ncjax.synth.pathtrace_scene.next_room_radiance`: textured where the
    camera sees it, its materials' mean colours in the light it sheds into the room), else 0."""
    sky = jnp.where(hit.kind == SurfaceKind.ESCAPE, environment_radiance(environment, direction), 0.0)
    return sky + next_room_radiance(scene, hit, direction, next_room, textured=seen)


def _emitted(
    scene: Scene,
    hit: Hit,
    direction: Float[Array, 3],
    environment: Float[Array, "He We 3"] | Float[Array, 3],
    next_room: Float[Array, 3],
    config: PathTraceConfig,
    seen: bool,
) -> Float[Array, 3]:
    """What a path adds where it arrives: an emissive surface's radiance, or the light through a hole.
    After a reflection (``seen`` False) what the sampling at the vertex already counted is left out."""
    emitted = surface_emission(scene, hit)
    if not (seen or config.emissive_boxes_light):
        emitted = jnp.zeros(3)
    if config.hole_sampling and not seen:
        return emitted
    return emitted + _arriving(scene, hit, direction, environment, next_room, seen)


def _reflect(
    scene: Scene,
    hit: Hit,
    direction: Float[Array, 3],
    uniform: Float[Array, 9],
    config: PathTraceConfig,
    environment: Float[Array, "He We 3"] | Float[Array, 3],
    next_room: Float[Array, 3],
    sun: Sun | None,
):
    """One path vertex: the light sampled towards the lights, the holes and the sun (before the path's
    throughput), and the next ray's direction with the throughput factor ``f cos / pdf`` of the reflection."""
    albedo, is_floor = surface_appearance(scene, hit)
    frame = tangent_frame(hit.normal)
    outgoing = frame @ -direction
    start = hit.point + _OFFSET * hit.normal

    def reflectance_cosine(world_direction):
        incoming = frame @ world_direction
        reflectance = jnp.where((incoming[2] > 0) & (outgoing[2] > 0), albedo / math.pi, 0.0)
        if config.floor_specular > 0:
            glossy = glossy_brdf(outgoing, incoming, albedo, config.floor_roughness, config.floor_specular)
            reflectance = jnp.where(is_floor, glossy, reflectance)
        return reflectance * jnp.maximum(incoming[2], 0.0)

    to_light, light_distance, intensity = sample_light(scene, hit.point, uniform[:3], config.light_radius)
    visible = intersect(scene, start, to_light).distance > light_distance - 1e-3
    direct = jnp.where(visible, reflectance_cosine(to_light), 0.0) * intensity
    if config.hole_sampling:
        to_hole, hole_distance, scale = sample_hole(scene, hit.point, uniform[3:6])
        through = intersect(scene, start, to_hole)
        # The shadow ray must leave through the hole it aimed at (not hit a mullion or the door's frame); one
        # into a room behind crossed the wall's plane at the door it aimed at, nothing standing in front of it.
        visible = ((through.kind == SurfaceKind.ESCAPE) & (jnp.abs(through.distance - hole_distance) < 1e-3)) | (
            through.kind == SurfaceKind.NEXT_ROOM
        )
        arriving = _arriving(scene, through, to_hole, environment, next_room, seen=False)
        direct = direct + jnp.where(visible, reflectance_cosine(to_hole), 0.0) * scale * arriving
    if sun is not None:
        sunlit = leaves_through_a_window(scene, intersect(scene, start, sun.direction))
        direct = direct + jnp.where(sunlit, reflectance_cosine(sun.direction), 0.0) * sun.irradiance

    reflected = sample_cosine(uniform[6:8])
    factor = jnp.where(outgoing[2] > 0, albedo, 0.0)
    if config.floor_specular > 0:
        glossy_direction, glossy_factor = sample_glossy(
            outgoing, albedo, config.floor_roughness, config.floor_specular, uniform[6:9]
        )
        reflected = jnp.where(is_floor, glossy_direction, reflected)
        factor = jnp.where(is_floor, glossy_factor, factor)
    return direct, start, frame.T @ reflected, factor


def trace_path(
    scene: Scene,
    origin: Float[Array, 3],
    direction: Float[Array, 3],
    uniform: Float[Array, "bounces 9"],
    config: PathTraceConfig,
    environment: Float[Array, "He We 3"] | Float[Array, 3],
    sun: Sun | None = None,
    next_room: Float[Array, 3] | None = None,
) -> Float[Array, 3]:
    """The radiance one light path brings back along a ray (ONE ray; batch with ``jax.vmap``).

    Args:
        scene: the scene (camera frame).
        origin, direction: (3,) the ray's start (inside the room) and unit direction.
        uniform: (bounces, 9) uniform numbers in [0, 1), all the randomness of the path.
        config: static settings; ``config.bounces`` must equal ``uniform``'s first axis.
        environment: see :func:`environment_radiance`.
        sun: a directional light through the windows, or None.
        next_room: (3,) the irradiance that lights the rooms behind open doors (before each door's
            ``room_light``); None is black.

    Returns:
        (3,) an unbiased estimate of the radiance (paths of at most ``bounces`` reflections).
    """
    next_room = jnp.zeros(3) if next_room is None else next_room
    hit = intersect(scene, origin, direction)

    def bounce(carry, numbers):
        hit, direction, throughput, radiance = carry
        # A path ends where it leaves the room (the room behind a door is seen, not travelled through).
        alive = (hit.kind != SurfaceKind.ESCAPE) & (hit.kind != SurfaceKind.NEXT_ROOM)
        direct, start, reflected, factor = _reflect(scene, hit, direction, numbers, config, environment, next_room, sun)
        radiance = radiance + jnp.where(alive, throughput * direct, 0.0)
        throughput = jnp.where(alive, throughput * factor, 0.0)
        hit = intersect(scene, start, reflected)
        radiance = radiance + throughput * _emitted(scene, hit, reflected, environment, next_room, config, seen=False)
        return (hit, reflected, throughput, radiance), None

    carry = (hit, direction, jnp.ones(3), _emitted(scene, hit, direction, environment, next_room, config, seen=True))
    (_, _, _, radiance), _ = jax.lax.scan(bounce, carry, uniform)
    return radiance


def camera_ray(
    cam: NonCentralPanorama, u: Float[Array, ""], v: Float[Array, ""]
) -> tuple[Float[Array, 3], Float[Array, 3]]:
    """The ray of pixel (u, v): its column's optical centre and the unit direction of its Plücker ray
    (:func:`~ncjax.geometry.camera.pixel_to_ray`), so that non-central rays (rc > 0) are exact."""
    return optical_centre(cam, u), pixel_to_ray(cam, u, v)[:3]


def _pixel(scene, cam, key, index, config: PathTraceConfig, environment, sun, next_room) -> Float[Array, 3]:
    """The mean radiance of the paths of pixel ``index`` (row-major), from its own stream of ``key``."""
    row, column = index // cam.width, index % cam.width
    uniform = jax.random.uniform(
        jax.random.fold_in(key, index), (config.samples_per_pixel, 2 + _PER_BOUNCE * config.bounces)
    )

    def sample(numbers):
        jitter = numbers[:2] - 0.5 if config.jitter else jnp.zeros(2)
        origin, direction = camera_ray(cam, column + jitter[0], row + jitter[1])
        return trace_path(
            scene,
            origin,
            direction,
            numbers[2:].reshape(config.bounces, _PER_BOUNCE),
            config,
            environment,
            sun,
            next_room,
        )

    return jnp.mean(jax.vmap(sample)(uniform), 0)


def path_trace(
    scene: Scene,
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    config: PathTraceConfig = PathTraceConfig(),
    environment: Float[Array, "He We 3"] | Float[Array, 3] | None = None,
    sun: Sun | None = None,
    next_room: Float[Array, 3] | None = None,
) -> Float[Array, "H W 3"]:
    """Path-trace the panorama of ``scene`` seen by ``cam``: linear radiance, no tone curve.

    Args:
        scene: one scene (camera frame); as in :func:`~ncjax.synth.render`, ``cam.rc`` is used, not the
            room's.
        cam: the panorama (static width W and height H; traced rc and fields of view).
        key: a ``jax.random`` key, the only source of randomness: same key, same image.
        config: static settings (:class:`PathTraceConfig`).
        environment: what is seen through windows, and lights the room through them: an equirectangular
            map (He, We, 3) or a constant colour (3,), see :func:`environment_radiance`; None is black.
        sun: a directional light that shines through the windows (:class:`Sun`), or None.
        next_room: (3,) the irradiance that lights the rooms seen through open doors (with decor; before each
            door's ``room_light``), which light the room through them too; None is black.

    Returns:
        (H, W, 3) radiance. Jit with ``config`` static; vmap over scenes (and keys, cameras' rc).
    """
    if environment is None:
        environment = jnp.zeros(3)
    count = cam.width * cam.height
    image = jax.lax.map(
        lambda index: _pixel(scene, cam, key, index, config, environment, sun, next_room),
        jnp.arange(count),
        batch_size=min(config.pixels_per_chunk, count),
    )
    return image.reshape(cam.height, cam.width, 3)
