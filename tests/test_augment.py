"""Camera effects of the augmentation module against numpy / OpenCV references and their defining properties."""

from __future__ import annotations

import dataclasses
import json

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.fft import dctn

from ncjax.network.denoise import to_greyscale
from ncjax.synth import augment

HEIGHT, WIDTH = 32, 64


def smooth_image(height: int = HEIGHT, width: int = WIDTH) -> np.ndarray:
    """A smooth colourful 8-bit image (as float in [0, 1]): what JPEG is made for."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    red = 0.5 + 0.35 * np.sin(2 * np.pi * u / width) * np.cos(np.pi * v / height)
    green = 0.2 + 0.6 * v / height
    blue = 0.5 + 0.3 * np.cos(2 * np.pi * (u + 2 * v) / width)
    return np.round(np.stack([red, green, blue], axis=-1) * 255) / 255


# ----------------------------------------------------------------------------- JPEG


def test_block_dct_is_scipys_orthonormal_dct_per_block():
    plane = np.random.default_rng(0).normal(size=(16, 24)).astype(np.float32)
    expected = np.block(
        [[dctn(plane[i : i + 8, j : j + 8], norm="ortho") for j in range(0, 24, 8)] for i in range(0, 16, 8)]
    )
    coefficients = augment.block_dct(jnp.asarray(plane))
    np.testing.assert_allclose(coefficients, expected, atol=1e-5)
    np.testing.assert_allclose(augment.block_idct(coefficients), plane, atol=1e-5)


@pytest.mark.parametrize("quality", [1, 10, 49, 50, 75, 100])
def test_quantisation_table_is_libjpegs(quality):
    base = augment._JPEG_LUMA_TABLE.astype(np.int64)
    scale = 5000 // quality if quality < 50 else 200 - 2 * quality  # libjpeg's jpeg_quality_scaling
    expected = np.clip((base * scale + 50) // 100, 1, 255)
    np.testing.assert_array_equal(augment.jpeg_quantisation_table(augment._JPEG_LUMA_TABLE, quality), expected)


@pytest.mark.parametrize("quality, subsampling", [(90, False), (30, False), (75, True), (20, True)])
@pytest.mark.parametrize("height, width", [(HEIGHT, WIDTH), (30, 52)])
def test_jpeg_matches_opencv(quality, subsampling, height, width):
    image = smooth_image(height, width)
    factor = cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420 if subsampling else cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444
    bgr = np.round(image[..., ::-1] * 255).astype(np.uint8)
    ok, encoded = cv2.imencode(
        ".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality, cv2.IMWRITE_JPEG_SAMPLING_FACTOR, factor]
    )
    assert ok
    expected = cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1] / 255
    ours = np.asarray(augment.jpeg_compress(jnp.asarray(image, jnp.float32), quality, subsampling))
    assert ours.shape == image.shape
    np.testing.assert_allclose(ours * 255, np.round(ours * 255), atol=1e-3)  # decoded to 8 bits
    # libjpeg's integer DCT and rounding differ slightly from the exact transform
    assert np.abs(ours - expected).mean() < 1.5 / 255
    # ... and much less than what the compression changes
    assert np.abs(ours - expected).mean() < 0.5 * np.abs(expected - image).mean() or quality > 80


def test_jpeg_at_quality_100_is_nearly_lossless():
    image = smooth_image()
    out = np.asarray(augment.jpeg_compress(jnp.asarray(image, jnp.float32), 100, chroma_subsampling=False))
    assert np.abs(out - image).max() <= 2 / 255 and np.abs(out - image).mean() < 0.5 / 255


def test_low_quality_jpeg_shows_its_blocks():
    image = smooth_image()
    luma = np.asarray(to_greyscale(augment.jpeg_compress(jnp.asarray(image, jnp.float32), 5)))[..., 0]
    steps = np.abs(np.diff(luma, axis=1))  # steps[:, u] is between columns u and u + 1
    across = (np.arange(WIDTH - 1) + 1) % 8 == 0
    assert steps[:, across].mean() > 3 * steps[:, ~across].mean()
    original = np.abs(np.diff(np.asarray(to_greyscale(jnp.asarray(image)))[..., 0], axis=1))
    assert original[:, across].mean() < 1.5 * original[:, ~across].mean()  # the blocks are the compression's


# ----------------------------------------------------------------------------- black bands

_NOISE = np.random.default_rng(1).uniform(0.01, 1.0, (HEIGHT, WIDTH, 3)).astype(np.float32)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 6), st.integers(0, 6))
def test_black_bands_are_zero_exactly_in_their_rows_and_leave_the_rest(top, bottom):
    out = np.asarray(augment.black_bands(jnp.asarray(_NOISE), top, bottom))
    covered = np.zeros(HEIGHT, bool)
    covered[top : HEIGHT - bottom] = True
    assert np.all(out[~covered] == 0.0)
    np.testing.assert_array_equal(out[covered], _NOISE[covered])


def test_black_band_heights_round_up():
    out = np.asarray(augment.black_bands(jnp.asarray(_NOISE), 2.3, 0.5))
    assert np.all(out[:3] == 0) and np.all(out[-1] == 0)
    np.testing.assert_array_equal(out[3:-1], _NOISE[3:-1])


# ----------------------------------------------------------------------------- vignetting


@pytest.mark.parametrize("lenses", [2, 3, 4, 5, 6])
def test_vignetting_is_at_most_one_and_periodic_in_the_lenses(lenses):
    height, width, strength = 16, 60, 0.4  # 60 columns: whole columns per lens
    factor = np.asarray(augment.vignetting_factor(height, width, strength, lenses, 1.0, 0.2))
    assert np.all(factor <= 1.0) and np.all(factor > 0.0)
    np.testing.assert_allclose(np.roll(factor, width // lenses, axis=1), factor, atol=1e-6)
    # azimuth only: 1 on a lens axis (column 0's centre), 1 - strength half-way to the next
    phase = np.pi / width
    horizontal = np.asarray(augment.vignetting_factor(height, width, strength, lenses, phase, 0.0))
    np.testing.assert_allclose(horizontal[:, 0], 1.0, atol=1e-6)
    if width % (2 * lenses) == 0:
        np.testing.assert_allclose(horizontal[:, width // (2 * lenses)], 1.0 - strength, atol=1e-6)
    assert horizontal.min() >= 1.0 - strength - 1e-6


def test_vignetting_darkens_towards_the_poles_symmetrically():
    factor = np.asarray(augment.vignetting_factor(32, 8, 0.0, 3, 0.0, 0.25))[:, 0]
    np.testing.assert_allclose(factor, factor[::-1], atol=1e-6)
    assert np.all(np.diff(factor[:16]) > 0)  # brightest at the horizon
    assert 0.75 <= factor[0] < 0.76  # the polar row's centre is 2.8 degrees off the pole


def test_vignette_scales_the_linear_intensities():
    image = jnp.full((16, 60, 3), 0.5)
    factor = augment.vignetting_factor(16, 60, 0.5, 4, 0.3, 0.2)
    expected = np.broadcast_to(0.5 * factor[..., None] ** (1 / 2.2), image.shape)
    np.testing.assert_allclose(augment.vignette(image, 0.5, 4, 0.3, 0.2), expected, atol=1e-6)


# ----------------------------------------------------------------------------- stitching seams


def _seam_weight(width, column, blend, extent):
    """Documented seam profile: a linear rise over ``blend`` centred on the seam, a fade over ``extent`` after it."""
    distance = (np.arange(width) - column + width / 2) % width - width / 2
    return np.clip(distance / blend + 0.5, 0, 1) * np.clip(1 - distance / extent, 0, 1)


def test_seams_leave_columns_far_from_them_untouched():
    columns, blend, extent = np.array([10.0, 60.5]), 4.0, 12.0
    gains, shifts = np.array([[1.2, 0.9, 1.05], [0.8, 0.85, 0.9]]), np.array([1.5, -2.0])
    out = np.asarray(augment.stitching_seams(jnp.asarray(_NOISE), columns, gains, shifts, blend, extent))
    touched = sum(_seam_weight(WIDTH, c, blend, extent) for c in columns) > 0
    # the second seam wraps round: it changes columns 59 to 63 and 0 to 11
    assert touched[[9, 10, 20, 59, 63, 0, 8]].all() and not touched[[23, 40, 57]].any()
    np.testing.assert_array_equal(out[:, ~touched], _NOISE[:, ~touched])
    assert not np.allclose(out[:, touched], _NOISE[:, touched])
    neutral = augment.stitching_seams(jnp.asarray(_NOISE), columns, np.ones((2, 3)), np.zeros(2), blend, extent)
    np.testing.assert_array_equal(neutral, _NOISE)


def test_seam_gain_and_shift_follow_the_profile():
    rows = np.arange(HEIGHT, dtype=np.float32)
    ramp = np.broadcast_to((0.2 + 0.02 * rows)[:, None, None], (HEIGHT, WIDTH, 3))  # linear in the row
    column, blend, extent, gain, shift = 20.0, 6.0, 16.0, np.array([1.1, 1.0, 0.9]), 1.5
    out = np.asarray(
        augment.stitching_seams(jnp.asarray(ramp), np.array([column]), gain[None], np.array([shift]), blend, extent)
    )
    weight = _seam_weight(WIDTH, column, blend, extent)
    # linear interpolation of a linear ramp is exact away from the edge rows
    expected = (0.2 + 0.02 * (rows[:, None] - weight * shift))[..., None] * gain ** weight[:, None]
    np.testing.assert_allclose(out[2:-2], expected[2:-2], atol=1e-6)


# ----------------------------------------------------------------------------- random_augment

_EVERYTHING = augment.AugmentConfig(
    blur_probability=1.0,
    vignetting_probability=1.0,
    jpeg_probability=1.0,
    band_probability=1.0,
    band_height=(0.1, 0.12),
    seam_probability=1.0,
)
_TRACES: list[augment.AugmentConfig] = []


@jax.jit
def _augment_default(key, image):
    _TRACES.append(augment.AugmentConfig())
    return augment.random_augment(key, image)


def test_random_augment_is_pure_keeps_shape_and_range_and_compiles_once():
    image = jnp.asarray(smooth_image(), jnp.float32)
    outputs = [_augment_default(jax.random.key(seed), image) for seed in range(6)]
    assert len(_TRACES) == 1
    for out in outputs:
        assert out.shape == image.shape and out.dtype == jnp.float32
        assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    np.testing.assert_array_equal(_augment_default(jax.random.key(0), image), outputs[0])
    assert not np.allclose(outputs[0], outputs[1])
    assert len(_TRACES) == 1


@pytest.mark.slow
def test_random_augment_with_every_effect_on():
    image = jnp.asarray(smooth_image(), jnp.float32)
    augmented = jax.jit(jax.vmap(augment.random_augment, in_axes=(0, None, None)), static_argnums=2)
    out = np.asarray(augmented(jax.random.split(jax.random.key(2), 3), image, _EVERYTHING))
    assert out.shape == (3, HEIGHT, WIDTH, 3) and np.all((out >= 0) & (out <= 1))
    # black bands of at least ceil(0.1 * 32) = 4 rows, up to JPEG's ringing near them
    assert out[:, :4].mean() < 0.05 and out[:, -4:].mean() < 0.05
    assert out[:, 8:-8].mean() > 0.1
    assert not np.allclose(out[0], out[1])


def test_augment_config_survives_json():
    config = dataclasses.replace(_EVERYTHING, vignetting_lenses=(3, 4), jpeg_chroma_subsampling=False)
    restored = augment.AugmentConfig.from_dict(json.loads(json.dumps(dataclasses.asdict(config))))
    assert restored == config and hash(restored) == hash(config)
