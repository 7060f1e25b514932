"""The camera model (ncjax.synth.photograph) and its development (ncjax.io.tone_mapping): the tone curve and
encoding against their definitions, the metering's normalisation, the white balance, the nadir patch, the local tone
mapping of an HDR capture, the development as their composition, and the photograph's type, range, determinism and
JPEG file."""

import dataclasses
import io

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from PIL import Image

from ncjax.io.tone_mapping import (
    develop,
    filmic_tone_curve,
    grey_world_gains,
    inverse_filmic_tone_curve,
    local_tone_mapping,
    luminance,
    metered_exposure,
    srgb_encode,
)
from ncjax.synth.photograph import PhotographConfig, nadir_patch, photograph
from ncjax.synth.photoreal import DEVELOPMENT

HEIGHT, WIDTH = 16, 32

_photograph = jax.jit(photograph, static_argnames="config")
# the camera's own size: its noise and JPEG as they are in the file, before any downsampling
AT_NATIVE_WIDTH = PhotographConfig(native_width=WIDTH)


def _radiance(seed: int = 0) -> np.ndarray:
    """A small linear radiance panorama: a smooth room of warm light with a few very bright (window) pixels."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    base = 0.05 + 0.1 * (1 + np.sin(2 * np.pi * u / WIDTH)) * (1 - v / HEIGHT)
    image = base[..., None] * np.array([1.2, 1.0, 0.7], np.float32) * rng.uniform(0.9, 1.1, (HEIGHT, WIDTH, 3))
    image[4:7, 10:14] = 30.0
    return image.astype(np.float32)


def test_tone_curve_is_monotonic_from_black_to_the_white_point():
    x = jnp.linspace(0.0, 10.0, 2001)
    curve = np.asarray(filmic_tone_curve(x, 6.0))
    assert curve[0] == pytest.approx(0.0, abs=1e-6)
    assert np.all(np.diff(curve) >= 0) and np.all(np.diff(curve[x <= 6.0]) > 0)
    np.testing.assert_allclose(filmic_tone_curve(jnp.float32(6.0), 6.0), 1.0, rtol=1e-6)
    assert np.all(curve[x >= 6.0] == 1.0)  # beyond the white point the film is saturated
    assert 0.1 < float(filmic_tone_curve(jnp.float32(0.6), 6.0)) < 0.5  # a tenth of white is a mid tone


def test_srgb_encoding_is_the_standards():
    x = jnp.array([0.0, 0.002, 0.0031308, 0.18, 0.5, 1.0, 2.0])
    expected = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.clip(x, 0, 1) ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(srgb_encode(x), np.clip(expected, 0, 1), atol=1e-6)
    assert float(srgb_encode(jnp.float32(0.18))) == pytest.approx(0.4613, abs=1e-3)


def test_metering_renders_the_log_average_at_middle_grey_and_ignores_the_scale():
    radiance = jnp.asarray(_radiance())
    factor = metered_exposure(radiance, 0.18, 6.0)
    key = np.exp(np.mean(np.log(np.asarray(luminance(radiance * factor), np.float64))))
    assert float(filmic_tone_curve(jnp.float32(key), 6.0)) == pytest.approx(0.18, rel=1e-3)
    np.testing.assert_allclose(metered_exposure(7.0 * radiance, 0.18, 6.0) * 7.0, factor, rtol=1e-5)
    assert float(metered_exposure(jnp.zeros((HEIGHT, WIDTH, 3)), 0.18, 6.0)) == 1.0


def test_the_inverse_tone_curve_undoes_it():
    display = jnp.linspace(0.01, 0.99, 50)
    for white_point in (2.0, 6.0, 11.2):
        linear = inverse_filmic_tone_curve(display, white_point)
        np.testing.assert_allclose(filmic_tone_curve(linear, white_point), display, atol=1e-5)
        assert np.all(np.diff(np.asarray(linear)) > 0) and float(linear[-1]) < white_point


def test_grey_world_gains_make_the_mean_grey_and_keep_its_luminance():
    radiance = jnp.asarray(_radiance())
    mean = np.asarray(jnp.mean(radiance.reshape(-1, 3), 0))
    gains = np.asarray(grey_world_gains(radiance, 1.0))
    balanced = mean * gains
    np.testing.assert_allclose(balanced, np.full(3, balanced[0]), rtol=1e-5)
    np.testing.assert_allclose(luminance(jnp.asarray(gains)), 1.0, rtol=1e-5)
    np.testing.assert_allclose(grey_world_gains(radiance, 0.0), np.ones(3), rtol=1e-6)
    half = np.asarray(grey_world_gains(radiance, 0.5))
    assert np.all((np.minimum(gains, 1) - 1e-6 <= half) & (half <= np.maximum(gains, 1) + 1e-6))


def test_nadir_patch_covers_the_bottom_rows_only_and_darkens_the_pole():
    image = jnp.asarray(np.clip(_radiance(1), 0, 1) ** (1 / 2.2))
    patched = np.asarray(nadir_patch(image, 0.25, 0.05, 0.5))
    np.testing.assert_array_equal(patched[: HEIGHT * 3 // 4], np.asarray(image)[: HEIGHT * 3 // 4])
    assert patched[-1].mean() < 0.6 * np.asarray(image)[-1].mean()
    # Towards the pole every column becomes the row's mean.
    assert np.std(patched[-1], axis=0).max() < 0.25 * np.std(np.asarray(image)[-1], axis=0).max()


@pytest.mark.slow
def test_photograph_is_an_8_bit_image_deterministic_per_key():
    radiance = jnp.asarray(_radiance())
    image = np.asarray(_photograph(jax.random.key(0), radiance, AT_NATIVE_WIDTH))
    assert image.shape == (HEIGHT, WIDTH, 3) and image.dtype == np.float32
    assert image.min() >= 0 and image.max() <= 1
    np.testing.assert_allclose(image * 255, np.round(image * 255), atol=1e-3)  # a decoded 8-bit JPEG
    np.testing.assert_array_equal(np.asarray(_photograph(jax.random.key(0), radiance, AT_NATIVE_WIDTH)), image)
    assert not np.array_equal(np.asarray(_photograph(jax.random.key(1), radiance, AT_NATIVE_WIDTH)), image)
    assert image[4:7, 10:14].mean() > 0.9  # the window blows out
    # The metering normalises the exposure: ten times the light is the same photograph.
    brighter = np.asarray(_photograph(jax.random.key(0), 10.0 * radiance, AT_NATIVE_WIDTH))
    assert np.abs(brighter - image).mean() < 2e-3 and np.abs(brighter - image).max() <= 3 / 255 + 1e-6
    # A batch of photographs is the photographs of its images.
    keys = jax.random.split(jax.random.key(2), 2)
    batch = jnp.stack([radiance, 3.0 * radiance])
    batched = jax.vmap(lambda key, x: photograph(key, x, AT_NATIVE_WIDTH))(keys, batch)
    np.testing.assert_allclose(batched[1], _photograph(keys[1], batch[1], AT_NATIVE_WIDTH), atol=1.5 / 255)


def test_a_photograph_without_defects_is_its_development():
    """A camera without errors, vignetting, seams, nadir patch, noise or JPEG takes :func:`develop`'s image, rounded
    to 8 bits; the development is its definition: local tone mapping, metering, white balance, tone curve, sRGB."""
    flawless = dataclasses.replace(  # the renders' development, its errors off too, no JPEG
        DEVELOPMENT,
        local_compression=(0.5, 0.5),
        exposure_spread=(1.0, 1.0),
        white_balance_error=(1.0, 1.0),
        native_width=4 * WIDTH,
    )
    radiance = jnp.asarray(_radiance(3))
    developed = np.asarray(develop(radiance, 0.5, 1.0, jnp.ones(3)))
    photographed = np.asarray(_photograph(jax.random.key(5), radiance, flawless))
    np.testing.assert_allclose(photographed, developed, atol=0.5 / 255)
    mapped = local_tone_mapping(radiance, 0.5)
    exposed = mapped * metered_exposure(mapped, 0.18, 6.0) * grey_world_gains(mapped, 0.6)
    np.testing.assert_allclose(developed, srgb_encode(filmic_tone_curve(exposed, 6.0)), atol=1e-6)
    # Without the local tone mapping (None), the room's large-scale light keeps its contrast: its bright half
    # against its dark half (the walls, not the window) differ more.
    single = np.asarray(develop(radiance, None, 1.0, jnp.ones(3)))
    bright, dark = slice(WIDTH // 8, 3 * WIDTH // 8), slice(5 * WIDTH // 8, 7 * WIDTH // 8)
    contrast = [image[8:, bright].mean() - image[8:, dark].mean() for image in (single, developed)]
    assert contrast[0] > contrast[1] > 0, contrast


@pytest.mark.slow
def test_a_downsampled_photograph_has_the_noise_of_the_pixels_it_averages():
    """Read at a k-th of the camera's width (no JPEG then), a photograph's sensor noise is a k-th of the file's."""
    radiance = jnp.asarray(_radiance())
    quiet = dict(read_noise=(0.0, 0.0), shot_noise=(0.0, 0.0))
    loud = dict(read_noise=(0.2, 0.2), shot_noise=(0.0, 0.0))
    spread = []
    for native_width in (4 * WIDTH, 16 * WIDTH):
        clean, noisy = (
            np.asarray(_photograph(jax.random.key(5), radiance, PhotographConfig(native_width=native_width, **noise)))
            for noise in (quiet, loud)
        )
        unclipped = (clean > 0.2) & (clean < 0.8)
        spread.append(np.std((noisy - clean)[unclipped]))
    assert spread[0] == pytest.approx(0.05, rel=0.15)
    assert spread[1] == pytest.approx(0.0125, rel=0.25)


