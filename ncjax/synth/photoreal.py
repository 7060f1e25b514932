"""Photoreal training images: a scene path-traced, denoised and developed by a consumer camera's model.

The ray caster (:mod:`ncjax.synth.render`) shades each hit locally. A photoreal image is the same scene's light as
it behaves: :func:`~ncjax.synth.pathtrace.path_trace`'s interreflections, area lights and rough-glossy floor, with
the windows showing one of the real outdoor HDR panoramas shipped in ``ncjax/data/window_views`` (CC0), turned and
scaled at random, which also lights the room through them, its sun as a directional light that casts patches of
sunlight; open doors and passages show the rooms behind them, lit evenly (darker towards their edges). The light is
traced at a fraction of the image's size (``trace_scale``), denoised and brought to the image's size over the
surfaces' albedo at that size (:mod:`ncjax.synth.pathtrace_denoise`), then developed by
:func:`~ncjax.synth.photograph.photograph` (by default its metered exposure, tone curve and white balance, 8 bits:
:data:`DEVELOPMENT`). The geometry is the scene's own, so the ray caster's labels, depth and semantics hold for
it unchanged: ``SynthConfig(photoreal=PhotorealConfig())`` renders the rooms of ``ncjax synth`` so
(:func:`~ncjax.synth.render.synthesize_batch`).

Every function is written for one scene and batched with ``jax.vmap``; a key is the only source of randomness.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama, angles_to_ray, pixel_to_angles
from ..io.tone_mapping import luminance
from .pathtrace import PathTraceConfig, Sun, path_trace
from .pathtrace_denoise import (
    DenoiseConfig,
    demodulated,
    filtered_light,
    guide_buffers,
    remodulated,
    upsampled_light,
)
from .photograph import PhotographConfig, photograph
from .scene import Scene

WINDOW_VIEWS_PATH = pathlib.Path(__file__).parents[1] / "data" / "window_views" / "outdoor.npz"
# The sun of a window view: what the clip takes within this angle of the brightest texel (the sun's disc, its
# glare spread over a few texels of 1.9 degrees, and the bright sky around it).
_SUN_CONE_DEGREES = 20.0

DEVELOPMENT = PhotographConfig(
    vignetting_strength=(0.0, 0.0),
    seam_exposure=(1.0, 1.0),
    seam_shift=(0.0, 0.0),
    nadir_rows=(0.0, 0.0),
    nadir_darkening=(1.0, 1.0),
    read_noise=(0.0, 0.0),
    shot_noise=(0.0, 0.0),
)
"""The camera model's development alone: metered exposure, tone curve, white balance, 8 bits. Training
(:func:`~ncjax.training.loop.augment_batch`) adds the camera's defects to every image, rendered either way."""

HDR_DEVELOPMENT = dataclasses.replace(DEVELOPMENT, local_compression=(0.4, 0.8))
""":data:`DEVELOPMENT` of an HDR capture, tone-mapped locally as real-estate capture apps do (the windows show their
view, shadowed corners lift). Measured, not the training renders' default: heads on such renders read photographs
no better (experiments/RESULTS.md, "Path-traced renders")."""


