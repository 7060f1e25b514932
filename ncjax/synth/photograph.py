"""A consumer 360-degree camera's photograph of a linear radiance panorama (pure jnp, jit/vmap-able).

The path tracer (:mod:`ncjax.synth.pathtrace`) returns physical radiance, unbounded and in arbitrary units;
a photograph is what a camera makes of it. :func:`photograph` does what the camera does, in its order:

- HDR capture (optional): the bracketed exposures fused and tone-mapped locally, as real-estate capture apps do:
  the scene's large-scale light compressed in log luminance, its detail kept
  (:func:`~ncjax.io.tone_mapping.local_tone_mapping`), so that windows show the view and shadowed corners lift;
- metering: the exposure that renders the scene's log-average luminance at a mid grey, so that whatever is far
  brighter (windows, lamps) blows out, as in real indoor panoramas;
- white balance: part of the grey-world correction of an automatic white balance, and a small random error;
- the lenses' vignetting and the stitcher's seams between the two lenses (a residual exposure and colour step,
  a pixel of parallax), from :mod:`ncjax.synth.augment`;
- a filmic tone curve (Hable's, with a shoulder that rolls highlights off to white) and the sRGB encoding;
- the nadir patch that hides the tripod: the bottom rows smeared and darkened;
- sensor noise, and the JPEG compression of the file (:func:`~ncjax.synth.augment.jpeg_compress`).

The development (metering, white balance, tone curve, encoding) is :func:`~ncjax.io.tone_mapping.develop`'s, which
also develops the linear HDR panorama files ``ncjax reconstruct`` is given (:mod:`ncjax.io.images`).

Every function takes ONE image (batch with ``jax.vmap``); random numbers come only from the key of
:func:`photograph`. The geometry is untouched (at most the seams' pixel of shift), so labels stay exact.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ..io.tone_mapping import MIDDLE_GREY, WHITE_BALANCE_STRENGTH, WHITE_POINT, develop
from ..network.denoise import gaussian_blur
from .augment import add_sensor_noise, jpeg_compress, stitching_seams, vignette


@dataclasses.dataclass(frozen=True)
class PhotographConfig:
    """Static settings of :func:`photograph` (hashable: a jit static argument).

    Each range ``(low, high)`` is drawn uniformly per photograph from its key.

    Attributes:
        local_compression: the factor on the log luminance of the scene's large-scale light
            (:func:`~ncjax.io.tone_mapping.local_tone_mapping`: 1 keeps it, as a single exposure does; 0.5 halves its
            contrasts in log, as an HDR capture app does). Off
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
    middle_grey: float = MIDDLE_GREY
    exposure_spread: tuple[float, float] = (0.8, 1.25)
    white_point: float = WHITE_POINT
    white_balance_strength: float = WHITE_BALANCE_STRENGTH
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
    log_low, log_high = jnp.log(config.exposure_spread[0]), jnp.log(config.exposure_spread[1])
    image = develop(
        radiance,
        _between(u[14], config.local_compression) if config.local_compression != (1.0, 1.0) else None,
        jnp.exp(log_low + u[0] * (log_high - log_low)),
        _between(u[1:4], config.white_balance_error),
        config.middle_grey,
        config.white_point,
        config.white_balance_strength,
    )
    # Two back-to-back lenses: their axes half a turn apart, the seams a quarter turn from each.
    phase = 2 * jnp.pi * u[4]
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
