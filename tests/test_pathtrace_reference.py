"""The path tracer (ncjax.synth.pathtrace) against Mitsuba 3 (ncjax.synth.pathtrace_reference), the reference
renderer: the same closed room with a box and a ceiling light, the same camera rays (central and non-central),
the same path lengths; the images must differ by Monte Carlo noise alone."""

import dataclasses

import jax
import numpy as np
import pytest

import ncjax
from ncjax.synth.pathtrace import PathTraceConfig, path_trace
from ncjax.synth.pathtrace_reference import (
    agreement,
    comparison_scene,
    mean_and_error,
    mitsuba_scene,
    render_reference,
)

pytest.importorskip("mitsuba")

HEIGHT, WIDTH = 16, 32
# Independent images per renderer (their spread gives each pixel's standard error) and paths per pixel in each.
BATCHES, SAMPLES = 16, 128
CONFIG = PathTraceConfig(samples_per_pixel=SAMPLES, bounces=3, floor_specular=0.0, jitter=False)


def _scene():
    return comparison_scene(
        boxes=[((1.0, 0.6, -1.0), (0.35, 0.25, 0.4), 0.5)], lights=[((-0.3, 0.2, 1.15), (2.0, 2.0, 2.0))]
    )


def _reference(scene, cam, config):
    """Mitsuba's mean image and standard errors, and where a centre ray meets the scene near a light."""
    images = [render_reference(scene, cam, config, SAMPLES, seed) for seed in range(BATCHES)]
    mean, error = mean_and_error(np.stack([image for image, _ in images]))
    return mean, error, images[0][1]


@pytest.mark.slow
@pytest.mark.parametrize("rc", [0.0, 0.3])
def test_path_tracer_agrees_with_mitsuba_within_noise(rc):
    """Each pixel's difference over its combined standard error is about a standard normal (a t of 15 degrees
    of freedom per renderer): nearly all within 3, root mean square about 1, no sign preferred; the images'
    means agree within 2 %. A reference one bounce short is told apart, so the test can see a bias."""
    scene, cam = _scene(), ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=rc)
    trace = jax.jit(path_trace, static_argnames="config")
    ours = np.stack([np.asarray(trace(scene, cam, jax.random.key(k), CONFIG)) for k in range(BATCHES)])
    mean, error = mean_and_error(ours)
    reference, reference_error, near_light = _reference(scene, cam, CONFIG)
    # Where a centre ray meets the light's disc or the ceiling it shades (Mitsuba's geometry holds the disc,
    # ncjax's does not): left out.
    assert near_light.mean() < 0.02
    figures = agreement(mean, error, reference, reference_error, ~near_light)
    assert figures["within_3_sigma"] > 0.95, figures
    assert 0.8 < figures["z_rms"] < 1.3, figures
    assert abs(figures["mean_ratio"] - 1) < 0.02, figures
    z = ((mean - reference) / np.sqrt(error**2 + reference_error**2))[~near_light]
    # The mean over the pixels of about standard normal values (a pixel's channels go together): within 4 of its
    # standard errors of 0.
    assert abs(z.mean()) < 4 / np.sqrt(len(z)), z.mean()

    short, short_error, _ = _reference(scene, cam, dataclasses.replace(CONFIG, bounces=CONFIG.bounces - 1))
    assert agreement(mean, error, short, short_error, ~near_light)["within_3_sigma"] < 0.5


def test_mitsuba_scene_rejects_what_it_does_not_model():
    """Textures and the glossy floor would make the comparison meaningless: they are refused, not ignored."""
    with pytest.raises(ValueError, match="floor_specular"):
        mitsuba_scene(_scene(), dataclasses.replace(CONFIG, floor_specular=0.1))
    with pytest.raises(ValueError, match="jitter"):
        mitsuba_scene(_scene(), dataclasses.replace(CONFIG, jitter=True))
    textured = _scene()
    textured = dataclasses.replace(
        textured, walls=dataclasses.replace(textured.walls, colour_b=textured.walls.colour_a / 2)
    )
    with pytest.raises(ValueError, match="flat materials"):
        mitsuba_scene(textured, CONFIG)
