"""The vectorising float32 arctangent (ncjax.geometry.fastmath) against numpy's float64 one."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ncjax.geometry.fastmath import arctan2

ULP_AT_PI = np.spacing(np.float32(np.pi))  # 2.4e-7 rad


def test_arctan2_is_within_two_ulp_of_float64_everywhere():
    rng = np.random.default_rng(0)
    angles = np.concatenate([np.linspace(-np.pi, np.pi, 200_001), rng.uniform(-np.pi, np.pi, 100_000)])
    radii = np.exp(rng.uniform(-20, 20, angles.shape))
    y, x = (radii * np.sin(angles)).astype(np.float32), (radii * np.cos(angles)).astype(np.float32)
    exact = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    error = np.abs(np.asarray(jax.jit(arctan2)(y, x), np.float64) - exact)
    error = np.minimum(error, 2 * np.pi - error)  # +pi and -pi are one angle
    assert error.max() <= 2 * ULP_AT_PI
    # relative accuracy for small angles, where an absolute bound would hide large relative errors
    small = np.abs(exact) < 0.1
    assert np.max(error[small] / np.maximum(np.abs(exact[small]), 1e-30)) < 4 * np.finfo(np.float32).eps


def test_arctan2_special_values_match_numpy():
    y = np.array([0.0, 0.0, 1.0, -1.0, 0.0, np.inf, 1.0, np.nan, 1e-30, -1e-30], np.float32)
    x = np.array([0.0, 1.0, 0.0, 0.0, -1.0, 1.0, np.inf, 1.0, -1.0, -1.0], np.float32)
    np.testing.assert_allclose(np.asarray(arctan2(y, x)), np.arctan2(y, x), atol=2 * ULP_AT_PI)


@pytest.mark.slow
@given(st.floats(-1e3, 1e3), st.floats(-1e3, 1e3))
def test_arctan2_gradient_is_the_exact_one(y, x):
    if x * x + y * y < 1e-6:
        return
    gradient = jax.grad(lambda p: arctan2(p[0], p[1]))(jnp.array([y, x], jnp.float32))
    squared = np.float64(x) ** 2 + np.float64(y) ** 2
    np.testing.assert_allclose(np.asarray(gradient), [x / squared, -y / squared], rtol=1e-5, atol=1e-12)


def test_arctan2_origin_has_zero_gradient_and_float64_is_numpy(x64):
    assert np.all(np.asarray(jax.grad(lambda p: arctan2(p[0], p[1]))(jnp.zeros(2, jnp.float32))) == 0)
    y, x = np.array([0.3, -2.0]), np.array([-1.0, 0.5])
    assert arctan2(y, x).dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(arctan2(y, x)), np.arctan2(y, x))
