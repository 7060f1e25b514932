"""Noise estimation and the denoising before the network (ncjax.network.denoise)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncjax.network.denoise import NOISE_TARGET, denoise_for_network, noise_sigma


def _scene(height=128, width=256):
    """A smooth shaded panorama-like image with a few hard edges (like a rendered room)."""
    rows, columns = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    grey = 0.3 + 0.4 * rows + 0.1 * np.sin(6 * columns)
    grey = np.where(rows > 0.7, 0.2, np.where(rows < 0.25, 0.85, grey))
    return jnp.asarray(np.repeat(grey[..., None], 3, -1), jnp.float32)


@pytest.mark.parametrize("sigma", [0.01, 0.03, 0.06])
def test_noise_sigma_matches_the_added_noise(sigma):
    noisy = _scene() + sigma * jax.random.normal(jax.random.key(0), (128, 256, 1))  # the same noise on each channel
    assert float(noise_sigma(noisy)) == pytest.approx(sigma, rel=0.1)
    assert float(noise_sigma(_scene())) < 0.2 * NOISE_TARGET


@pytest.mark.slow
def test_clean_images_pass_unchanged_and_noisy_ones_reach_the_target():
    clean = _scene(512, 1024)  # the blur's cap is 2.5 px at 512 rows
    np.testing.assert_array_equal(denoise_for_network(clean[None]), clean[None])  # a clean batch skips the blur
    noisy = jnp.clip(clean + 0.04 * jax.random.normal(jax.random.key(1), (512, 1024, 1)), 0.0, 1.0)
    # one batch: the blur runs, with sigma 0 (the identity) for the clean image
    kept, denoised = denoise_for_network(jnp.stack([clean, noisy]))
    np.testing.assert_array_equal(kept, clean)
    # away from the hard edges (rows 128 and 358) the blur leaves the scene and the noise falls to the target
    # (measured directly: the estimator, made for white noise, reads the blurred noise low)
    smooth = slice(180, 320)
    assert float(jnp.std(denoised[smooth] - clean[smooth])) == pytest.approx(NOISE_TARGET, rel=0.25)
    assert float(jnp.std(noisy[smooth] - clean[smooth])) == pytest.approx(0.04, rel=0.05)
