"""Tone reproduction: linear light (a path tracer's radiance, an HDR panorama file) developed into display values.

What a camera does between its sensor and its file, without its defects (pure jnp, jit/vmap-able, one image):
the optional HDR capture's :func:`local_tone_mapping` (Durand and Dorsey 2002), the averaging meter's
:func:`metered_exposure` (Reinhard et al. 2002), part of a grey-world white balance (:func:`grey_world_gains`),
Hable's :func:`filmic_tone_curve` and the :func:`srgb_encode` encoding; :func:`develop` is all of them in that
order. The camera model of the training renders (:mod:`ncjax.synth.photograph`) adds the defects; the panorama
reader (:mod:`ncjax.io.images`) develops linear HDR files with it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..network.denoise import gaussian_blur

# Rec. 709 / sRGB luminance of linear RGB
_LUMINANCE = (0.2126, 0.7152, 0.0722)
# Hable's filmic curve ("Uncharted 2"): shoulder strength, linear strength, linear angle, toe strength,
# toe numerator and denominator.
_HABLE = (0.15, 0.50, 0.10, 0.20, 0.02, 0.30)

MIDDLE_GREY = 0.18  # the display value an averaging meter renders the scene's log-average luminance at
WHITE_POINT = 6.0  # the linear value the filmic curve maps to 1 (brighter is clipped)
WHITE_BALANCE_STRENGTH = 0.6  # the share of the grey-world correction cameras apply to a warm room's cast


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


def develop(
    radiance: Float[Array, "H W 3"],
    local_compression: Float[ArrayLike, ""] | None,
    exposure_error: Float[ArrayLike, ""],
    white_balance_error: Float[ArrayLike, 3],
    middle_grey: float = MIDDLE_GREY,
    white_point: float = WHITE_POINT,
    white_balance_strength: float = WHITE_BALANCE_STRENGTH,
) -> Float[Array, "H W 3"]:
    """A camera's development of linear radiance into display values, without its defects: the optional HDR
    capture's :func:`local_tone_mapping`, the :func:`metered_exposure` (times ``exposure_error``), part of the
    :func:`grey_world_gains` (``white_balance_strength``, times ``white_balance_error``), the
    :func:`filmic_tone_curve` and the :func:`srgb_encode` encoding.

    Args:
        radiance: (H, W, 3) linear RGB, any positive scale.
        local_compression: the factor on the large-scale light's log contrasts, or None for a single exposure.
        exposure_error: the factor on the metered exposure.
        white_balance_error: per-channel gains on the white balance.
        middle_grey: the display value the metering renders the log-average luminance at.
        white_point: the linear value the tone curve maps to 1.
        white_balance_strength: how much of the grey-world correction is applied (0: none, 1: all).

    Returns:
        (H, W, 3) sRGB-encoded RGB in [0, 1].
    """
    if local_compression is not None:
        radiance = local_tone_mapping(radiance, local_compression)
    exposed = radiance * exposure_error * metered_exposure(radiance, middle_grey, white_point)
    gains = grey_world_gains(radiance, white_balance_strength) * jnp.asarray(white_balance_error)
    return srgb_encode(filmic_tone_curve(exposed * gains, white_point))
