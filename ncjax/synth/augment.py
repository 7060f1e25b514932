"""Photometric augmentations of panoramas for training (pure jnp, jit/vmap-able).

Every function takes an RGB image (H, W, 3) float in [0, 1] (docs/design.md section 5)
and returns one of the same shape, clipped to [0, 1]; random ones take a
``jax.random`` key first. Geometry is untouched, so the labels stay valid.
Real non-central captures are often grey, so greyscale is among them.
Horizontal operations wrap around: a panorama's left and right edges meet.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

_LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # numpy: importing ncjax starts no JAX backend


def adjust_exposure(image: Float[Array, "H W 3"], factor: Float[ArrayLike, ""]) -> Float[Array, "H W 3"]:
    """Scale the linear intensities (the image is gamma 2.2 encoded) by ``factor``."""
    return jnp.clip(image * factor ** (1 / 2.2), 0.0, 1.0)


def adjust_gamma(image: Float[Array, "H W 3"], gamma: Float[ArrayLike, ""]) -> Float[Array, "H W 3"]:
    """``image ** gamma``."""
    return jnp.clip(image, 0.0, 1.0) ** gamma


def white_balance(image: Float[Array, "H W 3"], gains: Float[ArrayLike, 3]) -> Float[Array, "H W 3"]:
    """Per-channel gains (a colour cast)."""
    return jnp.clip(image * gains, 0.0, 1.0)


def to_greyscale(image: Float[Array, "H W 3"]) -> Float[Array, "H W 3"]:
    """Luma (ITU-R 601) copied to the three channels."""
    return jnp.broadcast_to((image @ _LUMA)[..., None], image.shape)


def add_sensor_noise(
    key: PRNGKeyArray, image: Float[Array, "H W 3"], read_sigma: Float[ArrayLike, ""], shot_sigma: Float[ArrayLike, ""]
) -> Float[Array, "H W 3"]:
    """Gaussian noise whose variance grows with the intensity (read + shot noise)."""
    sigma = jnp.sqrt(read_sigma**2 + shot_sigma**2 * jnp.clip(image, 0.0, 1.0))
    return jnp.clip(image + sigma * jax.random.normal(key, image.shape), 0.0, 1.0)


def gaussian_blur(image: Float[Array, "H W 3"], sigma: Float[ArrayLike, ""], radius: int = 3) -> Float[Array, "H W 3"]:
    """Separable Gaussian blur of standard deviation ``sigma`` pixels (a static
    ``radius`` bounds the kernel): wraps around horizontally, clamps vertically."""
    offsets = jnp.arange(-radius, radius + 1)
    weights = jnp.exp(-0.5 * (offsets / jnp.maximum(sigma, 1e-3)) ** 2)
    weights = weights / jnp.sum(weights)
    # each pass sums slices of one padded copy (wrapped, then edge-padded), which XLA fuses: shifted copies
    # (jnp.roll) or a gather of (H, 2 radius + 1, W, 3) rows are materialised, 27 GB for four 4096 x 2048 images
    height, width = image.shape[:2]
    wrapped = jnp.pad(image, ((0, 0), (radius, radius), (0, 0)), mode="wrap")
    horizontal = sum(w * wrapped[:, 2 * radius - k : 2 * radius - k + width] for k, w in enumerate(weights))
    padded = jnp.pad(horizontal, ((radius, radius), (0, 0), (0, 0)), mode="edge")
    return sum(w * padded[k : k + height] for k, w in enumerate(weights))


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Ranges and probabilities of :func:`random_augment` (static, hashable)."""

    exposure: tuple[float, float] = (0.5, 2.0)
    gamma: tuple[float, float] = (0.8, 1.25)
    white_balance: tuple[float, float] = (0.85, 1.15)
    read_noise: tuple[float, float] = (0.0, 0.02)
    shot_noise: tuple[float, float] = (0.0, 0.04)
    blur_sigma: tuple[float, float] = (0.3, 1.2)
    blur_probability: float = 0.3
    greyscale_probability: float = 0.2


def random_augment(
    key: PRNGKeyArray, image: Float[Array, "H W 3"], config: AugmentConfig = AugmentConfig()
) -> Float[Array, "H W 3"]:
    """Exposure, gamma, white balance, blur (sometimes), greyscale (sometimes) and
    sensor noise, with parameters drawn from ``config``'s ranges."""
    key_noise, key_parameters = jax.random.split(key)
    u = jax.random.uniform(key_parameters, (10,))

    def between(x, bounds):
        return bounds[0] + x * (bounds[1] - bounds[0])

    # Exposure is drawn log-uniformly: halving and doubling are equally likely.
    log_low, log_high = jnp.log(config.exposure[0]), jnp.log(config.exposure[1])
    image = adjust_exposure(image, jnp.exp(log_low + u[0] * (log_high - log_low)))
    image = adjust_gamma(image, between(u[1], config.gamma))
    image = white_balance(image, between(u[2:5], config.white_balance))
    image = jnp.where(u[5] < config.blur_probability, gaussian_blur(image, between(u[6], config.blur_sigma)), image)
    image = jnp.where(u[7] < config.greyscale_probability, to_greyscale(image), image)
    return add_sensor_noise(key_noise, image, between(u[8], config.read_noise), between(u[9], config.shot_noise))
