"""Image noise estimated, and brought down to what the network was trained on (pure jnp, jit/vmap-able).

The shipped network was trained on clean renders (training augments gamma, brightness and greyscale,
no sensor noise); on noisy panoramas its rows fall apart (experiments/RESULTS.md: at a read and
shot sigma of 0.05, 84-94% of the test rooms fail). A panorama whose estimated noise exceeds a
target is blurred just enough to bring it to that target before the network and the edge snap
see it; a clean panorama is left bit for bit as it is.

Its two pixel operations, greyscale and a wrap-around Gaussian blur, are also among the training
augmentations (:mod:`ncjax.synth.augment`).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

# Luma noise the network is given at most: inside its training range, above our clean renders' 0.006.
NOISE_TARGET = 0.01
_MAX_BLUR = 2.5  # pixels at 512 rows: a stronger blur costs more than the noise it removes
_BLUR_RADIUS = 8  # static kernel half-width, >= 3 sigmas of the strongest blur
_LUMA = np.array([0.299, 0.587, 0.114], np.float32)  # numpy: importing ncjax starts no JAX backend


def to_greyscale(image: Float[Array, "H W 3"]) -> Float[Array, "H W 3"]:
    """Luma (ITU-R 601) copied to the three channels."""
    return jnp.broadcast_to((image @ _LUMA)[..., None], image.shape)


def gaussian_blur(image: Float[Array, "H W C"], sigma: Float[ArrayLike, ""], radius: int = 3) -> Float[Array, "H W C"]:
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


def noise_sigma(image: Float[Array, "H W 3"]) -> Float[Array, ""]:
    """Standard deviation of white noise on the image's luma, by Immerkaer's estimator.

    J. Immerkaer, "Fast noise variance estimation", CVIU 64(2), 1996: the
    mean absolute response to the 3 x 3 mask [[1, -2, 1], [-2, 4, -2], [1, -2, 1]],
    which cancels planar intensity, times sqrt(pi / 2) / 6. Edges and texture add
    to it a little (about 0.002 on our clean renders).

    Args:
        image: RGB, float in [0, 1].
    """
    luma = to_greyscale(image)[..., 0]
    horizontal = luma[:, :-2] - 2 * luma[:, 1:-1] + luma[:, 2:]  # second difference along each row
    response = horizontal[:-2] - 2 * horizontal[1:-1] + horizontal[2:]  # then along the columns: the 3 x 3 mask
    return math.sqrt(math.pi / 2) / 6 * jnp.mean(jnp.abs(response))


def denoise_for_network(images: Float[Array, "B H W 3"], target: float = NOISE_TARGET) -> Float[Array, "B H W 3"]:
    """The images blurred so that their noise falls to about ``target``; unchanged where the estimate is below.

    A Gaussian blur of sigma ``s`` pixels divides white noise by about ``2 sqrt(pi) s``,
    so ``s = noise / (2 sqrt(pi) target)``, capped at 2.5 px (at 512 rows, scaled with
    the height). Below the target ``s`` is 0, whose kernel is exactly the identity.
    This takes a batch, unlike the rest of the module, so that a batch without a noisy
    image skips the blur (one ``lax.cond``; under ``vmap`` both branches would run):
    on the CPU the blur costs about 15 times the noise estimate.

    Args:
        images: RGB, float in [0, 1].
        target: luma noise sigma to reach.
    """
    noise = jax.vmap(noise_sigma)(images)
    scale = images.shape[1] / 512
    sigma = jnp.minimum(jnp.where(noise > target, noise / (2 * math.sqrt(math.pi) * target), 0.0), _MAX_BLUR * scale)
    radius = max(1, round(_BLUR_RADIUS * scale))

    def blurred(batch):
        return jax.vmap(gaussian_blur, in_axes=(0, 0, None))(batch, sigma, radius)

    return jax.lax.cond(jnp.any(sigma > 0), blurred, lambda batch: batch, images)