@dataclasses.dataclass(frozen=True)
class PhotorealConfig:
    """Static settings of :func:`photoreal_image` (hashable: a jit static argument).

    Attributes:
        trace: the path tracer's settings. By default 8 paths a pixel of 3 bounces, and the lamps' shades
            only seen (their ceiling lights stand for their light): about a third of the cost of 16 paths of 4
            bounces.
        denoise: the denoiser's settings; None keeps the Monte Carlo noise. Its luminance weight is 4 times
            looser than the denoiser's default: at 8 paths a pixel the default leaves blotches on walls that only
            bounced light reaches (the realism probe's Frechet distance 539 at the default, 449 so; two rooms' log
            luminance against 128 paths a pixel, blurred over 3 pixels, off by 0.065 and 0.036 rms at the default,
            0.062 and 0.044 so: experiments/RESULTS.md, "Path-traced renders").
        camera: the camera that develops the radiance (default :data:`DEVELOPMENT`; ``PhotographConfig()``
            adds vignetting, stitching seams, the tripod at the nadir and sensor noise).
        trace_scale: the light is traced at the image's size divided by this (an integer dividing both sides),
            then brought to the image's size within each surface and multiplied by the albedo each image pixel
            sees (:func:`~ncjax.synth.pathtrace_denoise.upsampled_light`): 2 traces a quarter of the pixels, with
            textures and edges as sharp as the ray caster's; only the light itself is softer.
        window_brightness: the range of the median radiance of what windows show (the ceiling lights give a
            few units to the walls near them).
        sun_clip: what windows show is clipped at this times its median: the sun, a thousand times the sky,
            would otherwise be found by a few paths only (speckles the denoiser cannot remove).
        sun: what the clip takes around the sun lights the room as a directional light through the windows
            (:func:`window_light`): patches of sunlight, sampled at every path vertex, without speckles.
        next_room_light: the rooms seen through open doors and passages are lit evenly (darker towards their edges,
            as the ray caster darkens them), and light the room through their doors: each door's ``room_light``
            (0.35-1.8) times this much of ``pi`` times the mean radiance of what the windows show (the irradiance of a
            surface open to that whole view). At 0.015 they look about as bright as the room's walls, as in
            photographs: what is seen of them has 0.22-2.04 times the walls' median luminance (median 0.81; the ray
            caster's 0.55) over the 11 of the first 16 rooms of ``synth-decor-open`` (seed 701) that show them
            (``experiments/next_room_light.py``). At 0.1 they glowed, 1.3-10.8 times (median 3.7), and heads trained
            on such renders followed the photographs' doorways to the floor lines of the rooms behind
            (experiments/RESULTS.md, "Path-traced renders").
    """

    trace: PathTraceConfig = PathTraceConfig(
        samples_per_pixel=8, bounces=3, pixels_per_chunk=2048, emissive_boxes_light=False
    )
    denoise: DenoiseConfig | None = DenoiseConfig(luminance_sigma=16.0)
    camera: PhotographConfig = DEVELOPMENT
    trace_scale: int = 2
    window_brightness: tuple[float, float] = (1.4, 2.8)
    sun_clip: float = 4.0
    sun: bool = True
    next_room_light: float = 0.015

    def __post_init__(self):
        if int(self.trace_scale) != self.trace_scale or self.trace_scale < 1:
            raise ValueError(f"trace_scale must be a positive integer, got {self.trace_scale!r}")
        low, high = self.window_brightness
        if not 0 < low <= high:
            raise ValueError(f"window_brightness must be a range 0 < low <= high, got {self.window_brightness}")
        if not self.sun_clip >= 1:
            raise ValueError(f"sun_clip must be >= 1 (times the median), got {self.sun_clip}")
        if not self.next_room_light >= 0:
            raise ValueError(f"next_room_light must be >= 0, got {self.next_room_light}")


@functools.cache
def window_views() -> Float[np.ndarray, "N He We 3"]:
    """The shipped outdoor panoramas (float32 linear RGB, equirectangular), read once."""
    with np.load(WINDOW_VIEWS_PATH) as shipped:
        return shipped["views"].astype(np.float32)


def window_light(
    key: PRNGKeyArray, views: Float[Array, "N He We 3"], config: PhotorealConfig = PhotorealConfig()
) -> tuple[Float[Array, "He We 3"], Sun]:
    """What the windows show, and the sun that shines through them.

    One of ``views`` at random, turned by a random azimuth, scaled to a random median luminance in
    ``config.window_brightness`` and clipped at ``config.sun_clip`` times that median. With ``config.sun``, the
    light the clip took away above the horizon within ``_SUN_CONE_DEGREES`` of the brightest texel becomes the
    :class:`~ncjax.synth.pathtrace.Sun`: its irradiance is that light integrated over its solid angle, its
    direction the light's mean one, so a sunny view casts patches of sunlight that an overcast one does not.

    Returns:
        ``(view, sun)``: the clipped (He, We, 3) view and the sun (zero irradiance without ``config.sun``).
    """
    key_pick, key_turn, key_level = jax.random.split(key, 3)
    view = views[jax.random.randint(key_pick, (), 0, views.shape[0])]
    view = jnp.roll(view, jax.random.randint(key_turn, (), 0, views.shape[2]), axis=1)
    level = luminance(view)
    median = jax.random.uniform(key_level, (), minval=config.window_brightness[0], maxval=config.window_brightness[1])
    gain = median / jnp.maximum(jnp.median(level), 1e-12)
    clip = jnp.minimum(1.0, config.sun_clip * median / jnp.maximum(level * gain, 1e-12))
    clipped = view * (gain * clip)[..., None]

    rows, columns = view.shape[:2]
    row, column = jnp.meshgrid(*(jnp.arange(n, dtype=jnp.float32) for n in (rows, columns)), indexing="ij")
    azimuth, elevation = pixel_to_angles(NonCentralPanorama(columns, rows), column, row)
    direction = angles_to_ray(0.0, azimuth, elevation)[..., :3]
    solid_angle = (2 * math.pi / columns) * (math.pi / rows) * jnp.cos(elevation)
    above = elevation > 0
    brightest = direction.reshape(-1, 3)[jnp.argmax(jnp.where(above, level, -1.0))]
    near_sun = above & (direction @ brightest > math.cos(math.radians(_SUN_CONE_DEGREES)))
    taken = (view * gain - clipped) * jnp.where(near_sun & config.sun, solid_angle, 0.0)[..., None]
    weighted = jnp.sum(luminance(taken)[..., None] * direction, (0, 1))
    norm = jnp.linalg.norm(weighted)
    sun_direction = jnp.where(norm > 0, weighted / jnp.maximum(norm, 1e-30), brightest)
    return clipped, Sun(direction=sun_direction, irradiance=jnp.sum(taken, (0, 1)))


