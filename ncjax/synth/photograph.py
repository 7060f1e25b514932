"""A consumer 360-degree camera's photograph of a linear radiance panorama (pure jnp, jit/vmap-able).

The path tracer (:mod:`ncjax.synth.pathtrace`) returns physical radiance, unbounded and in arbitrary units;
a photograph is what a camera makes of it. :func:`photograph` does what the camera does, in its order:

- HDR capture (optional): the bracketed exposures fused and tone-mapped locally, as real-estate capture apps do:
  the scene's large-scale light compressed in log luminance, its detail kept (:func:`local_tone_mapping`), so
  that windows show the view and shadowed corners lift;
- metering: the exposure that maps a high percentile of the luminance to the tone curve's white point, so
  that whatever is brighter (windows, lamps) blows out, as in real indoor panoramas;
- white balance: part of the grey-world correction of an automatic white balance, and a small random error;
- the lenses' vignetting and the stitcher's seams between the two lenses (a residual exposure and colour step,
  a pixel of parallax), from :mod:`ncjax.synth.augment`;
- a filmic tone curve (Hable's, with a shoulder that rolls highlights off to white) and the sRGB encoding;
- the nadir patch that hides the tripod: the bottom rows smeared and darkened;
- sensor noise, and the JPEG compression of the file (:func:`~ncjax.synth.augment.jpeg_compress`).

Every function takes ONE image (batch with ``jax.vmap``); random numbers come only from the key of
:func:`photograph`. The geometry is untouched (at most the seams' pixel of shift), so labels stay exact.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ..network.denoise import gaussian_blur
from .augment import add_sensor_noise, jpeg_compress, stitching_seams, vignette

# Rec. 709 / sRGB luminance of linear RGB
_LUMINANCE = (0.2126, 0.7152, 0.0722)
# Hable's filmic curve ("Uncharted 2"): shoulder strength, linear strength, linear angle, toe strength,
# toe numerator and denominator.
_HABLE = (0.15, 0.50, 0.10, 0.20, 0.02, 0.30)


@dataclasses.dataclass(frozen=True)
class PhotographConfig:
    """Static settings of :func:`photograph` (hashable: a jit static argument).

    Each range ``(low, high)`` is drawn uniformly per photograph from its key.

    Attributes:
        local_compression: the factor on the log luminance of the scene's large-scale light (:func:`local_tone_mapping`:
            1 keeps it, as a single exposure does; 0.5 halves its contrasts in log, as an HDR capture app does). Off
            in the training renders' development: heads trained on renders developed at 0.4-0.8 read photographs no
            better, and the realism probe tells them from photographs as well (experiments/RESULTS.md,
            "Path-traced renders").
        middle_grey: the display value (linear, before the sRGB encoding) at which the metering renders the scene's
            log-average luminance: 0.18, the grey a camera's averaging meter aims at.
        exposure_spread: the metering's error: a factor on the exposure, drawn log-uniformly.
        white_point: the linear value the tone curve maps to 1 (brighter is clipped).
        white_balance_strength: how much of the grey-world correction the camera applies (0: none, 1: all).
        white_balance_error: per-channel gain of the remaining error.
        vignetting_strength: the vignetting's darkening half-way between the two lenses (linear).
        seam_exposure: the exposure step across each of the two stitching seams (factor on one side).
        seam_shift: the vertical shift across a seam, pixels.
        nadir_rows: the fraction of the rows, from the bottom, that the nadir patch covers.
        nadir_blur: the patch's blur, as a fraction of the image width (its smear is wider at the pole).
        nadir_darkening: the factor on the patch's brightness at the pole (the tripod's shadow).
        read_noise: standard deviation of the sensor's read noise (encoded intensities), at ``native_width``.
        shot_noise: standard deviation of its shot noise at intensity 1 (grows as the square root), at
            ``native_width``.
        jpeg_quality: JPEG quality of the file (1 to 100).
        native_width: the width of the camera's own panoramas (5760 for a consumer 360-degree camera). A
            panorama read at a width k times smaller averages k x k of its pixels: the noise is divided by k, and
            the JPEG's 8 x 8 blocks are left out where they would shrink below 4 pixels (k > 2).
    """

    local_compression: tuple[float, float] = (1.0, 1.0)
    middle_grey: float = 0.18
    exposure_spread: tuple[float, float] = (0.8, 1.25)
    white_point: float = 6.0
    white_balance_strength: float = 0.6
    white_balance_error: tuple[float, float] = (0.95, 1.05)
    vignetting_strength: tuple[float, float] = (0.05, 0.2)
    seam_exposure: tuple[float, float] = (0.95, 1.05)
    seam_shift: tuple[float, float] = (-1.0, 1.0)
    nadir_rows: tuple[float, float] = (0.06, 0.1)
    nadir_blur: float = 0.006
    nadir_darkening: tuple[float, float] = (0.4, 0.8)
    read_noise: tuple[float, float] = (0.003, 0.008)
    shot_noise: tuple[float, float] = (0.005, 0.015)
    jpeg_quality: tuple[float, float] = (75.0, 92.0)
    native_width: float = 5760.0

    def __post_init__(self):
        if not 0 < self.local_compression[0] <= self.local_compression[1] <= 1:
            raise ValueError(f"local_compression must be 0 < low <= high <= 1, got {self.local_compression}")
        if not 0 < self.middle_grey < 1:
            raise ValueError(f"middle_grey must be in (0, 1), got {self.middle_grey}")
        if not self.white_point > 0:
            raise ValueError(f"white_point must be > 0, got {self.white_point}")
        if not 0 <= self.white_balance_strength <= 1:
            raise ValueError(f"white_balance_strength must be in [0, 1], got {self.white_balance_strength}")
        if not self.native_width > 0:
            raise ValueError(f"native_width must be > 0, got {self.native_width}")
        if not 0 <= self.nadir_rows[0] <= self.nadir_rows[1] < 0.5:
            raise ValueError(f"nadir_rows must be 0 <= low <= high < 0.5, got {self.nadir_rows}")


def luminance(image: Float[Array, "*S 3"]) -> Float[Array, "*S"]:
    """Rec. 709 luminance of linear RGB."""
    return image @ jnp.asarray(_LUMINANCE, image.dtype)


def log_luminance(radiance: Float[Array, "H W 3"]) -> Float[Array, "H W"]:
    """The natural log of each pixel's luminance, black pixels lifted to 1e-4 of the image's mean: shadowed corners
    would pull a log-average (the metering's key) to zero and a log image to minus infinity. No light is negative
    (a resampled photograph's texels may be): it counts as black."""
    level = jnp.maximum(luminance(radiance), 0.0)
    return jnp.log(level + 1e-4 * jnp.mean(level) + 1e-30)


def local_tone_mapping(
    radiance: Float[Array, "H W 3"],
    compression: Float[ArrayLike, ""],
    edge_contrast: float = 0.5,
    scale: float = 1 / 32,
    grid: int = 8,
) -> Float[Array, "H W 3"]:
    """Compress the large-scale light of a radiance panorama and keep its detail (Durand and Dorsey 2002, "Fast
    bilateral filtering for the display of high-dynamic-range images", Section 5), as an HDR capture's
    tone mapping does.

    The log luminance splits into a base (the light: windows, sun patches, shadows, the fall-off into corners) and a
    detail (textures and edges of smaller contrast); the base is multiplied by ``compression``, the detail kept. The
    base is the log luminance smoothed by a guided filter with itself as guide (He, Sun and Tang 2013, "Guided image
    filtering", Eq. 4-8), run on a ``grid`` times coarser image and its coefficients brought back bilinearly (He and
    Sun 2015, "Fast guided filter"): steps of more than ``edge_contrast`` (natural log) over a window stay in the base,
    finer ones in the detail. The colour of each pixel is kept.

    Args:
        radiance: (H, W, 3) linear RGB, any positive scale.
        compression: the factor on the base's log contrasts (1 changes nothing).
        edge_contrast: the guided filter's regularisation, sqrt(epsilon), in natural log luminance.
        scale: the filter's Gaussian window, as a fraction of the image width.
        grid: the coarse image's reduction factor along each axis (static).

    Returns:
        (H, W, 3) linear RGB, each pixel multiplied by ``exp((compression - 1) * (base - mean base))``.
    """
    height, width = radiance.shape[:2]
    log_level = log_luminance(radiance)
    coarse = jax.image.resize(log_level, (max(height // grid, 1), max(width // grid, 1)), "linear")
    sigma = scale * coarse.shape[1]
    radius = int(3 * sigma) + 1

    def window_means(*images):  # the Gaussian window's mean of each (h, w) image
        return jnp.moveaxis(gaussian_blur(jnp.stack(images, -1), sigma, radius), -1, 0)

    mean, mean_square = window_means(coarse, coarse**2)
    variance = jnp.maximum(mean_square - mean**2, 0.0)
    slope = variance / (variance + edge_contrast**2)
    slope, offset = window_means(slope, (1 - slope) * mean)
    slope, offset = (jax.image.resize(x, (height, width), "linear") for x in (slope, offset))
    base = slope * log_level + offset
    return radiance * jnp.exp((jnp.asarray(compression) - 1) * (base - jnp.mean(base)))[..., None]


def metered_exposure(
    radiance: Float[Array, "H W 3"], middle_grey: Float[ArrayLike, ""], white_point: Float[ArrayLike, ""]
) -> Float[Array, ""]:
    """The factor on the radiance that renders its log-average luminance (the scene's key: Reinhard et al. 2002,
    "Photographic tone reproduction for digital images", Eq. 1) at ``middle_grey`` through
    :func:`filmic_tone_curve`.

    A camera's averaging meter exposes whatever it sees as a mid grey, so a dim room comes out as bright as a
    sunny one, and what is far brighter than the room's average (windows, lamps) blows out. A black image gets
    the factor 1.
    """
    key = jnp.exp(jnp.mean(log_luminance(radiance)))
    target = inverse_filmic_tone_curve(middle_grey, white_point)
    return jnp.where(jnp.mean(jnp.maximum(luminance(radiance), 0.0)) > 0, target / key, 1.0)


def grey_world_gains(radiance: Float[Array, "H W 3"], strength: Float[ArrayLike, ""]) -> Float[Array, 3]:
    """Automatic white balance: per-channel gains that make the image's mean grey, raised to ``strength``
    (cameras correct only part of a warm room's cast); the gains keep the mean luminance."""
    mean = jnp.mean(radiance.reshape(-1, 3), 0)
    grey = luminance(mean)
    gains = (grey / jnp.maximum(mean, 1e-12 * grey + 1e-30)) ** strength
    return jnp.where(grey > 0, gains / luminance(gains), 1.0)


def _hable(x: Float[ArrayLike, "*S"]) -> Float[Array, "*S"]:
    a, b, c, d, e, f = _HABLE
    return (x * (a * x + c * b) + d * e) / (x * (a * x + b) + d * f) - e / f


def filmic_tone_curve(linear: Float[Array, "*S"], white_point: Float[ArrayLike, ""]) -> Float[Array, "*S"]:
    """Hable's filmic curve normalised to map ``white_point`` to 1 (display-linear, clipped to [0, 1]).

    Monotonic: a toe that deepens the shadows, a nearly linear middle, a shoulder that compresses the
    highlights smoothly up to the white point, where the film saturates.
    """
    return jnp.clip(_hable(jnp.maximum(linear, 0.0)) / _hable(white_point), 0.0, 1.0)


def inverse_filmic_tone_curve(display: Float[ArrayLike, "*S"], white_point: Float[ArrayLike, ""]) -> Float[Array, "*S"]:
    """The linear value that :func:`filmic_tone_curve` maps to ``display`` in [0, 1): the positive root of the
    quadratic that Hable's rational curve equal to ``display * curve(white_point)`` is."""
    a, b, c, d, e, f = _HABLE
    level = jnp.asarray(display) * _hable(jnp.asarray(white_point)) + e / f
    # a (1 - level) x^2 + b (c - level) x + d (e - level f) = 0
    quadratic, linear, constant = a * (1 - level), b * (c - level), d * (e - level * f)
    return (-linear + jnp.sqrt(linear**2 - 4 * quadratic * constant)) / (2 * quadratic)


def srgb_encode(linear: Float[Array, "*S"]) -> Float[Array, "*S"]:
    """The sRGB transfer function (IEC 61966-2-1) of display-linear values in [0, 1]."""
    linear = jnp.clip(linear, 0.0, 1.0)
    curve = 1.055 * jnp.maximum(linear, 0.0031308) ** (1 / 2.4) - 0.055
    return jnp.where(linear <= 0.0031308, 12.92 * linear, curve)


def nadir_patch(
    image: Float[Array, "H W 3"], rows: Float[ArrayLike, ""], blur: float, darkening: Float[ArrayLike, ""]
) -> Float[Array, "H W 3"]:
    """Hide the tripod as stitching software does: the bottom ``rows`` (a fraction of the height) replaced by
    a blurred, darkened copy, fading in over the patch's top third and darkest at the pole.

    Args:
        image: encoded RGB in [0, 1].
        rows: the patch's height as a fraction of the image height (may be traced).
        blur: the blur's standard deviation as a fraction of the image width (static: it sizes the kernel).
        darkening: the factor on the brightness at the bottom row.
    """
    height, width = image.shape[:2]
    sigma = max(blur * width, 0.5)
    blurred = gaussian_blur(image, sigma, radius=int(3 * sigma))
    # Near the pole every column sees the same few centimetres of floor: the smear becomes each row's mean.
    below = (jnp.arange(height) + 0.5) / height - (1 - rows)  # > 0 inside the patch
    depth = jnp.clip(below / jnp.maximum(rows, 1e-6), 0.0, 1.0)[:, None, None]
    smeared = depth * jnp.mean(blurred, 1, keepdims=True) + (1 - depth) * blurred
    patch = smeared * (1 - (1 - darkening) * depth)
    weight = jnp.clip(3 * depth, 0.0, 1.0) * (below > 0)[:, None, None]
    return weight * patch + (1 - weight) * image


def _between(u: Float[ArrayLike, "*S"], bounds: tuple[float, float]) -> Float[Array, "*S"]:
    return bounds[0] + jnp.asarray(u) * (bounds[1] - bounds[0])


def photograph(
    key: PRNGKeyArray, radiance: Float[Array, "H W 3"], config: PhotographConfig = PhotographConfig()
) -> Float[Array, "H W 3"]:
    """The photograph a consumer 360-degree camera would take of a linear radiance panorama.

    Args:
        key: a ``jax.random`` key, the only source of randomness (the camera's errors, noise, JPEG quality).
        radiance: (H, W, 3) linear RGB, any positive scale (the metering sets the exposure).
        config: static settings (:class:`PhotographConfig`).

    Returns:
        (H, W, 3) sRGB-encoded RGB in [0, 1], multiples of 1/255 (a decoded 8-bit file, JPEG-compressed unless
        ``native_width`` is more than twice W).
        Jit with ``config`` static; vmap over keys and images.
    """
    height, width = radiance.shape[:2]
    key_parameters, key_noise = jax.random.split(key)
    u = jax.random.uniform(key_parameters, (16,))
    if config.local_compression != (1.0, 1.0):
        radiance = local_tone_mapping(radiance, _between(u[14], config.local_compression))

    log_low, log_high = jnp.log(config.exposure_spread[0]), jnp.log(config.exposure_spread[1])
    error = jnp.exp(log_low + u[0] * (log_high - log_low))
    exposed = radiance * error * metered_exposure(radiance, config.middle_grey, config.white_point)
    gains = grey_world_gains(radiance, config.white_balance_strength) * _between(u[1:4], config.white_balance_error)
    exposed = exposed * gains

    # Two back-to-back lenses: their axes half a turn apart, the seams a quarter turn from each.
    phase = 2 * jnp.pi * u[4]
    image = srgb_encode(filmic_tone_curve(exposed, config.white_point))
    image = vignette(image, _between(u[5], config.vignetting_strength), 2, phase, 0.0)
    seam_columns = width * ((phase / (2 * jnp.pi) + 0.25 + jnp.array([0.0, 0.5])) % 1.0)
    seam_gains = jnp.stack([_between(u[6], config.seam_exposure), 1 / _between(u[6], config.seam_exposure)])
    image = stitching_seams(
        image,
        seam_columns,
        jnp.broadcast_to(seam_gains[:, None], (2, 3)),
        _between(u[7:9], config.seam_shift),
        0.01 * width,
        0.25 * width,
    )
    image = nadir_patch(
        image, _between(u[9], config.nadir_rows), config.nadir_blur, _between(u[10], config.nadir_darkening)
    )
    averaged = max(config.native_width / width, 1.0)  # native pixels per pixel, along each axis
    read_noise, shot_noise = _between(u[11], config.read_noise), _between(u[12], config.shot_noise)
    image = add_sensor_noise(key_noise, image, read_noise / averaged, shot_noise / averaged)
    if averaged > 2:
        return jnp.round(image * 255) / 255  # an 8-bit file
    return jpeg_compress(image, _between(u[13], config.jpeg_quality))
