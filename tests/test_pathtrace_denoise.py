"""The path tracer's denoiser (ncjax.synth.pathtrace_denoise): on hand-made guides, what it must keep (textures,
edges between surfaces, the environment, a noise-free image) and what it must remove (noise, with the mean
kept); light traced at half size brought to full size without crossing edges; on a path-traced room, a few
samples a pixel denoised come closer to many samples a pixel."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ncjax
from ncjax.geometry.camera import pixel_to_angles
from ncjax.synth.pathtrace import PathTraceConfig, path_trace
from ncjax.synth.pathtrace_denoise import (
    DenoiseConfig,
    GuideBuffers,
    demodulated,
    denoise,
    guide_buffers,
    remodulated,
    shifted,
    upsampled_light,
)
from ncjax.synth.pathtrace_reference import comparison_scene
from ncjax.synth.pathtrace_scene import SurfaceKind

HEIGHT, WIDTH = 32, 64
# the path-traced room's size: at 32 x 64 a pixel spans 6 degrees, over which its true light varies too much
TRACED_HEIGHT, TRACED_WIDTH = 64, 128
_denoise = jax.jit(denoise, static_argnames="config")


def _flat_guides(surface=None, albedo=None, shape=(HEIGHT, WIDTH)) -> GuideBuffers:
    """One wall facing the camera at 2 m (or the surfaces numbered by ``surface``), albedo 0.5 unless given."""
    surface = np.full(shape, 3 + len(SurfaceKind)) if surface is None else surface
    albedo = np.full((*shape, 3), 0.5) if albedo is None else albedo
    normal = np.broadcast_to([0.0, -1.0, 0.0], (*shape, 3))
    depth = np.full(shape, 2.0)
    return GuideBuffers(
        jnp.asarray(albedo, jnp.float32),
        jnp.asarray(normal, jnp.float32),
        jnp.asarray(depth, jnp.float32),
        jnp.asarray(surface, jnp.int32),
    )


def test_shifts_wrap_around_the_columns_and_stop_at_the_first_and_last_rows():
    image = np.arange(5 * 7).reshape(5, 7)
    for rows, columns in [(0, 0), (1, 0), (-2, 3), (4, -5), (-6, 9)]:
        source_rows = np.clip(np.arange(5) + rows, 0, 4)
        source_columns = (np.arange(7) + columns) % 7
        expected = image[source_rows][:, source_columns]
        np.testing.assert_array_equal(np.asarray(shifted(jnp.asarray(image), rows, columns)), expected)


def test_noise_is_removed_and_the_texture_and_the_mean_kept():
    rng = np.random.default_rng(0)
    rows, columns = np.meshgrid(np.arange(HEIGHT), np.arange(WIDTH), indexing="ij")
    albedo = np.where(((rows // 4 + columns // 4) % 2)[..., None] == 0, [0.8, 0.6, 0.4], [0.2, 0.3, 0.3])
    irradiance = 1.0 + 0.3 * np.sin(2 * np.pi * columns / WIDTH)[..., None]  # slow light falloff
    clean = albedo * irradiance
    noisy = clean * rng.gamma(4.0, 1 / 4.0, clean.shape)  # positive, mean 1, 50% noise
    denoised = np.asarray(_denoise(jnp.asarray(noisy, jnp.float32), _flat_guides(albedo=albedo)))
    before = np.sqrt(np.mean((noisy - clean) ** 2))
    after = np.sqrt(np.mean((denoised - clean) ** 2))
    assert after < 0.2 * before, (before, after)
    assert abs(denoised.mean() / clean.mean() - 1) < 0.03
    # the checkerboard stays sharp: smoothed edges between albedos 4x apart would be off by far more
    assert np.percentile(np.abs(denoised / clean - 1), 99) < 0.2


def test_a_noise_free_image_is_kept():
    rows, columns = np.meshgrid(np.arange(HEIGHT), np.arange(WIDTH), indexing="ij")
    image = (0.4 + 0.2 * np.cos(2 * np.pi * columns / WIDTH) + 0.01 * rows)[..., None] * np.array([1.0, 0.9, 0.8])
    denoised = np.asarray(_denoise(jnp.asarray(image, jnp.float32), _flat_guides()))
    np.testing.assert_allclose(denoised, image, rtol=0.03)


def test_surfaces_do_not_mix_and_the_environment_is_kept():
    rng = np.random.default_rng(1)
    surface = np.full((HEIGHT, WIDTH), 1 + len(SurfaceKind))  # the floor
    surface[: HEIGHT // 2] = 3 + 2 * len(SurfaceKind)  # a wall above it
    surface[4:10, 20:30] = 0  # a window: the environment
    image = np.where((np.arange(HEIGHT) < HEIGHT // 2)[:, None, None], 0.2, 1.0) * np.ones((HEIGHT, WIDTH, 3))
    image[4:10, 20:30] = rng.uniform(0, 50, (6, 10, 3))  # a bright, detailed view
    image = image.astype(np.float32)
    denoised = np.asarray(_denoise(jnp.asarray(image), _flat_guides(surface=surface)))
    np.testing.assert_array_equal(denoised[4:10, 20:30], image[4:10, 20:30])
    np.testing.assert_allclose(denoised, image, rtol=1e-5)


_upsample = jax.jit(upsampled_light, static_argnames="config")


def test_upsampled_light_on_one_surface_is_bilinear_at_the_traced_pixels_directions():
    # A light equal to each traced pixel's elevation becomes each image pixel's elevation (linear in the row:
    # interpolated exactly; half-pixel centres, so the traced pixels look where the image's pixels look).
    image = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.3)
    traced = ncjax.NonCentralPanorama(WIDTH // 2, HEIGHT // 2, rc=0.3)
    rows, columns = np.mgrid[0 : traced.height, 0 : traced.width].astype(np.float32)
    _, elevation = pixel_to_angles(traced, columns, rows)
    light = jnp.broadcast_to(elevation[..., None], (traced.height, traced.width, 3))
    coarse, fine = _flat_guides(shape=(traced.height, traced.width)), _flat_guides()
    upsampled = np.asarray(_upsample(light, coarse, fine))
    rows, columns = np.mgrid[0 : image.height, 0 : image.width].astype(np.float32)
    _, expected = pixel_to_angles(image, columns, rows)
    inner = slice(1, -1)  # the first and last rows are extrapolated flat
    np.testing.assert_allclose(upsampled[inner, :, 0], np.asarray(expected)[inner], atol=1e-5)


def test_upsampled_light_does_not_cross_edges_and_textures_come_from_the_full_size_albedo():
    # Two walls meet between traced columns: each full-size pixel takes its own wall's light, and the radiance
    # its own full-size texel's albedo (a checkerboard of single pixels the traced size cannot hold).
    wall_a, wall_b = 3 + len(SurfaceKind), 3 + 2 * len(SurfaceKind)
    edge = 21  # full-size columns 0-20 and 43-63 on wall a (an odd column: inside a traced pixel)
    fine_surface = np.where((np.arange(WIDTH) < edge) | (np.arange(WIDTH) >= WIDTH - edge), wall_a, wall_b)
    fine_surface = np.broadcast_to(fine_surface, (HEIGHT, WIDTH))
    coarse_surface = np.ascontiguousarray(fine_surface[::2, ::2])  # the traced pixel's centre ray: its left half
    light = np.where(coarse_surface == wall_a, 1.0, 5.0)[..., None] * np.ones(3, np.float32)
    checker = (np.add.outer(np.arange(HEIGHT), np.arange(WIDTH)) % 2)[..., None]
    albedo = np.where(checker == 0, 0.2, 0.7) * np.ones(3)
    coarse = _flat_guides(surface=coarse_surface, shape=coarse_surface.shape)
    fine = _flat_guides(surface=fine_surface, albedo=albedo)
    upsampled = np.asarray(_upsample(jnp.asarray(light), coarse, fine))
    expected_light = np.where(fine_surface == wall_a, 1.0, 5.0)[..., None]
    np.testing.assert_allclose(upsampled, np.broadcast_to(expected_light, upsampled.shape), rtol=1e-4)
    radiance = np.asarray(remodulated(jnp.asarray(upsampled), fine))
    np.testing.assert_allclose(radiance, expected_light * albedo, rtol=1e-4)
    # demodulated is remodulated's inverse
    np.testing.assert_allclose(np.asarray(demodulated(jnp.asarray(radiance, jnp.float32), fine)), upsampled, rtol=1e-5)


def test_rejects_bad_settings():
    with pytest.raises(ValueError, match="levels"):
        DenoiseConfig(levels=-1)
    with pytest.raises(ValueError, match="luminance_sigma"):
        DenoiseConfig(luminance_sigma=-1.0)


@pytest.mark.slow
def test_a_denoised_path_trace_comes_closer_to_many_samples_a_pixel():
    """A furnished room lit by one ceiling light: 4 samples a pixel denoised against 256 samples a pixel."""
    scene = comparison_scene(
        boxes=(((1.0, 0.5, -1.0), (0.4, 0.3, 0.4), 0.3),), lights=(((0.0, 0.0, 1.19), (4.0, 4.0, 4.0)),)
    )
    cam = ncjax.NonCentralPanorama(TRACED_WIDTH, TRACED_HEIGHT, rc=0.2)
    trace = jax.jit(path_trace, static_argnames="config")
    few = np.asarray(trace(scene, cam, jax.random.key(0), PathTraceConfig(samples_per_pixel=4, bounces=3)))
    many = np.asarray(trace(scene, cam, jax.random.key(1), PathTraceConfig(samples_per_pixel=256, bounces=3)))
    guides = jax.jit(guide_buffers)(scene, cam)
    assert set(np.unique(np.asarray(guides.surface) % len(SurfaceKind))) == {
        SurfaceKind.FLOOR,
        SurfaceKind.CEILING,
        SurfaceKind.WALL,
        SurfaceKind.BOX,
    }
    denoised = np.asarray(_denoise(jnp.asarray(few), guides))
    before = np.sqrt(np.mean((few - many) ** 2))
    after = np.sqrt(np.mean((denoised - many) ** 2))
    assert after < 0.5 * before, (before, after)
    assert abs(denoised.mean() / many.mean() - 1) < 0.02
