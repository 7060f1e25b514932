"""Boundary rows snapped to image edges: painted panoramas with known sub-pixel boundaries."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ncjax
import ncjax.network.edges
import ncjax.training.data

HEIGHT, WIDTH = 128, 256
# At 128 rows the default radius (3 rows at 512) would round to 1: reach 3 rows here.
SNAP = ncjax.EdgeSnap(radius=12.0, sigma=4.0)


def painted(phase, amplitude):
    """A flat-shaded panorama with smooth sub-pixel ceiling and floor boundaries, and those rows."""
    columns = jnp.arange(WIDTH)
    ceiling = 40.0 + amplitude * jnp.sin(2 * jnp.pi * columns / WIDTH + phase)
    floor = 90.0 - 0.7 * amplitude * jnp.cos(4 * jnp.pi * columns / WIDTH + phase)
    colours = jnp.array([[0.9, 0.9, 0.85], [0.6, 0.5, 0.4], [0.3, 0.25, 0.2]])
    image = ncjax.training.data.paint_panorama(ceiling, floor, columns // 40, HEIGHT, colours)
    return image, ceiling, floor


@functools.cache
def snapper():
    return jax.jit(lambda image, c, f: ncjax.network.edges.snap_to_edges(image, c, f, SNAP))


@settings(max_examples=10, deadline=None)
@given(
    phase=st.floats(0, 2 * np.pi),
    amplitude=st.floats(0, 8),
    seed=st.integers(0, 2**31 - 1),
)
def test_rows_within_reach_land_on_the_painted_boundary(phase, amplitude, seed):
    image, ceiling, floor = painted(phase, amplitude)
    rng = np.random.default_rng(seed)
    guess_c = ceiling + rng.uniform(-2.4, 2.4, WIDTH)
    guess_f = floor + rng.uniform(-2.4, 2.4, WIDTH)
    snapped_c, snapped_f = snapper()(image, guess_c, guess_f)
    error = np.abs(np.concatenate([snapped_c - ceiling, snapped_f - floor]))
    # Within the blur's reach of a wall corner (a change of wall shade every 40 columns) the two
    # walls' contrasts mix and bias the edge a little.
    near_corner = np.tile(np.abs((np.arange(WIDTH) + 20) % 40 - 20) < 3, 2)
    assert np.max(error[~near_corner]) < 0.06
    assert np.max(error[near_corner]) < 0.25
    assert np.mean(error) < 0.03


def test_snapping_follows_the_panorama_around():
    """Rolling the panorama's columns rolls the snapped rows (the blur wraps around)."""
    image, ceiling, floor = painted(0.3, 5.0)
    image = image + 0.05 * jax.random.uniform(jax.random.PRNGKey(0), image.shape)  # texture
    guess_c, guess_f = ceiling + 1.3, floor - 0.8
    c, f = snapper()(image, guess_c, guess_f)
    rolled_c, rolled_f = snapper()(jnp.roll(image, 37, axis=1), jnp.roll(guess_c, 37), jnp.roll(guess_f, 37))
    np.testing.assert_allclose(rolled_c, np.roll(c, 37), atol=1e-4)
    np.testing.assert_allclose(rolled_f, np.roll(f, 37), atol=1e-4)


def test_rows_stay_where_there_is_no_edge():
    flat = jnp.full((HEIGHT, WIDTH, 3), 0.5)
    rows = jnp.linspace(20.0, 100.0, WIDTH).at[5].set(jnp.nan)
    c, f = snapper()(flat, rows, rows + 3.0)
    np.testing.assert_array_equal(np.asarray(c), np.asarray(rows))
    np.testing.assert_array_equal(np.asarray(f), np.asarray(rows + 3.0))
    # Far from any edge (out of reach), a row moves at most radius + 1 rows.
    image, ceiling, _ = painted(1.0, 3.0)
    c, _ = snapper()(image, ceiling + 20.0, ceiling + 20.0)
    assert np.max(np.abs(np.asarray(c) - (ceiling + 20.0))) <= 4.0


@pytest.mark.slow
def test_uint8_images_and_the_blur():
    image, ceiling, floor = painted(2.0, 4.0)
    as_bytes = jnp.round(image * 255).astype(jnp.uint8)
    c8, f8 = snapper()(as_bytes, ceiling + 1.0, floor - 1.0)
    assert np.median(np.abs(c8 - ceiling)) < 0.05 and np.median(np.abs(f8 - floor)) < 0.05
    # The blur keeps a constant image, and each row's mean (normalised weights, columns wrapping around).
    stripes = jnp.broadcast_to(jax.random.uniform(jax.random.PRNGKey(1), (1, WIDTH, 3)), (HEIGHT, WIDTH, 3))
    np.testing.assert_allclose(ncjax.network.edges.blur(jnp.ones((8, 16, 3)), 1.5), 1.0, rtol=1e-6)
    np.testing.assert_allclose(
        jnp.mean(ncjax.network.edges.blur(stripes, 1.0), axis=1), jnp.mean(stripes, axis=1), atol=1e-5
    )


def test_edge_snap_validation():
    for kwargs in ({"radius": 0.5}, {"sigma": -1.0}, {"min_strength": -0.1}):
        with pytest.raises(ValueError):
            ncjax.EdgeSnap(**kwargs)