@pytest.mark.slow
def test_photograph_survives_a_real_jpeg_round_trip():
    image = np.asarray(_photograph(jax.random.key(3), jnp.asarray(_radiance(2))))
    buffer = io.BytesIO()
    Image.fromarray(np.round(image * 255).astype(np.uint8)).save(buffer, format="JPEG", quality=90)
    decoded = np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB"), np.float32) / 255
    assert decoded.shape == image.shape
    assert np.abs(decoded - image).mean() < 0.02


def test_configuration_rejects_bad_values():
    for bad in (
        dict(middle_grey=0.0),
        dict(middle_grey=1.0),
        dict(native_width=0.0),
        dict(white_point=0.0),
        dict(white_balance_strength=1.5),
        dict(nadir_rows=(0.2, 0.1)),
        dict(local_compression=(0.0, 0.5)),
        dict(local_compression=(0.8, 0.5)),
        dict(local_compression=(0.5, 1.5)),
    ):
        with pytest.raises(ValueError):
            PhotographConfig(**bad)


def _window_wall(fine_contrast: float = 0.0) -> np.ndarray:
    """A 64 x 128 panorama: a dim wall (radiance 1) with a window 100 times brighter over a quarter of the columns,
    a warm colour, and a fine checker of ``fine_contrast`` (relative) over everything."""
    v, u = np.mgrid[0:64, 0:128]
    level = np.where((u >= 48) & (u < 80), 100.0, 1.0) * (1 + fine_contrast * ((u + v) % 2 * 2 - 1))
    return (level[..., None] * np.array([1.2, 1.0, 0.7])).astype(np.float32)


def test_local_tone_mapping_compresses_the_light_and_keeps_fine_detail_and_colour():
    wall = _window_wall(fine_contrast=0.05)
    mapped = np.asarray(jax.jit(local_tone_mapping)(jnp.asarray(wall), 0.5))
    level = luminance(mapped)
    # Far from the window's edges the 100:1 step becomes about 10:1: its log halved.
    window, dim = level[24:40, 56:72].mean(), level[24:40, 4:20].mean()
    assert 8 < window / dim < 12.5
    # The checker's 5% (a 1.105 ratio between neighbours) is detail: kept within a percent.
    neighbours = level[30, 9:13] / level[30, 8:12]
    np.testing.assert_allclose(np.maximum(neighbours, 1 / neighbours), 1.05 / 0.95, rtol=0.01)
    # Each pixel's colour is kept: every channel takes the same factor.
    np.testing.assert_allclose(mapped / mapped[..., 1:2], wall / wall[..., 1:2], rtol=1e-5)


def test_local_tone_mapping_at_compression_one_changes_nothing():
    wall = jnp.asarray(_window_wall(fine_contrast=0.05))
    np.testing.assert_allclose(np.asarray(local_tone_mapping(wall, 1.0)), np.asarray(wall), rtol=1e-6)
