"""The non-central panorama model against hand-computed values, numpy and finite differences."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import ncjax


def test_pixel_maps_match_design_conventions():
    cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=0.6)
    azimuth, elevation = ncjax.geometry.pixel_to_angles(cam, 0.0, 0.0)
    np.testing.assert_allclose(azimuth, math.pi - math.pi / 1024, rtol=1e-6)
    np.testing.assert_allclose(elevation, math.pi / 2 - math.pi / 1024, rtol=1e-6)
    azimuth, elevation = ncjax.geometry.pixel_to_angles(cam, 1023.0, 511.0)
    np.testing.assert_allclose(azimuth, -math.pi + math.pi / 1024, rtol=1e-6)
    np.testing.assert_allclose(elevation, -math.pi / 2 + math.pi / 1024, rtol=1e-6)


def test_forward_projection_of_hand_computed_point():
    # Point at azimuth 0, 1.5 m beyond the circle horizontally and 1.5 m up: 45 degrees.
    cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=0.5)
    u, v = ncjax.geometry.project(cam, jnp.array([2.0, 0.0, 1.5]))
    assert float(u) == pytest.approx(511.5, abs=1e-4)
    assert float(v) == pytest.approx(127.5, abs=1e-4)
    ray = ncjax.geometry.pixel_to_ray(cam, 511.5, 127.5)
    s = math.sqrt(0.5)
    np.testing.assert_allclose(ray, [s, 0.0, s, 0.0, -0.5 * s, 0.0], atol=1e-6)


def test_ray_is_a_valid_line_through_its_optical_centre():
    cam = ncjax.NonCentralPanorama(width=64, height=32, rc=0.7)
    u, v = jnp.meshgrid(jnp.arange(64.0), jnp.arange(32.0))
    rays = ncjax.geometry.pixel_to_ray(cam, u, v)
    assert rays.shape == (32, 64, 6)
    np.testing.assert_allclose(ncjax.geometry.plucker_constraint(rays), 0.0, atol=1e-6)
    np.testing.assert_allclose(jnp.linalg.norm(rays[..., :3], axis=-1), 1.0, rtol=1e-6)
    centres = ncjax.geometry.optical_centre(cam, u)
    np.testing.assert_allclose(jnp.linalg.norm(centres[..., :2], axis=-1), 0.7, rtol=1e-6)
    np.testing.assert_allclose(jnp.cross(centres, rays[..., :3]), rays[..., 3:], atol=1e-6)


def test_central_panorama_is_equirectangular():
    cam = ncjax.NonCentralPanorama(width=360, height=180, rc=0.0)
    point = np.array([1.0, -2.0, 0.5])
    u, v = ncjax.geometry.project(cam, point)
    azimuth = math.atan2(point[1], point[0])
    elevation = math.atan2(point[2], math.hypot(point[0], point[1]))
    assert float(u) == pytest.approx((math.pi - azimuth) / (2 * math.pi) * 360 - 0.5, abs=1e-3)
    assert float(v) == pytest.approx((math.pi / 2 - elevation) / math.pi * 180 - 0.5, abs=1e-3)


def test_field_of_view_parameters():
    cam = ncjax.NonCentralPanorama(width=100, height=50, rc=0.3, fov_horizontal=math.pi, fov_vertical=math.pi / 2)
    azimuth, elevation = ncjax.geometry.pixel_to_angles(cam, -0.5, -0.5)
    assert float(azimuth) == pytest.approx(math.pi / 2)
    assert float(elevation) == pytest.approx(math.pi / 4)
    u, v = ncjax.geometry.angles_to_pixel(cam, azimuth, elevation)
    assert (float(u), float(v)) == pytest.approx((-0.5, -0.5), abs=1e-5)


@pytest.mark.slow
def test_points_inside_the_circle_are_nan_with_finite_gradients():
    cam = ncjax.NonCentralPanorama(width=64, height=32, rc=0.5)
    inside = jnp.array([[0.1, 0.2, 1.0], [0.0, 0.0, -1.0]])
    u, v = ncjax.geometry.project(cam, inside)
    assert np.all(np.isnan(u)) and np.all(np.isnan(v))
    assert not np.any(ncjax.geometry.is_visible(cam, inside))
    gradient = jax.grad(lambda p: jnp.nansum(jnp.stack(ncjax.geometry.project(cam, p))))(inside)
    assert np.all(np.isfinite(gradient))
    assert bool(ncjax.geometry.is_visible(cam, jnp.array([0.6, 0.0, 0.0])))


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_bad_radius_is_rejected(bad):
    with pytest.raises(ValueError, match="rc"):
        ncjax.NonCentralPanorama(rc=bad)


@pytest.mark.parametrize("size", [(0, 512), (1024.5, 512), (1024, -2)])
def test_bad_size_is_rejected(size):
    # Without the test-time type checker a non-integer is a ValueError; with it, a TypeError.
    with pytest.raises((ValueError, TypeError)):
        ncjax.NonCentralPanorama(width=size[0], height=size[1])


@given(
    u=st.floats(0.0, 1023.0),
    v=st.floats(5.0, 506.0),
    t=st.floats(0.2, 20.0),
    rc=st.floats(0.0, 1.0),
)
def test_project_inverts_pixel_to_ray(u, v, t, rc):
    cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=rc)
    ray = ncjax.geometry.pixel_to_ray(cam, u, v)
    point = ncjax.geometry.optical_centre(cam, u) + t * ray[:3]
    pu, pv = ncjax.geometry.project(cam, point)
    assert abs(float(pu) - u) < 1e-2 and abs(float(pv) - v) < 1e-2


def test_round_trip_float64_is_exact(x64):
    cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=0.45)
    u, v = np.meshgrid(np.linspace(0, 1023, 37), np.linspace(1, 510, 23))
    rays = ncjax.geometry.pixel_to_ray(cam, u, v)
    points = ncjax.geometry.optical_centre(cam, u) + 3.0 * rays[..., :3]
    pu, pv = ncjax.geometry.project(cam, points)
    np.testing.assert_allclose(pu, u, atol=1e-8)
    np.testing.assert_allclose(pv, v, atol=1e-8)


def _central_difference(f, x, eps=1e-6):
    columns = []
    for i in range(x.shape[0]):
        step = np.zeros_like(x)
        step[i] = eps
        columns.append((np.asarray(f(x + step)) - np.asarray(f(x - step))) / (2 * eps))
    return np.stack(columns, -1)


@pytest.mark.slow
def test_projection_gradients_match_finite_differences(x64):
    def pixel(inputs):
        cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=inputs[3])
        return jnp.stack(ncjax.geometry.project(cam, inputs[:3]))

    x = np.array([1.3, -2.1, 0.7, 0.55])
    forward, reverse = jax.jacfwd(pixel)(x), jax.jacrev(pixel)(x)
    np.testing.assert_allclose(forward, reverse, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(forward, _central_difference(pixel, x), rtol=1e-6, atol=1e-8)


@pytest.mark.slow
def test_ray_gradients_match_finite_differences(x64):
    def ray(inputs):
        cam = ncjax.NonCentralPanorama(width=1024, height=512, rc=inputs[2])
        return ncjax.geometry.pixel_to_ray(cam, inputs[0], inputs[1])

    x = np.array([300.25, 120.5, 0.8])
    forward, reverse = jax.jacfwd(ray)(x), jax.jacrev(ray)(x)
    np.testing.assert_allclose(forward, reverse, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(forward, _central_difference(ray, x), rtol=1e-6, atol=1e-9)


def test_batched_cameras_under_jit_and_vmap():
    cams = jax.vmap(lambda rc: ncjax.NonCentralPanorama(width=128, height=64, rc=rc))(jnp.array([0.0, 0.3, 0.9]))
    points = jnp.tile(jnp.array([[2.0, 1.0, 0.5], [-1.0, 3.0, -1.0]]), (3, 1, 1))
    u, v = jax.jit(jax.vmap(ncjax.geometry.project))(cams, points)
    assert u.shape == v.shape == (3, 2)
    for i, rc in enumerate([0.0, 0.3, 0.9]):
        single = ncjax.NonCentralPanorama(width=128, height=64, rc=rc)
        np.testing.assert_allclose(
            np.stack([u[i], v[i]]), np.stack(ncjax.geometry.project(single, points[i])), rtol=1e-6
        )
    rays = jax.jit(jax.vmap(ncjax.geometry.pixel_to_ray, in_axes=(0, None, None)))(cams, jnp.arange(5.0), 10.0)
    assert rays.shape == (3, 5, 6)
    # rc changes the vertical position of near points: the scale cue of the model.
    assert float(jnp.abs(v[2, 0] - v[0, 0])) > 1.0
