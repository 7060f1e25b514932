"""Denoising of path-traced panoramas, guided by what the camera rays first meet.

At the samples a pixel a render affords, a path-traced image is mostly Monte Carlo noise where only bounced light
arrives. The noise is in the light, not in the surfaces: each pixel's radiance is its albedo times the irradiance
its paths estimate, and the irradiance varies slowly over a surface. So the image is divided by the albedo of the
surface each pixel first meets (demodulated), the irradiance is smoothed by an edge-avoiding a-trous wavelet filter
(Dammertz et al. 2010, "Edge-avoiding a-trous wavelet transform for fast global illumination filtering"; the
variance-guided luminance weight of Schied et al. 2017, "Spatiotemporal variance-guided filtering"), and multiplied
by the albedo again: textures stay sharp, and the filter never mixes two surfaces (another kind or slot, another
normal, another depth). What is seen through windows, the environment, and what emits are kept as traced (they
carry no path noise).

Each guide comes from one ray through each pixel's centre (:func:`guide_buffers`, one ray a pixel against the path
tracer's many); the filter itself is a few shifted-image sums (:func:`denoise`). The same separation lets light
traced at a fraction of the image's size be brought to full size within each surface (:func:`upsampled_light`) and
multiplied by the full-size albedo: the light is soft, the textures sharp. Shifts wrap around the panorama's columns
(its seam is no edge) and stop at its top and bottom rows.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ..geometry.camera import NonCentralPanorama
from ..io.tone_mapping import luminance
from .pathtrace import camera_ray
from .pathtrace_scene import SurfaceKind, intersect, surface_appearance, surface_emission
from .scene import Scene

# The a-trous filter's 1D kernel, the cubic B-spline's (its 5 x 5 outer product is one level's footprint).
_B3_SPLINE = (1 / 16, 1 / 4, 3 / 8, 1 / 4, 1 / 16)
# Irradiance is the radiance over an albedo at least this (a black surface's noise is not amplified to infinity).
_MIN_ALBEDO = 0.02
# Guide pixels computed together: bounds memory, as the path tracer's chunks do (a 512 x 1024 image's guides at
# once held gigabytes of intermediate hits).
_GUIDE_PIXELS_PER_CHUNK = 16384


@dataclasses.dataclass(frozen=True)
class DenoiseConfig:
    """Static settings of :func:`denoise` (hashable: a jit static argument).

    Attributes:
        levels: a-trous levels; level i's taps are 2^i pixels apart, so the footprint is 2^(levels+1) + 1 pixels
            wide (5 levels: 65 px).
        normal_power: a tap's weight has the factor max(0, n_p . n_q)^normal_power (128: two surfaces 10
            degrees apart weigh 0.14 of one another).
        depth_tolerance: the factor exp(-|d_p - d_q| / (depth_tolerance * d_p * step)): the relative depth
            difference allowed a pixel away (the depth grows along a receding surface).
        luminance_sigma: the factor exp(-|l_p - l_q| / (luminance_sigma * sqrt(var_p) + tiny)), with var_p the
            noise variance of the irradiance's luminance at p (estimated over its 3 x 3 neighbours of the same
            surface, then carried through the levels): differences larger than the noise, such as shadows' edges,
            are kept.
        firefly_factor: before filtering, a pixel's irradiance is limited to this times its 3 x 3 neighbours'
            median (single paths that found a light by chance; 0: off).
    """

    levels: int = 5
    normal_power: float = 128.0
    depth_tolerance: float = 0.05
    luminance_sigma: float = 4.0
    firefly_factor: float = 4.0

    def __post_init__(self):
        if int(self.levels) != self.levels or self.levels < 0:
            raise ValueError(f"levels must be an integer >= 0, got {self.levels!r}")
        for name in ("normal_power", "depth_tolerance", "luminance_sigma", "firefly_factor"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")


class GuideBuffers(eqx.Module):
    """What each pixel's centre ray first meets (all fields traced).

    Attributes:
        albedo: (H, W, 3) the surface's albedo (:func:`~ncjax.synth.pathtrace_scene.surface_appearance`); 1 where
            the ray escapes or meets what emits.
        normal: (H, W, 3) the surface's unit normal.
        depth: (H, W) the distance along the ray, metres.
        surface: (H, W) one integer per surface: its :class:`~ncjax.synth.pathtrace_scene.SurfaceKind` and slot;
            0 where the ray escapes or meets what emits (kept as traced).
    """

    albedo: Float[Array, "H W 3"]
    normal: Float[Array, "H W 3"]
    depth: Float[Array, "H W"]
    surface: Int[Array, "H W"]


def guide_buffer(scene: Scene, cam: NonCentralPanorama, u: Float[Array, ""], v: Float[Array, ""]):
    """The albedo, normal, depth and surface number of the first hit of pixel (u, v)'s ray (ONE pixel).

    What emits (lamp shades, light panels) is numbered 0 with the environment, albedo 1: kept as traced, its
    glow is not spread over the ceiling around it."""
    hit = intersect(scene, *camera_ray(cam, u, v))
    albedo, _ = surface_appearance(scene, hit)
    kept = (hit.kind == SurfaceKind.ESCAPE) | jnp.any(surface_emission(scene, hit) > 0)
    surface = hit.kind + len(SurfaceKind) * (hit.index + 1)
    return jnp.where(kept, 1.0, albedo), hit.normal, hit.distance, jnp.where(kept, 0, surface)


def guide_buffers(scene: Scene, cam: NonCentralPanorama) -> GuideBuffers:
    """The guides of every pixel of ``cam`` (its centre's ray, as :func:`~ncjax.synth.pathtrace.path_trace`
    traces it), a few rows at a time (``_GUIDE_PIXELS_PER_CHUNK``). Jit with the camera's size static."""
    rows, columns = jnp.meshgrid(jnp.arange(cam.height), jnp.arange(cam.width), indexing="ij")
    per_row = jax.vmap(guide_buffer, (None, None, 0, 0))
    return GuideBuffers(
        *jax.lax.map(
            lambda row: per_row(scene, cam, row[1], row[0]),
            (rows.astype(jnp.float32), columns.astype(jnp.float32)),
            batch_size=min(cam.height, max(1, _GUIDE_PIXELS_PER_CHUNK // cam.width)),
        )
    )


def shifted(image: Float[Array, "H W ..."], rows: int, columns: int) -> Float[Array, "H W ..."]:
    """``image`` moved so that pixel (r, c) holds pixel (r + rows, c + columns): columns wrap around (a
    panorama's seam), rows stop at the first and last (the poles)."""
    height = image.shape[0]
    source = jnp.clip(jnp.arange(height) + rows, 0, height - 1)
    return jnp.roll(image[source], -columns, axis=1)


def _taps(step: int):
    """The a-trous level's 25 taps: (row offset, column offset, kernel weight)."""
    return [(step * (i - 2), step * (j - 2), _B3_SPLINE[i] * _B3_SPLINE[j]) for i in range(5) for j in range(5)]


def _similarity(pixels: GuideBuffers, others: GuideBuffers, step: int, config: DenoiseConfig):
    """How much each pixel may take of the light of the pixel ``others`` holds at its place, ``step`` pixels away,
    by the guides alone, in [0, 1]: 0 on another surface, else the normals' agreement times the depths'."""
    facing = jnp.maximum(jnp.sum(pixels.normal * others.normal, -1), 0.0)
    depth_gap = jnp.abs(pixels.depth - others.depth)
    depth_weight = jnp.exp(-depth_gap / (config.depth_tolerance * pixels.depth * step + 1e-6))
    return jnp.where(pixels.surface == others.surface, facing**config.normal_power * depth_weight, 0.0)


def _geometric_weight(guides: GuideBuffers, rows: int, columns: int, step: int, config: DenoiseConfig):
    """How much each pixel may take of its neighbour ``(rows, columns)`` away by the guides alone, in [0, 1]
    (nothing where it shows the environment: that is not filtered)."""
    neighbours = jax.tree.map(lambda guide: shifted(guide, rows, columns), guides)
    return jnp.where(guides.surface > 0, _similarity(guides, neighbours, step, config), 0.0)


def _local_variance(brightness: Float[Array, "H W"], guides: GuideBuffers, config: DenoiseConfig):
    """The luminance's variance over each pixel's 3 x 3 neighbours of its own surface (itself included)."""
    weights, values = [], []
    for rows in (-1, 0, 1):
        for columns in (-1, 0, 1):
            centre = (rows, columns) == (0, 0)
            weights.append(jnp.ones_like(brightness) if centre else _geometric_weight(guides, rows, columns, 1, config))
            values.append(shifted(brightness, rows, columns))
    weights, values = jnp.stack(weights), jnp.stack(values)
    total = jnp.sum(weights, 0)
    mean = jnp.sum(weights * values, 0) / total
    return jnp.sum(weights * (values - mean) ** 2, 0) / total


def _clamped_fireflies(irradiance: Float[Array, "H W 3"], config: DenoiseConfig) -> Float[Array, "H W 3"]:
    """Each pixel's irradiance limited to ``firefly_factor`` times its 3 x 3 neighbours' median luminance."""
    brightness = luminance(irradiance)
    around = jnp.stack([shifted(brightness, r, c) for r in (-1, 0, 1) for c in (-1, 0, 1) if (r, c) != (0, 0)])
    limit = config.firefly_factor * jnp.median(around, 0)
    scale = jnp.where(brightness > limit, limit / jnp.maximum(brightness, 1e-12), 1.0)
    return irradiance * scale[..., None]


def _atrous_level(irradiance, variance, guides: GuideBuffers, step: int, config: DenoiseConfig):
    """One a-trous level: each pixel the weighted mean of its 25 taps ``step`` pixels apart, and the variance of
    that mean (the weights squared)."""
    brightness = luminance(irradiance)
    spread = config.luminance_sigma * jnp.sqrt(jnp.maximum(variance, 0.0)) + 1e-6
    total = jnp.zeros_like(brightness)
    mean = jnp.zeros_like(irradiance)
    mean_variance = jnp.zeros_like(variance)
    for rows, columns, kernel in _taps(step):
        if (rows, columns) == (0, 0):
            weight = jnp.full_like(brightness, kernel)
        else:
            gap = jnp.abs(brightness - shifted(brightness, rows, columns))
            weight = kernel * _geometric_weight(guides, rows, columns, step, config) * jnp.exp(-gap / spread)
        total = total + weight
        mean = mean + weight[..., None] * shifted(irradiance, rows, columns)
        mean_variance = mean_variance + weight**2 * shifted(variance, rows, columns)
    return mean / total[..., None], mean_variance / total**2


def demodulated(radiance: Float[Array, "H W 3"], guides: GuideBuffers) -> Float[Array, "H W 3"]:
    """The light of each pixel: its radiance over the albedo its centre ray meets (the irradiance on a surface;
    the radiance itself where the ray escapes, whose guide albedo is 1)."""
    return radiance / jnp.maximum(guides.albedo, _MIN_ALBEDO)


def remodulated(light: Float[Array, "H W 3"], guides: GuideBuffers) -> Float[Array, "H W 3"]:
    """The radiance of pixels of ``light`` (:func:`demodulated`'s inverse): times the albedo again."""
    return light * jnp.maximum(guides.albedo, _MIN_ALBEDO)


def filtered_light(
    light: Float[Array, "H W 3"], guides: GuideBuffers, config: DenoiseConfig = DenoiseConfig()
) -> Float[Array, "H W 3"]:
    """:func:`demodulated` light with its Monte Carlo noise filtered out within each surface; the environment's
    pixels (``guides.surface == 0``) unchanged. Jit with ``config`` static; vmap over images."""
    irradiance = light
    if config.firefly_factor > 0:
        irradiance = _clamped_fireflies(irradiance, config)
    variance = _local_variance(luminance(irradiance), guides, config)
    for level in range(config.levels):
        irradiance, variance = _atrous_level(irradiance, variance, guides, 2**level, config)
    return jnp.where((guides.surface > 0)[..., None], irradiance, light)


def denoise(
    radiance: Float[Array, "H W 3"], guides: GuideBuffers, config: DenoiseConfig = DenoiseConfig()
) -> Float[Array, "H W 3"]:
    """The path-traced ``radiance`` with its Monte Carlo noise filtered out (the module's method).

    Args:
        radiance: (H, W, 3) linear radiance, :func:`~ncjax.synth.pathtrace.path_trace`'s.
        guides: the same panorama's :func:`guide_buffers`.
        config: static settings (:class:`DenoiseConfig`).

    Returns:
        (H, W, 3) the denoised radiance; the environment's pixels (``guides.surface == 0``) unchanged.
        Jit with ``config`` static; vmap over images.
    """
    return remodulated(filtered_light(demodulated(radiance, guides), guides, config), guides)


def upsampled_light(
    light: Float[Array, "h w 3"], coarse: GuideBuffers, fine: GuideBuffers, config: DenoiseConfig = DenoiseConfig()
) -> Float[Array, "H W 3"]:
    """Light traced at a fraction of a panorama's size, brought to its full size by joint bilateral upsampling
    (Kopf et al. 2007): each full-size pixel takes the bilinear mean of the 4 nearest traced pixels (half-pixel
    centres), weighted as the denoiser weighs its taps, by whether they show the same surface, facing the same
    way at the same depth, so that light does not bleed across an edge; a pixel none of them matches keeps the
    plain bilinear mean. Multiplied by the full-size albedo (:func:`remodulated` with ``fine``), the light's
    softness no longer blurs textures and edges.

    Args:
        light: (h, w, 3) :func:`demodulated` (and filtered) light of the traced panorama.
        coarse: the traced panorama's :func:`guide_buffers`.
        fine: the full-size panorama's (its sides integer multiples of the traced ones).
        config: the weights' settings (``normal_power``, ``depth_tolerance``).

    Returns:
        (H, W, 3) the light at full size. Columns wrap around the panorama's seam; rows stop at the poles.
    """
    (height, width), (coarse_height, coarse_width) = fine.depth.shape, coarse.depth.shape
    scale = width // coarse_width

    def neighbours(size, coarse_size, wrap):
        position = (jnp.arange(size) + 0.5) * coarse_size / size - 0.5
        first = jnp.floor(position)
        fraction = position - first
        indices = first.astype(jnp.int32) + jnp.arange(2)[:, None]
        indices = indices % coarse_size if wrap else jnp.clip(indices, 0, coarse_size - 1)
        return indices, jnp.stack([1 - fraction, fraction])

    row_index, row_weight = neighbours(height, coarse_height, wrap=False)
    column_index, column_weight = neighbours(width, coarse_width, wrap=True)
    total = jnp.zeros((height, width))
    upsampled = jnp.zeros((height, width, 3))
    for i in range(2):
        for j in range(2):
            rows, columns = row_index[i][:, None], column_index[j][None, :]
            neighbour = jax.tree.map(lambda guide: guide[rows, columns], coarse)
            same = neighbour.surface == fine.surface
            # The environment's pixels match by surface alone (their normal and depth are the wall's plane).
            geometric = jnp.where(fine.surface > 0, _similarity(fine, neighbour, scale, config), same)
            # The small floor: where no neighbour matches, the bilinear weights alone decide.
            weight = row_weight[i][:, None] * column_weight[j][None, :] * (geometric + 1e-6)
            total = total + weight
            upsampled = upsampled + weight[..., None] * light[rows, columns]
    return upsampled / total[..., None]
