"""Photoreal training images (ncjax.synth.photoreal): what windows show and the sun they let in, the wall-floor
edge on its label row, and rooms rendered so keeping the ray caster's labels, depth and semantics."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_pathtrace import FLOOR, _scene

from ncjax.geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles
from ncjax.io.tone_mapping import luminance
from ncjax.synth import PhotorealConfig, RoomConfig, SceneConfig, SynthConfig
from ncjax.synth.pathtrace import PathTraceConfig
from ncjax.synth.photoreal import photoreal_image, window_light, window_views
from ncjax.synth.render import synthesize_batch


def _views(seed: int = 0) -> np.ndarray:
    """Two small outdoor panoramas: a lognormal sky each, the second with a sun a thousand times brighter."""
    rng = np.random.default_rng(seed)
    views = np.exp(rng.normal(0.0, 0.5, (2, 8, 16, 3))).astype(np.float32)
    views[1, 2, 5] = 1000.0
    return views


@pytest.mark.parametrize("seed", range(6))
def test_a_window_shows_a_view_at_a_median_in_range_clipped_at_the_sun_clip(seed):
    config = PhotorealConfig(window_brightness=(1.5, 2.5), sun_clip=3.0)
    views = _views(seed)
    view = np.asarray(window_light(jax.random.key(seed), jnp.asarray(views), config)[0])
    level = np.asarray(luminance(jnp.asarray(view)))
    median = np.median(level)
    assert 1.5 - 1e-4 <= median <= 2.5 + 1e-4
    assert level.max() <= 3.0 * median * (1 + 1e-5)
    # one of the views, turned about the vertical axis and scaled: each row keeps its texels' ratios
    candidates = [np.roll(v, shift, axis=1) for v in views for shift in range(views.shape[2])]
    unclipped = level < 3.0 * median * (1 - 1e-4)
    assert any(np.allclose((view / c)[unclipped], (view / c)[unclipped].mean(), rtol=1e-4) for c in candidates), (
        "not a turned, scaled view"
    )


@pytest.mark.parametrize("seed", range(4))
def test_the_light_clipped_around_the_sun_becomes_the_sun(seed):
    # A clip high enough that only the sun's texel (1000 times the sky) is clipped: the sun's irradiance is
    # that texel's clipped-away radiance times its solid angle, and its direction the texel's.
    config = PhotorealConfig(sun_clip=50.0)
    views = _views(seed)[1:]
    view, sun = window_light(jax.random.key(seed), jnp.asarray(views), config)
    view = np.asarray(view)
    shift = (int(np.argmax(view[2].sum(-1))) - 5) % 16  # the view's brightest texel is the sun, clipped
    turned = np.roll(views[0], shift, axis=1)
    gain = float(np.median(view / turned))
    row, column = 2, (5 + shift) % 16
    azimuth, elevation = pixel_to_angles(NonCentralPanorama(16, 8), float(column), float(row))
    azimuth, elevation = float(azimuth), float(elevation)
    solid_angle = (2 * math.pi / 16) * (math.pi / 8) * math.cos(elevation)
    expected = (turned[row, column] * gain - view[row, column]) * solid_angle
    np.testing.assert_allclose(np.asarray(sun.irradiance), expected, rtol=1e-3)
    direction = [math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation)]
    np.testing.assert_allclose(np.asarray(sun.direction), direction, atol=1e-5)
    without = window_light(jax.random.key(seed), jnp.asarray(views), PhotorealConfig(sun_clip=50.0, sun=False))
    np.testing.assert_array_equal(np.asarray(without[0]), view)
    np.testing.assert_array_equal(np.asarray(without[1].irradiance), 0.0)


def test_the_shipped_window_views_are_outdoor_hdr_panoramas():
    views = window_views()
    assert views.ndim == 4 and views.shape[0] >= 8 and views.shape[2] == 2 * views.shape[1] and views.shape[3] == 3
    assert np.all(np.isfinite(views)) and views.min() >= 0
    flat = views.reshape(len(views), -1)
    assert np.all(flat.max(1) > 10 * np.median(flat, 1)) and np.all(flat.max(1) > 1), "high dynamic range"


def test_configuration_rejects_bad_values():
    with pytest.raises(ValueError, match="trace_scale"):
        PhotorealConfig(trace_scale=0)
    with pytest.raises(ValueError, match="window_brightness"):
        PhotorealConfig(window_brightness=(0.0, 1.0))
    with pytest.raises(ValueError, match="sun_clip"):
        PhotorealConfig(sun_clip=0.5)
    with pytest.raises(ValueError, match="trace_scale 4 must divide"):
        SynthConfig(width=36, height=18, photoreal=PhotorealConfig(trace_scale=4))


@pytest.mark.slow
@pytest.mark.parametrize("rc", [0.0, 0.3])
def test_the_wall_floor_edge_lands_on_its_label_row(rc):
    # A box room of white walls and a dark floor, lit by one ceiling light, photographed at 64 x 128 (traced at
    # 32 x 64): in every column the image darkens most from the last row above the floor line's exact row to the
    # first below it. The exact row is where the column's ray, leaving its own optical centre (rc > 0: not the
    # panorama's centre), meets the floor at the wall.
    scene = _scene(albedo=(0.8, 0.8, 0.8), floor_albedo=(0.05, 0.05, 0.05), lights=[((0.3, 0.2, 1.0), (3.0, 3.0, 3.0))])
    cam = NonCentralPanorama(128, 64, rc=rc)
    config = PhotorealConfig(trace=PathTraceConfig(samples_per_pixel=4, bounces=2, pixels_per_chunk=512))
    photograph = jax.jit(photoreal_image, static_argnames="config")
    image = photograph(jax.random.key(0), scene, cam, jnp.asarray(_views()), config)
    level = np.asarray(luminance(image))[cam.height // 2 :]
    drop = level[:-1] - level[1:]  # from each row of the lower half to the next
    assert np.all(drop.max(0) > 0.1), "no wall-floor edge"
    edge = cam.height // 2 + np.argmax(drop, 0) + 0.5  # the boundary between the last wall row and the first floor row
    azimuth, _ = pixel_to_angles(cam, np.arange(cam.width, dtype=np.float32), 0.0)
    azimuth = np.asarray(azimuth, np.float64)
    heading = np.stack([np.cos(azimuth), np.sin(azimuth)], -1)
    centre = rc * heading
    with np.errstate(divide="ignore"):
        exits = (np.where(heading > 0, [2.0, 1.5], [-2.0, -1.5]) - centre) / heading
    reach = np.min(np.where(np.isfinite(exits) & (exits > 0), exits, np.inf), -1)
    _, label = angles_to_pixel(
        cam, jnp.asarray(azimuth, jnp.float32), jnp.asarray(np.arctan2(FLOOR, reach), jnp.float32)
    )
    np.testing.assert_array_less(np.abs(edge - np.asarray(label)), 0.5 + 1e-3)


@pytest.mark.slow
def test_photoreal_rooms_keep_the_ray_casters_scenes_labels_depth_and_semantics():
    tiny = PhotorealConfig(trace=PathTraceConfig(samples_per_pixel=2, bounces=1, pixels_per_chunk=256))
    base = SynthConfig(
        room=RoomConfig(world="mix", rc_range=(0.0, 0.6)), scene=SceneConfig(decor=True), width=32, height=16
    )
    keys = jax.vmap(jax.random.key)(jnp.arange(2))
    cast = jax.device_get(synthesize_batch(keys, base))
    photoreal = jax.device_get(synthesize_batch(keys, SynthConfig(**{**vars(base), "photoreal": tiny})))
    (cast_scenes, cast_renderings, cast_labels), (scenes, renderings, labels) = cast, photoreal
    for a, b in zip(jax.tree.leaves((cast_scenes, cast_labels)), jax.tree.leaves((scenes, labels)), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(cast_renderings.depth, renderings.depth)
    np.testing.assert_array_equal(cast_renderings.semantic, renderings.semantic)
    rgb = np.asarray(renderings.rgb)
    assert rgb.shape == (2, 16, 32, 3) and rgb.min() >= 0 and rgb.max() <= 1
    np.testing.assert_allclose(rgb * 255, np.round(rgb * 255), atol=1e-3)  # an 8-bit file
    assert not np.allclose(rgb, cast_renderings.rgb, atol=0.05), "the ray caster's image"
    again = jax.device_get(synthesize_batch(keys, SynthConfig(**{**vars(base), "photoreal": tiny})))[1]
    np.testing.assert_array_equal(rgb, again.rgb)
