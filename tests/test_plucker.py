"""Plücker toolkit against numpy geometry and hypothesis properties."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import ncjax

finite = st.floats(-5.0, 5.0)
points = hnp.arrays(np.float64, (3,), elements=finite)


def _well_separated(p, q):
    return np.linalg.norm(p - q) > 0.1


@given(p=points, q=points, s=st.floats(-3, 3), t=st.floats(-3, 3), o=points)
def test_rays_through_points_of_a_line_meet_it(p, q, s, t, o):
    if not (_well_separated(p, q) and _well_separated(o, p + s * (q - p))):
        return
    line = ncjax.geometry.line_through_points(p, q)
    ray = ncjax.geometry.line_through_points(o, p + s * (q - p))
    assert (
        abs(float(ncjax.geometry.side(line, ray)))
        < 1e-4 * (1 + np.abs(o).max() + np.abs(p).max() + np.abs(q).max()) ** 2
    )
    assert abs(float(ncjax.geometry.plucker_constraint(line))) < 1e-4 * (1 + np.abs(p).max()) ** 2


def _numpy_closest(pa, da, pb, db):
    matrix = np.stack([da, -db], 1)
    (ta, tb), *_ = np.linalg.lstsq(matrix, pb - pa, rcond=None)
    return pa + ta * da, pb + tb * db


def test_closest_points_and_distance_match_numpy(x64):
    rng = np.random.default_rng(0)
    for _ in range(50):
        pa, pb, da, db = rng.normal(size=(4, 3))
        a = ncjax.geometry.line_from_point_direction(pa, da)
        b = ncjax.geometry.line_from_point_direction(pb, db)
        on_a, on_b, distance = ncjax.geometry.closest_points(a, b)
        ref_a, ref_b = _numpy_closest(pa, da, pb, db)
        np.testing.assert_allclose(on_a, ref_a, atol=1e-9)
        np.testing.assert_allclose(on_b, ref_b, atol=1e-9)
        # The side operator gives the same distance: |side| / |a x b| for unit directions.
        expected = abs(float(ncjax.geometry.side(a, b))) / np.linalg.norm(np.cross(a[:3], b[:3]))
        assert float(distance) == np.float64(expected).round(12) or abs(float(distance) - expected) < 1e-9


@pytest.mark.slow
def test_closest_points_of_parallel_lines_are_finite():
    a = ncjax.geometry.line_from_point_direction(jnp.array([0.0, 0.0, 1.0]), jnp.array([1.0, 0.0, 0.0]))
    b = ncjax.geometry.line_from_point_direction(jnp.array([0.0, 2.0, 1.0]), jnp.array([-2.0, 0.0, 0.0]))
    on_a, on_b, distance = ncjax.geometry.closest_points(a, b)
    assert float(distance) == np.float32(2.0)
    np.testing.assert_allclose(on_a, [0.0, 0.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(on_b, [0.0, 2.0, 1.0], atol=1e-6)
    gradient = jax.grad(lambda x: ncjax.geometry.closest_points(x, b)[2])(a)
    assert np.all(np.isfinite(gradient))


def test_intersection_of_coplanar_lines():
    meet = np.array([1.0, -2.0, 0.5])
    a = ncjax.geometry.line_from_point_direction(meet + np.array([0.3, 0.1, 0.0]), np.array([3.0, 1.0, 0.0]))
    b = ncjax.geometry.line_from_point_direction(meet, np.array([-1.0, 2.0, 0.0]))
    np.testing.assert_allclose(ncjax.geometry.intersect_coplanar_lines(a, b), meet, atol=1e-5)


def test_closest_point_to_origin_and_point_at():
    line = ncjax.geometry.line_through_points(jnp.array([1.0, 1.0, 2.0]), jnp.array([1.0, -1.0, 2.0]))
    np.testing.assert_allclose(ncjax.geometry.closest_point_to_origin(line), [1.0, 0.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(ncjax.geometry.point_at(line, 2.0), [1.0, -2.0, 2.0], atol=1e-6)
    scaled = 3.0 * line
    np.testing.assert_allclose(ncjax.geometry.closest_point_to_origin(scaled), [1.0, 0.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(ncjax.geometry.normalize_line(scaled), line, atol=1e-6)


@given(angle=st.floats(-math.pi, math.pi), p=points, q=points)
def test_rotation_and_translation_move_the_line_with_its_points(angle, p, q):
    if not _well_separated(p, q):
        return
    rotation = np.asarray(ncjax.geometry.rotation_z(angle), dtype=np.float64)
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-6)
    rotated = ncjax.geometry.rotate_line_z(ncjax.geometry.line_through_points(p, q), angle)
    np.testing.assert_allclose(rotated, ncjax.geometry.line_through_points(rotation @ p, rotation @ q), atol=1e-4)
    offset = np.array([0.5, -1.0, 2.0])
    moved = ncjax.geometry.translate_line(ncjax.geometry.line_through_points(p, q), offset)
    np.testing.assert_allclose(moved, ncjax.geometry.line_through_points(p + offset, q + offset), atol=1e-4)


def test_horizontal_wall_line_contains_its_wall_points():
    direction = np.array([math.cos(0.3), math.sin(0.3)])
    distance, height = -2.5, 1.2
    line = ncjax.geometry.horizontal_wall_line(direction, distance, height)
    e1 = np.array([direction[0], direction[1], 0.0])
    e2 = np.array([-direction[1], direction[0], 0.0])
    p = distance * e2 + height * np.array([0.0, 0.0, 1.0])
    np.testing.assert_allclose(line, ncjax.geometry.line_from_point_direction(p + 0.7 * e1, e1), atol=1e-6)


@pytest.mark.slow
def test_batch_shapes():
    a = jnp.ones((4, 3, 6))
    assert ncjax.geometry.side(a, a).shape == (4, 3)
    assert ncjax.geometry.closest_points(a, a[0])[2].shape == (4, 3)
    assert ncjax.geometry.rotate_line_z(a, jnp.zeros((4, 3))).shape == (4, 3, 6)
    assert jax.jit(jax.vmap(ncjax.geometry.intersect_coplanar_lines))(a, a).shape == (4, 3, 3)