def next_room_irradiance(view: Float[Array, "He We 3"], config: PhotorealConfig = PhotorealConfig()) -> Float[Array, 3]:
    """The irradiance that lights the rooms behind open doors (before each door's ``room_light``):
    ``config.next_room_light`` of a surface's open to the whole of what the windows show (``pi`` times its mean
    radiance)."""
    return config.next_room_light * math.pi * jnp.mean(view, (0, 1))


def photoreal_image(
    key: PRNGKeyArray,
    scene: Scene,
    cam: NonCentralPanorama,
    views: Float[Array, "N He We 3"],
    config: PhotorealConfig = PhotorealConfig(),
) -> Float[Array, "H W 3"]:
    """The photograph of ``scene`` by ``cam`` with physically based light (the module's method).

    Args:
        key: a ``jax.random`` key: the window's view, the paths and the camera's errors and noise.
        scene: one scene (camera frame); ``cam.rc`` is used, as by :func:`~ncjax.synth.render.render`.
        cam: the image's camera (static size, a multiple of ``config.trace_scale``).
        views: the outdoor panoramas windows may show (:func:`window_views`).
        config: static settings (:class:`PhotorealConfig`).

    Returns:
        (H, W, 3) sRGB in [0, 1], multiples of 1/255. Jit with ``config`` static; vmap over keys and scenes.
    """
    key_camera = jax.random.split(key, 3)[2]  # the first two streams are photoreal_radiance's
    return photograph(key_camera, photoreal_radiance(key, scene, cam, views, config), config.camera)


def photoreal_radiance(
    key: PRNGKeyArray,
    scene: Scene,
    cam: NonCentralPanorama,
    views: Float[Array, "N He We 3"],
    config: PhotorealConfig = PhotorealConfig(),
) -> Float[Array, "H W 3"]:
    """The linear radiance that :func:`photoreal_image` develops: traced, denoised and brought to the image's size.

    Args:
        key: a ``jax.random`` key: the window's view and the paths (the same key as :func:`photoreal_image`'s gives
            the radiance it develops).
        scene, cam, views, config: as for :func:`photoreal_image`.

    Returns:
        (H, W, 3) linear RGB, in the units of the window views' radiance. Jit with ``config`` static; vmap over keys
        and scenes.
    """
    scale = config.trace_scale
    if cam.width % scale or cam.height % scale:
        raise ValueError(f"trace_scale {scale} must divide the image size {cam.height} x {cam.width}")
    key_view, key_trace, _ = jax.random.split(key, 3)  # the third stream is photoreal_image's camera's
    traced = NonCentralPanorama(cam.width // scale, cam.height // scale, cam.rc, cam.fov_horizontal, cam.fov_vertical)
    view, sun = window_light(key_view, views, config)
    next_room = next_room_irradiance(view, config)
    radiance = path_trace(scene, traced, key_trace, config.trace, view, sun if config.sun else None, next_room)
    guides = guide_buffers(scene, traced)
    light = demodulated(radiance, guides)
    if config.denoise is not None:
        light = filtered_light(light, guides, config.denoise)
    if scale > 1:  # the light traced at a fraction of the size, the textures and edges at the image's own
        image_guides = guide_buffers(scene, cam)
        light = upsampled_light(light, guides, image_guides, config.denoise or DenoiseConfig())
        guides = image_guides
    return remodulated(light, guides)
