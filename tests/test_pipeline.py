"""The geometric pipeline (paper Section 4.4): corners, RANSAC, branches, adjustment, failure codes."""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.geometry.plucker import wall_planes_meet
from ncjax.geometry.reprojection import (
    boundary_points,
    column_directions,
    fit_plan_line,
    fit_plan_lines,
    range_along,
    wall_boundary_rows,
)
from ncjax.pipeline.adjust import (
    BoundaryObservations,
    _boundary_residuals_fast_jvp,
    adjust_layout,
    boundary_residuals,
    boundary_weights,
    jacobian_structure,
    layout_problem,
    layout_residuals,
    loop_corners,
    observation_directions,
    problem_residuals,
)
from ncjax.pipeline.assemble import finish_layout
from ncjax.pipeline.atlanta import atlanta_walls, corner_offsets
from ncjax.pipeline.batch import _batched_layout_jit, _Inputs, _layout_jit
from ncjax.pipeline.config import CornerConfig, UncertaintyConfig
from ncjax.pipeline.corners import (
    SideWindow,
    column_walls,
    find_corners,
    full_window_spread,
    is_peak,
    side_extrapolation,
    straight_wall_value,
)
from ncjax.pipeline.evidence import gather_evidence
from ncjax.pipeline.floor_check import ceiling_consistent_floor
from ncjax.pipeline.manhattan import _segment_directions, cyclic_binary_labels, manhattan_frame, manhattan_walls
from ncjax.pipeline.run import choose_manhattan
from ncjax.pipeline.sparse_normal import normal_matrix, probe_jacobian
from ncjax.pipeline.types import Rows, Walls
from ncjax.pipeline.uncertainty import correlation_time, layout_uncertainty, room_height_sigma
from ncjax.solvers.ransac import boundary_angles, boundary_errors, num_hypotheses, wall_columns
from ncjax.solvers.wall import make_wall
from ncjax.synth.labels import corner_target

WIDTH, HEIGHT = 512, 256


def _corners(threshold, **settings):
    """The corner settings of ``find_corners``' own defaults (no fallback, no exact-target split) but ``settings``."""
    return CornerConfig(
        **{
            "threshold": threshold,
            "min_corners": 0,
            "fallback_threshold": 0.0,
            "exact_target_tolerance": 0.0,
            **settings,
        }
    )


@functools.cache
def rooms(world: str, occlusion: str, count: int = 6):
    config = ncjax.RoomConfig(world=world, occlusion=occlusion, room_tries=2, camera_tries=64)
    batch = jax.jit(jax.vmap(lambda k: ncjax.synth.random_room(k, config)))(jax.random.split(jax.random.key(11), count))
    labels = jax.jit(jax.vmap(lambda r: ncjax.synth.room_labels(r, r.camera(WIDTH, HEIGHT))))(batch)
    return batch, labels


def pick(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def target(width: int, corners) -> np.ndarray:
    columns = np.arange(width)
    gap = np.abs(columns[:, None] - np.asarray(corners)[None, :]) % width
    return 0.96 ** np.min(np.minimum(gap, width - gap), axis=1)


# --- corner extraction -------------------------------------------------------------------------


@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.5, 20.0))
def test_boundary_angles_are_the_row_errors(seed, threshold):
    """RANSAC's errors as angles in the column's half-plane (one arctangent of products) are the row errors in
    pixels over the rows' angular size, also for rows past a pole."""
    cam = ncjax.NonCentralPanorama(rc=0.3, width=WIDTH, height=HEIGHT)
    rng = np.random.default_rng(seed)
    yaw = rng.uniform(-np.pi, np.pi)
    direction = jnp.array([np.cos(yaw), np.sin(yaw)], jnp.float32)
    heights = jnp.float32(rng.uniform(0.2, 3.0)), jnp.float32(-rng.uniform(0.2, 2.0))
    wall = make_wall(direction, jnp.float32(rng.choice([-1, 1]) * rng.uniform(0.5, 4.0)), *heights, jnp.array(True))
    columns = jnp.arange(WIDTH, dtype=jnp.float32)
    ceiling, floor, _ = wall_boundary_rows(
        cam, wall.direction, wall.distance, wall.ceiling_height, wall.floor_height, columns
    )
    # rows near the wall's own and anywhere in the image; the top and bottom rows lie past a pole
    ceiling_v = jnp.where(
        rng.random(WIDTH) < 0.7, ceiling + rng.normal(0, 2 * threshold, WIDTH), rng.uniform(-1, HEIGHT, WIDTH)
    )
    floor_v = jnp.where(
        rng.random(WIDTH) < 0.7, floor + rng.normal(0, 2 * threshold, WIDTH), rng.uniform(-1, HEIGHT, WIDTH)
    )
    azimuth = column_directions(cam, columns)
    ceiling_error, floor_error = boundary_errors(cam, wall, azimuth, ceiling_v, floor_v)
    rays = (ncjax.geometry.pixel_to_ray(cam, columns, v) for v in (ceiling_v, floor_v))
    ceiling_angle, floor_angle = boundary_angles(cam, wall, azimuth, *rays)
    pixels_per_radian = cam.height / cam.fov_vertical
    for errors, angles in ((ceiling_error, ceiling_angle), (floor_error, floor_angle)):
        errors, angles = np.asarray(errors), np.asarray(angles) * pixels_per_radian
        seen = np.isfinite(errors)
        assert np.array_equal(seen, np.isfinite(angles)) and seen.mean() > 0.3
        assert np.allclose(angles[seen], errors[seen], atol=1e-2, rtol=1e-4)


@pytest.mark.slow
@given(st.lists(st.floats(0.0, 511.0), min_size=1, max_size=6, unique=True))
def test_find_corners_recovers_sub_column_positions(corners):
    corners = sorted(corners)
    if len(corners) > 1 and min(np.diff(corners + [corners[0] + WIDTH])) < 4:
        return  # closer than the suppression window
    columns, mask, _, overflow = find_corners(jnp.asarray(target(WIDTH, corners), jnp.float32), 8, 2, _corners(0.3))
    found = np.sort(np.asarray(columns)[np.asarray(mask)] % WIDTH)
    assert not overflow and len(found) == len(corners)
    gap = np.abs(found - np.sort(np.asarray(corners) % WIDTH))
    np.testing.assert_array_less(np.minimum(gap, WIDTH - gap), 2e-3)


@pytest.mark.slow
@given(st.floats(0.0, 1023.0), st.floats(0.05, 2.0), st.sampled_from([1.0, 0.9, 0.7]), st.sampled_from([1.0, 1.3, 0.8]))
def test_a_peak_of_the_exact_target_that_holds_two_corners_gives_both(first, apart, scale, power):
    # Two corners closer than the suppression window give one peak; the exact 0.96**d target still tells each
    # column's distance to the nearer, so both come back. A lobe that only looks like it (scaled or sharpened, as a
    # network's) is one corner.
    corners = np.array([first, first + apart, first + 300.0]) % WIDTH
    exact = scale == 1.0 and power == 1.0
    prob = jnp.asarray(scale * target(WIDTH, corners) ** power, jnp.float32)
    columns, mask, is_exact, overflow = find_corners(prob, 8, 2, _corners(0.3, exact_target_tolerance=0.01))
    found = np.sort(np.asarray(columns)[np.asarray(mask)] % WIDTH)
    assert not overflow
    assert bool(np.all(np.asarray(is_exact)[np.asarray(mask)])) == exact
    if not exact:
        assert len(found) == 2
        return
    assert len(found) == 3
    gap = np.abs(found[:, None] - corners[None, :]) % WIDTH
    np.testing.assert_array_less(np.min(np.minimum(gap, WIDTH - gap), axis=0), 2e-3)


def test_exact_target_splitting_is_off_at_zero_tolerance():
    prob = jnp.asarray(target(WIDTH, [100.0, 101.5]), jnp.float32)
    columns, mask, exact, _ = find_corners(prob, 8, 2, _corners(0.3))
    assert int(mask.sum()) == 1 and not bool(exact.any())


def test_plateau_gives_one_peak_and_wrap_around():
    prob = jnp.zeros(16).at[jnp.array([15, 0])].set(0.9)  # a plateau across the seam
    peak = is_peak(prob, 2, 0.5)
    assert int(peak.sum()) == 1 and bool(peak[15])
    walls = column_walls(jnp.array([3.0, 9.0, 16.0]), jnp.array([True, True, False]), 16)
    np.testing.assert_array_equal(walls, [1, 1, 1, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 1])


@pytest.mark.slow
@given(st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6), st.integers(0, 6))
def test_weak_peaks_make_up_the_minimum_corner_count(heights, min_corners):
    # Six lobes at known columns with peak heights in [0, 1]: the threshold 0.4 keeps the strong ones; when fewer
    # than `min_corners` are strong, the strongest of those above the fallback 0.1 are added, and none below it.
    corners = np.arange(6) * 80.0 + 20.0
    lobes = np.asarray(target(WIDTH, corners))
    offset = np.abs(np.arange(WIDTH)[:, None] + 0.5 - corners[None])
    nearest = np.argmin(np.minimum(offset, WIDTH - offset), axis=1)  # the lobe each column belongs to
    prob = jnp.asarray(lobes * np.asarray(heights)[nearest], jnp.float32)
    columns, mask, _, _ = find_corners(prob, 8, 2, _corners(0.4, min_corners=min_corners, fallback_threshold=0.1))
    peaks = np.array([np.asarray(prob)[nearest == k].max() for k in range(6)])
    usable = np.sort(peaks[peaks >= 0.1])[::-1]
    strong = int(np.sum(peaks >= 0.4))
    threshold = min(0.4, usable[min(min_corners, len(usable)) - 1]) if min_corners and len(usable) else 0.4
    assert int(mask.sum()) == int(np.sum(peaks >= max(threshold, 0.1)))  # ties at the threshold are all kept
    assert int(mask.sum()) >= min(min_corners, len(usable))
    kept = np.isin(np.arange(6), nearest[np.round(np.asarray(columns)[np.asarray(mask)]).astype(int) % WIDTH])
    if kept.any() and not kept.all():
        assert peaks[kept].min() >= peaks[~kept].max()  # the strongest peaks are the ones kept
    _, plain, _, _ = find_corners(prob, 8, 2, _corners(0.4))
    assert int(plain.sum()) == strong


def test_capacity_overflow_is_reported():
    _, mask, _, overflow = find_corners(
        jnp.asarray(target(WIDTH, np.arange(10) * 50.0), jnp.float32), 4, 2, _corners(0.3)
    )
    assert bool(overflow) and int(mask.sum()) == 4


def test_paper_number_of_hypotheses():
    assert num_hypotheses(0.9999, 0.2, 3) == 13  # paper: 12.84
    assert num_hypotheses(0.9999, 0.6, 6) == 2245  # paper: 2244 (it truncates 2244.1)
    with pytest.raises(ValueError):
        num_hypotheses(1.0, 0.2, 3)


@pytest.mark.slow
def test_wall_columns_spread_over_each_wall():
    width, size = 64, 8
    corners = jnp.array([5.3, 20.0, 58.7, 64.0])  # the last wall wraps around the seam
    mask = jnp.array([True, True, True, False])
    column_wall = column_walls(corners, mask, width)
    candidate = jnp.ones(width, bool).at[jnp.array([6, 7, 30])].set(False)
    columns, valid = (np.asarray(x) for x in wall_columns(column_wall, candidate, corners, size))
    for wall in range(3):
        own = [c for c in range(width) if column_wall[c] == wall and candidate[c]]
        chosen = columns[wall][valid[wall]]
        assert set(chosen) <= set(own) and len(set(chosen)) == len(chosen) == min(size, len(own))
        along = (chosen - np.floor(float(corners[wall]))) % width
        assert np.all(np.diff(along) > 0)  # in image order from the wall's start corner
        rank = np.searchsorted(np.sort((np.array(own) - np.floor(float(corners[wall]))) % width), along)
        assert rank[0] < len(own) / size and rank[-1] >= len(own) * (1 - 1 / size) - 1  # spread over the wall
    assert not valid[3].any()


@pytest.mark.slow
def test_boundary_residuals_fast_jvp_matches_autodiff():
    """The local-Jacobian JVP of the adjustment's per-column residuals equals JAX's own, for every argument."""
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.4)
    direction = jnp.array([jnp.cos(0.3), jnp.sin(0.3)])
    args = (
        direction,
        jnp.array(-2.1),
        jnp.array(1.2),
        jnp.array(-1.4),
        cam,
        (column_directions(cam, 17.3), jnp.array(40.0), jnp.array(90.0)),
    )
    fast = _boundary_residuals_fast_jvp
    key = jax.random.key(5)
    for trial in range(3):
        tangents = jax.tree.map(lambda x: jax.random.normal(jax.random.fold_in(key, trial), jnp.shape(x)), args)
        value, tangent = jax.jvp(fast, args, tangents)
        expected_value, expected_tangent = jax.jvp(boundary_residuals, args, tangents)
        np.testing.assert_allclose(value, expected_value, rtol=1e-6)
        np.testing.assert_allclose(tangent, expected_tangent, rtol=1e-4, atol=1e-4)
    # reverse mode and a vmapped Jacobian (what the least-squares solver materialises)
    argnums = (0, 1, 2, 3, 5)
    jacobian = jax.vmap(jax.jacrev(fast, argnums=argnums), in_axes=(0, 0, None, None, None, 0))
    angles = jnp.linspace(0.1, 0.5, 4)
    batched = (
        jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1),
        jnp.full(4, -2.0),
        args[2],
        args[3],
        cam,
        (column_directions(cam, jnp.arange(4.0) + 10), jnp.full(4, 40.0), jnp.full(4, 90.0)),
    )
    expected = jax.vmap(jax.jacrev(boundary_residuals, argnums=argnums), in_axes=(0, 0, None, None, None, 0))
    for got, want in zip(jax.tree.leaves(jacobian(*batched)), jax.tree.leaves(expected(*batched)), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("manhattan, stride, floor_weight", [(True, 1, 1.0), (False, 3, 0.25)])
def test_adjustment_recovers_the_room_from_a_perturbed_start(manhattan, stride, floor_weight):
    batch, labels = rooms("manhattan" if manhattan else "atlanta", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    every = slice(None, None, stride)  # PipelineConfig.adjustment_stride
    used = jnp.ones(WIDTH, bool)[every]
    observations = BoundaryObservations(
        columns=jnp.arange(WIDTH)[every],
        ceiling_v=label.ceiling_v[every],
        floor_v=label.floor_v[every],
        ceiling_used=used,
        floor_used=used,
        column_wall=label.wall_index[every],
        corner_columns=jnp.zeros(len(room.mask)),
        corner_used=jnp.zeros(len(room.mask), bool),
        wall_mask=room.mask,
        row_weights=jnp.array([1.0, floor_weight]),
    )
    turn = 0.02 if manhattan else 0.02 * jnp.cos(jnp.arange(len(room.mask)))
    start = jnp.stack(
        [
            jnp.cos(turn) * directions[:, 0] - jnp.sin(turn) * directions[:, 1],
            jnp.sin(turn) * directions[:, 0] + jnp.cos(turn) * directions[:, 1],
        ],
        -1,
    )
    labels_, _ = manhattan_frame(directions, room.mask.astype(directions.dtype))
    adjust = jax.jit(functools.partial(adjust_layout, labels=labels_ if manhattan else None))
    walls = Walls(start, 1.05 * distances, 0.95 * room.ceiling_height, 0.95 * room.floor_height)
    adjusted, improved = adjust(cam, observations, walls)
    u, d, h_c, h_f = adjusted.directions, adjusted.distances, adjusted.ceiling_height, adjusted.floor_height
    assert bool(improved)
    seen = np.asarray(room.mask & jnp.any(label.wall_index[:, None] == jnp.arange(len(room.mask)), 0))
    np.testing.assert_allclose(np.abs(np.sum(u * directions, -1))[seen], 1.0, atol=1e-5)
    np.testing.assert_allclose(np.abs(d)[seen], np.abs(distances)[seen], rtol=1e-3)
    np.testing.assert_allclose([h_c, h_f], [room.ceiling_height, room.floor_height], rtol=1e-3)


@settings(max_examples=20, deadline=None)
@given(st.floats(0.2, 5.0), st.floats(1.2, 8.0), st.booleans(), st.integers(0, 2**31 - 1))
def test_boundary_weights_are_the_squared_noise_ratio(ceiling_sigma, ratio, floor_noisier, seed):
    """Gaussian rows whose noise differs by ``ratio``: the noisier boundary gets about ``1 / ratio^2``, the other 1;
    unused rows do not count."""
    rng = np.random.default_rng(seed)
    sigmas = (ceiling_sigma, ceiling_sigma * ratio) if floor_noisier else (ceiling_sigma * ratio, ceiling_sigma)
    errors = [rng.normal(0.0, sigma, 20000).astype(np.float32) for sigma in sigmas]
    used = rng.random(20000) < 0.7
    outliers = [np.where(used, e, 1e4) for e in errors]  # far off, but unused
    weights = np.asarray(boundary_weights(*map(jnp.asarray, (*outliers, used, used)), 0.1))
    noisy = 1 if floor_noisier else 0
    assert weights[1 - noisy] == 1.0
    # the estimate's relative spread is about 2% with 14000 rows: 10% is 5 standard deviations
    np.testing.assert_allclose(weights[noisy], 1.0 / ratio**2, rtol=0.1)


def test_boundary_weights_are_one_for_exact_or_missing_rows():
    zeros, noisy, used = jnp.zeros(64), 3.0 * jnp.ones(64), jnp.ones(64, bool)
    np.testing.assert_array_equal(boundary_weights(zeros, 0.3 * jnp.ones(64), used, used, 0.5), [1.0, 1.0])
    # a boundary without rows is not the less noisy one: the other keeps weight 1, however noisy
    np.testing.assert_array_equal(boundary_weights(noisy, zeros, used, ~used, 0.5), [1.0, 1.0])
    np.testing.assert_array_equal(boundary_weights(zeros, noisy, ~used, used, 0.5), [1.0, 1.0])
    np.testing.assert_array_equal(boundary_weights(noisy, noisy, ~used, ~used, 0.5), [1.0, 1.0])


@pytest.mark.slow
@pytest.mark.parametrize("world", ["manhattan", "atlanta"])
def test_adjustment_structure_gives_the_dense_normal_matrix(world):
    """The colouring of the final adjustment's parameters is valid: probing recovers ``J^T J`` exactly,
    with unused columns, penalised corners and empty wall slots."""
    batch, labels = rooms(world, "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    labels = manhattan_frame(directions, room.mask.astype(directions.dtype))[0] if world == "manhattan" else None
    columns = jnp.arange(WIDTH)
    observations = BoundaryObservations(
        columns=columns,
        ceiling_v=label.ceiling_v + 0.3,
        floor_v=label.floor_v - 0.2,
        ceiling_used=columns % 5 != 0,
        floor_used=columns % 7 != 0,
        column_wall=jnp.where(columns % 11 == 0, -1, label.wall_index),
        corner_columns=jnp.linspace(0, WIDTH, len(room.mask)),
        corner_used=room.mask,
        wall_mask=room.mask,
        row_weights=jnp.array([1.0, 0.25]),
    )
    assert not bool(jnp.all(room.mask)), "the room should leave empty slots"
    problem = layout_problem(
        Walls(directions, 1.02 * distances, room.ceiling_height, room.floor_height), labels, room.mask
    )
    flat, unravel = jax.flatten_util.ravel_pytree(problem.start)

    def residuals(f):
        return problem_residuals(problem, unravel(f), cam, observations, observation_directions(cam, observations), 1.0)

    structure = jacobian_structure(problem, observations)
    dense = jax.jit(jax.jacfwd(residuals))(flat)
    probed = jax.jit(
        lambda f: normal_matrix(probe_jacobian(jax.linearize(residuals, f)[1], structure, f.dtype), structure)
    )(flat)
    scale = np.abs(dense.T @ dense).max()
    np.testing.assert_allclose(probed / scale, dense.T @ dense / scale, atol=1e-6)
    # the fitted rows are the layout's residuals times each boundary's weight
    start = Walls(directions, 1.02 * distances, room.ceiling_height, room.floor_height)
    plain = layout_residuals(start, cam, observations, 1.0)[: 2 * WIDTH].reshape(2, WIDTH)
    weighted = residuals(flat)[: 2 * WIDTH].reshape(2, WIDTH)
    assert np.abs(plain[1]).max() > 0.5  # the start is off the room
    np.testing.assert_allclose(weighted, plain * np.array([[1.0], [0.25]]), rtol=1e-4, atol=1e-3)


SMOOTHING = 9  # columns averaged into one noise value: errors correlated along the wall like a network's


def _noisy_label_rows(room, label, ceiling_noise, floor_noise) -> BoundaryObservations:
    """Every column's exact rows plus the given noise, weighted as the pipeline weights them, no corner penalty."""
    used = jnp.ones(WIDTH, bool)
    return BoundaryObservations(
        columns=jnp.arange(WIDTH),
        ceiling_v=label.ceiling_v + ceiling_noise,
        floor_v=label.floor_v + floor_noise,
        ceiling_used=used,
        floor_used=used,
        column_wall=label.wall_index,
        corner_columns=jnp.zeros(len(room.mask)),
        corner_used=jnp.zeros(len(room.mask), bool),
        wall_mask=room.mask,
        row_weights=boundary_weights(ceiling_noise, floor_noise, used, used, 0.1),
    )


@pytest.mark.extended
@pytest.mark.parametrize("manhattan, floor_noise", [(True, 1.0), (False, 3.0)])
def test_layout_uncertainty_matches_monte_carlo(manhattan, floor_noise):
    """Rows of a known room with 1 px ceiling noise and ``floor_noise`` px floor noise, white or averaged over
    ``SMOOTHING`` columns, weighted as the pipeline weights them: the predicted corner covariance matches
    the spread of the adjusted corners over the draws."""
    batch, labels = rooms("manhattan" if manhattan else "atlanta", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    wall_labels, _ = manhattan_frame(directions, room.mask.astype(directions.dtype))
    wall_labels = wall_labels if manhattan else None
    draws = 48
    white = jax.random.normal(jax.random.key(1), (draws, 2, WIDTH))
    samples = jax.random.normal(jax.random.key(2), (draws, 2, WIDTH + SMOOTHING - 1))
    box = jnp.ones(SMOOTHING) / math.sqrt(SMOOTHING)  # unit variance after averaging
    smooth = jax.vmap(jax.vmap(lambda x: jnp.convolve(x, box, mode="valid")))(samples)

    def one(noise):
        observations = _noisy_label_rows(room, label, noise[0], floor_noise * noise[1])
        walls = adjust_layout(
            cam, observations, Walls(directions, distances, room.ceiling_height, room.floor_height), wall_labels
        )[0]
        corners, _ = loop_corners(walls.directions, walls.distances, room.mask)
        return corners, layout_uncertainty(cam, observations, walls, wall_labels)

    corners, uncertainty = jax.jit(jax.vmap(one))(jnp.concatenate([white, smooth]))
    truth, _ = loop_corners(directions, distances, room.mask)
    for kind, expected_tau in ((slice(None, draws), 1.0), (slice(draws, None), SMOOTHING)):
        error = (corners[kind] - truth)[:, room.mask]  # (draws, corners, 2)
        covariance = uncertainty.corner_covariance[kind][:, room.mask]
        # squared Mahalanobis distances: chi-square with 2 degrees of freedom if calibrated. Medians and
        # quantiles, not means: where two walls meet at a shallow angle the corner's error has heavy tails.
        mahalanobis = np.einsum("dki,dkij,dkj->dk", error, np.linalg.inv(covariance), error)
        assert 0.9 < np.median(mahalanobis) < 2.1, np.median(mahalanobis)  # chi-square median: 2 ln 2 = 1.39
        assert 0.88 < np.mean(mahalanobis < 5.991) < 0.99  # its 95% quantile
        # a box average of n white samples has tau = 1 + 2 sum_k (1 - k / n) = n
        tau = np.median(uncertainty.correlation_time[kind])
        assert 0.75 * expected_tau < tau < 1.25 * expected_tau, tau
        np.testing.assert_allclose(np.median(uncertainty.row_sigma[kind], 0), [1.0, floor_noise], rtol=0.15)


@pytest.mark.extended
@pytest.mark.parametrize("manhattan", [True, False])
def test_layout_uncertainty_with_wall_offsets_matches_monte_carlo(manhattan):
    """Rows of a known room with 0.5 px white noise plus a 2 px offset per wall and boundary (an error the
    fit absorbs): with ``wall_offset_noise`` = 2 px the covariance matches the adjusted corners' spread
    (Manhattan) or errs on the safe side (Atlanta: the residuals show part of the offsets, which then count
    twice); without it (the residuals alone) too few true corners fall inside their 95% ellipse."""
    batch, labels = rooms("manhattan" if manhattan else "atlanta", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    wall_labels = manhattan_frame(directions, room.mask.astype(directions.dtype))[0] if manhattan else None
    draws, offset = 64, 2.0
    white = 0.5 * jax.random.normal(jax.random.key(3), (draws, 2, WIDTH))
    per_wall = offset * jax.random.normal(jax.random.key(4), (draws, 2, len(room.mask)))
    noise = white + jnp.where(label.wall_index >= 0, per_wall[:, :, label.wall_index], 0.0)

    def one(noise):
        observations = _noisy_label_rows(room, label, noise[0], noise[1])
        walls = adjust_layout(
            cam, observations, Walls(directions, distances, room.ceiling_height, room.floor_height), wall_labels
        )[0]
        corners, _ = loop_corners(walls.directions, walls.distances, room.mask)
        return corners, *(
            layout_uncertainty(
                cam, observations, walls, wall_labels, config=UncertaintyConfig(wall_offset_noise=2 * size)
            ).corner_covariance
            for size in (offset, 0.0)
        )

    corners, modelled, residuals_only = jax.jit(jax.vmap(one))(noise)
    truth, _ = loop_corners(directions, distances, room.mask)
    error = (corners - truth)[:, room.mask]
    inside = [
        np.mean(np.einsum("dki,dkij,dkj->dk", error, np.linalg.inv(covariance[:, room.mask]), error) < 5.991)
        for covariance in (modelled, residuals_only)
    ]
    if manhattan:
        assert 0.88 < inside[0] < 0.995 and inside[1] < 0.8, inside
    else:
        assert inside[0] >= 0.95 and inside[1] < 0.92, inside


@pytest.mark.extended
@pytest.mark.parametrize("manhattan", [True, False])
def test_layout_uncertainty_with_one_exact_boundary_is_positive(manhattan):
    """Noisy ceiling rows, exact floor rows (the floor's variance 0): the covariances stay positive
    semi-definite, the floor height's variance included."""
    batch, labels = rooms("manhattan" if manhattan else "atlanta", "none")
    checked = 0
    for room, label in [(pick(batch, i), pick(labels, i)) for i in range(4)]:
        cam = room.camera(WIDTH, HEIGHT)
        directions, distances = ncjax.synth.room_walls(room)[:2]
        wall_labels = manhattan_frame(directions, room.mask.astype(directions.dtype))[0] if manhattan else None
        observations = _noisy_label_rows(room, label, jax.random.normal(jax.random.key(7), (WIDTH,)), jnp.zeros(WIDTH))
        walls = adjust_layout(
            cam, observations, Walls(directions, distances, room.ceiling_height, room.floor_height), wall_labels
        )[0]
        uncertainty = layout_uncertainty(cam, observations, walls, wall_labels)
        corners = np.asarray(uncertainty.corner_covariance)[np.asarray(room.mask)]
        if not np.all(np.isfinite(corners)):
            continue  # a wall that no column sees: its corners' covariance is infinite by design
        checked += 1
        assert np.all(np.linalg.eigvalsh(corners) >= -1e-9), np.linalg.eigvalsh(corners).min()
        assert np.all(np.diag(np.asarray(uncertainty.height_covariance)) >= 0)
        assert float(uncertainty.correlation_time) < 3.0  # white ceiling noise; the floor's rounding does not count
    assert checked >= 2


@pytest.mark.extended
@pytest.mark.parametrize("manhattan", [True, False])
def test_layout_uncertainty_of_a_wall_no_row_sees(manhattan):
    """One wall's rows unused: its corners' covariance is infinite, the heights' and the other corners' finite;
    the other walls still fix the heights, about as well as every wall does."""
    batch, labels = rooms("manhattan" if manhattan else "atlanta", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    wall_labels = manhattan_frame(directions, room.mask.astype(directions.dtype))[0] if manhattan else None
    noise = jax.random.normal(jax.random.key(5), (2, WIDTH))
    every = _noisy_label_rows(room, label, noise[0], noise[1])
    hidden = 1
    seen = label.wall_index != hidden
    blind = dataclasses.replace(every, ceiling_used=seen, floor_used=seen)
    walls = adjust_layout(
        cam, every, Walls(directions, distances, room.ceiling_height, room.floor_height), wall_labels
    )[0]
    full, partial = (layout_uncertainty(cam, o, walls, wall_labels) for o in (every, blind))
    count = int(np.sum(room.mask))
    touching = np.isin(np.arange(count), [hidden, (hidden + 1) % count])  # wall k runs from corner k to k + 1
    corners = np.asarray(partial.corner_covariance)[:count]
    assert np.all(np.isinf(corners[touching])) and np.all(np.isfinite(corners[~touching]))
    assert np.all(np.isfinite(np.asarray(full.corner_covariance)[:count]))
    height, full_height = np.asarray(partial.height_covariance), np.asarray(full.height_covariance)
    assert np.all(np.isfinite(height)) and np.all(np.linalg.eigvalsh(height) >= 0)
    np.testing.assert_allclose(np.diag(height), np.diag(full_height), rtol=0.5)
    assert np.all(np.linalg.eigvalsh(corners[~touching]) > 0)


@pytest.mark.slow
def test_layout_uncertainty_of_a_wall_one_corner_pins():
    """Atlanta: a wall whose rows are unused and whose start corner alone is observed (two parameters, one
    constraint: J^T J singular, no column zero) leaves its far corner free: a variance orders of magnitude
    above the other corners', not the near-zero one of a regularised inverse without its prior."""
    batch, labels = rooms("atlanta", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    noise = jax.random.normal(jax.random.key(5), (2, WIDTH))
    every = _noisy_label_rows(room, label, noise[0], noise[1])
    count, hidden = int(np.sum(room.mask)), 1
    wall, before = np.asarray(label.wall_index), np.roll(np.asarray(label.wall_index), 1)
    meets = ((before == hidden - 1) & (wall == hidden)) | ((before == hidden) & (wall == hidden - 1))
    start_corner = jnp.zeros(len(room.mask)).at[hidden].set(np.flatnonzero(meets)[0] - 0.5)  # between two pixel columns
    seen = label.wall_index != hidden
    pinned = dataclasses.replace(
        every,
        ceiling_used=seen,
        floor_used=seen,
        corner_columns=start_corner,
        corner_used=jnp.arange(len(room.mask)) == hidden,
    )
    walls = adjust_layout(cam, every, Walls(directions, distances, room.ceiling_height, room.floor_height), None)[0]
    full, partial = (layout_uncertainty(cam, o, walls, None) for o in (every, pinned))
    spread = np.trace(np.asarray(partial.corner_covariance)[:count], axis1=1, axis2=2)
    far, elsewhere = hidden + 1, ~np.isin(np.arange(count), [hidden, hidden + 1])
    assert np.all(np.isfinite(spread)) and spread[far] > 1e3 * spread[elsewhere].max(), spread
    np.testing.assert_allclose(np.diag(partial.height_covariance), np.diag(full.height_covariance), rtol=0.5)


@pytest.mark.slow
def test_layout_uncertainty_of_a_height_no_row_sees():
    """No ceiling row used: the ceiling height is free, so the room height's sigma is infinite (not 0)."""
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 2), pick(labels, 2)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    wall_labels = manhattan_frame(directions, room.mask.astype(directions.dtype))[0]
    noise = jax.random.normal(jax.random.key(6), (2, WIDTH))
    every = _noisy_label_rows(room, label, noise[0], noise[1])
    floor_only = dataclasses.replace(every, ceiling_used=jnp.zeros(WIDTH, bool))
    walls = adjust_layout(
        cam, every, Walls(directions, distances, room.ceiling_height, room.floor_height), wall_labels
    )[0]
    assert np.isfinite(float(room_height_sigma(layout_uncertainty(cam, every, walls, wall_labels).height_covariance)))
    assert np.isinf(float(room_height_sigma(layout_uncertainty(cam, floor_only, walls, wall_labels).height_covariance)))


def test_correlation_time_matches_a_direct_sum():
    """tau = 1 + 2 sum of the lag correlations up to the first non-positive one, pairs on one wall only (cyclic)."""
    rng = np.random.default_rng(3)
    count, max_lag = 96, 12
    smooth = np.stack(
        [
            np.convolve(np.tile(rng.normal(size=count), 2), np.ones(4) / 4, "same")[count // 2 : count // 2 + count]
            for _ in range(2)
        ]
    )
    used = rng.random((2, count)) < 0.8
    column_wall = np.repeat([2, 0, 1, -1, 2], [20, 30, 25, 6, 15])
    used &= column_wall >= 0
    variance = np.sum(np.where(used, smooth**2, 0)) / used.sum()
    expected, positive = 1.0, True
    for lag in range(1, max_lag + 1):
        shifted = np.roll(np.arange(count), -lag)
        pair = used & used[:, shifted] & (column_wall == column_wall[shifted])[None]
        rho = np.sum(np.where(pair, smooth * smooth[:, shifted], 0)) / max(pair.sum(), 1) / variance
        positive &= rho > 0
        expected += 2 * rho * positive
    tau = jax.jit(correlation_time, static_argnums=3)(jnp.asarray(smooth, jnp.float32), used, column_wall, max_lag)
    assert expected > 1.5  # the smoothing correlates neighbours
    np.testing.assert_allclose(tau, expected, rtol=1e-5)


# --- forward model of the boundaries ------------------------------------------------------------


@pytest.mark.slow
def test_wall_rows_match_exact_labels():
    batch, labels = rooms("atlanta", "any")
    for i in range(3):
        room, label = pick(batch, i), pick(labels, i)
        directions, distances = ncjax.synth.room_walls(room)[:2]
        wall = label.wall_index
        columns = jnp.arange(WIDTH, dtype=jnp.float32)
        ceiling, floor, seen = wall_boundary_rows(
            room.camera(WIDTH, HEIGHT),
            directions[wall],
            distances[wall],
            room.ceiling_height,
            room.floor_height,
            columns,
        )
        assert bool(jnp.all(seen))
        np.testing.assert_allclose(ceiling, label.ceiling_v, atol=2e-3)
        np.testing.assert_allclose(floor, label.floor_v, atol=2e-3)


@pytest.mark.slow
def test_boundary_points_invert_the_rows_and_fit_the_wall_line():
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.4)
    direction, distance = jnp.array([0.6, 0.8]), jnp.array(-2.5)
    columns = jnp.arange(200.0, 260.0)
    ceiling, _, _ = wall_boundary_rows(cam, direction, distance, 1.2, -1.5, columns)
    points, ok = boundary_points(cam, columns, ceiling, 1.2)
    assert bool(jnp.all(ok))
    np.testing.assert_allclose(points @ jnp.array([-0.8, 0.6]), -2.5, atol=1e-4)
    fitted, offset = fit_plan_line(points, jnp.ones(len(columns)))
    assert abs(abs(float(fitted @ direction)) - 1) < 1e-6
    np.testing.assert_allclose(offset * jnp.sign(fitted @ direction), -2.5, atol=1e-4)


def test_wall_planes_meet_like_plucker_lines():
    a, b = jnp.array([1.0, 0.0]), jnp.array([0.6, 0.8])
    point, ok = wall_planes_meet(a, -2.0, b, -1.0)
    lines = ncjax.geometry.horizontal_wall_line(jnp.stack([a, b]), jnp.array([-2.0, -1.0]), 1.0)
    np.testing.assert_allclose(point, ncjax.geometry.intersect_coplanar_lines(lines[0], lines[1])[:2], atol=1e-5)
    assert bool(ok) and not bool(wall_planes_meet(a, -2.0, a, -1.0)[1])


# --- the pipeline on exact boundaries --------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    "world,occlusion",
    # Atlanta's own program is the extended tier's (its solvers are tested in test_layout_solvers.py)
    [("manhattan", "none"), pytest.param("atlanta", "none", marks=pytest.mark.extended), ("manhattan", "required")],
)
def test_exact_boundaries_give_the_room(world, occlusion):
    batch, labels = rooms(world, occlusion)
    good = 0
    for i in range(6):
        room, label = pick(batch, i), pick(labels, i)
        layout = ncjax.layout_from_boundaries(
            label.ceiling_v, label.floor_v, label.corner_target, room.camera(WIDTH, HEIGHT), world=world
        )
        if not bool(layout.ok):
            continue
        result = metrics.evaluate_layout(layout, room if world == "manhattan" else label)
        if not math.isfinite(result["ce"]):
            continue  # corner count differs: two corners closer than the suppression window at 512 px
        assert result["ce"] < 0.02 and result["iou3d"] > 0.98, result
        if occlusion == "required":
            assert bool(jnp.any(layout.inserted))
        good += 1
    assert good >= 4  # 512 x 256: corners a few columns apart may merge


@pytest.mark.extended
def test_batch_auto_world_and_shapes():
    """A batch of two rooms, each with its own camera (rc), in a (1, 2) batch shape."""
    batch, labels = rooms("manhattan", "none")
    two = pick(labels, slice(0, 2))
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(pick(batch, slice(0, 2)))
    assert float(cams.rc[0]) != float(cams.rc[1])
    stacked = [x[None] for x in (two.ceiling_v, two.floor_v, two.corner_target)]
    cam = jax.tree.map(lambda x: x[None], cams)
    layout = ncjax.layout_from_boundaries(*stacked, cam, world="auto")
    assert (
        layout.ceiling_corners.shape == (1, 2, 32, 3) and layout.mask.shape == (1, 2, 32) and layout.ok.shape == (1, 2)
    )
    assert layout.corner_covariance.shape == (1, 2, 32, 2, 2) and layout.height_covariance.shape == (1, 2, 2, 2)
    assert bool(jnp.all(jnp.isfinite(layout.corner_covariance)))
    assert bool(jnp.all(layout.ok)) and bool(jnp.all(layout.manhattan))
    for i in range(2):
        result = metrics.evaluate_layout(jax.tree.map(lambda x: x[0, i], layout), pick(batch, i))
        assert result["ce"] < 0.02, result
    with pytest.raises(ValueError, match="batch's shape"):
        ncjax.layout_from_boundaries(*stacked, cams, world="auto")


@pytest.mark.extended
def test_auto_world_gives_the_chosen_branchs_own_layout():
    """``world="auto"`` adjusts both branches' walls as one batch: the layout it keeps is the one that branch
    gives alone, for a room of each world with noisy rows (where both branches return a layout)."""
    for world in ("manhattan", "atlanta"):
        batch, labels = rooms(world, "none")
        room, label = pick(batch, 0), pick(labels, 0)
        noise = jax.random.normal(jax.random.key(3), (2, WIDTH))
        rows = (label.ceiling_v + noise[0], label.floor_v + noise[1], label.corner_target)
        cam = room.camera(WIDTH, HEIGHT)
        auto = ncjax.layout_from_boundaries(*rows, cam, world="auto")
        chosen = "manhattan" if bool(auto.manhattan) else "atlanta"
        alone = ncjax.layout_from_boundaries(*rows, cam, world=chosen)
        assert int(auto.status) == int(alone.status)
        for name in ("ceiling_corners", "floor_corners", "ceiling_height", "floor_height", "explained_fraction"):
            np.testing.assert_allclose(getattr(auto, name), getattr(alone, name), atol=1e-4, err_msg=name)


@pytest.mark.extended
def test_compact_slots_give_the_same_layouts_and_rooms_that_need_more_are_rerun():
    batch, labels = rooms("manhattan", "required")
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(batch)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)
    # chunks of 4: the compact run of the six rooms is a loop over one chunk and a remainder of two
    full = ncjax.PipelineConfig(capacity=16, compact_capacity=0, chunk_size=4).replace(
        uncertainty={"covariance": False}
    )
    layout = ncjax.layout_from_boundaries(
        *rows, cams, config=dataclasses.replace(full, compact_capacity=8), world="manhattan"
    )
    walls = np.asarray(layout.mask).sum(1)
    # the third room's exact rows hold walls 1 and 1.7 columns wide (the latter's two corners one peak of the
    # exact target), which neither capacity lays out: the comparison below checks that they fail alike
    assert layout.mask.shape == (6, 16) and np.asarray(layout.ok).tolist() == [True, True, False, True, True, True]
    assert (walls > 8).any() and (walls <= 8).any(), walls  # both the compact run and the rerun count
    empty = ~np.asarray(layout.mask)
    for name in ("ceiling_corners", "wall_directions", "wall_distances", "ceiling_lines", "corner_columns"):
        assert not np.asarray(getattr(layout, name))[empty].any(), name
    # four rooms, across the chunk and the remainder, with all the slots from the start in one vmap
    last = slice(2, 6)
    keys = jax.random.split(jax.random.key(0), 6)[last]
    inputs = _Inputs(Rows(*(x[last] for x in rows)), pick(cams, last), None, keys)
    expected = _batched_layout_jit(inputs, full, "manhattan", 16)
    np.testing.assert_array_equal(layout.mask[last], expected.mask)
    np.testing.assert_array_equal(layout.status[last], expected.status)
    np.testing.assert_allclose(layout.ceiling_corners[last], expected.ceiling_corners, atol=1e-4)
    np.testing.assert_allclose(layout.floor_corners[last], expected.floor_corners, atol=1e-4)


@pytest.mark.extended
def test_degenerate_inputs_fail_with_a_reason_and_no_nan():
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 0), pick(labels, 0)
    cam = room.camera(WIDTH, HEIGHT)
    nan = jnp.full(WIDTH, jnp.nan)
    cases = {
        ncjax.LayoutStatus.INVALID_INPUT: (nan, nan, label.corner_target, cam),
        ncjax.LayoutStatus.NO_CORNERS: (label.ceiling_v, label.floor_v, jnp.zeros(WIDTH), cam),
        ncjax.LayoutStatus.NO_SCALE: (
            label.ceiling_v,
            label.floor_v,
            label.corner_target,
            ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.0),
        ),
    }
    for status, args in cases.items():
        layout = ncjax.layout_from_boundaries(*args, world="manhattan")
        assert int(layout.status) == status and not bool(layout.ok)
        assert bool(jnp.all(jnp.isfinite(layout.ceiling_corners)))
        # failed layouts' covariances: finite or all-infinite (not determined), never NaN
        assert not np.any(np.isnan(layout.corner_covariance)) and not np.any(np.isnan(layout.height_covariance))
    # swapped rows, a flat NaN corner probability and a 0.1 mm circle: a failure, without NaN anywhere
    tiny = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=1e-4)
    layout = ncjax.layout_from_boundaries(label.floor_v, label.ceiling_v, nan, tiny, world="manhattan")
    assert not bool(layout.ok)
    assert not any(np.any(np.isnan(np.asarray(leaf))) for leaf in jax.tree.leaves(layout))
    # The same exact room, valid with the defaults, is implausible for a 1 m room-height limit.
    assert bool(
        ncjax.layout_from_boundaries(label.ceiling_v, label.floor_v, label.corner_target, cam, world="manhattan").ok
    )
    strict = ncjax.PipelineConfig().replace(checks={"max_room_height": 1.0})
    layout = ncjax.layout_from_boundaries(
        label.ceiling_v, label.floor_v, label.corner_target, cam, config=strict, world="manhattan"
    )
    assert int(layout.status) == ncjax.LayoutStatus.DEGENERATE_LAYOUT


@pytest.mark.slow
def test_scale_test_fails_layouts_whose_height_sigma_exceeds_the_threshold():
    """Rows with 1 px of noise: the layout's relative room-height sigma is positive and finite; a scale
    test just below it fails the same layout with UNCERTAIN_SCALE, which the default (off) never does."""
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 0), pick(labels, 0)
    cam = room.camera(WIDTH, HEIGHT)
    noise = jax.random.normal(jax.random.key(8), (2, WIDTH))
    rows = (label.ceiling_v + noise[0], label.floor_v + noise[1], label.corner_target)
    layout = ncjax.layout_from_boundaries(*rows, cam, world="manhattan")
    assert bool(layout.ok)
    relative = float(room_height_sigma(layout.height_covariance) / (layout.ceiling_height - layout.floor_height))
    assert 0.0 < relative < 0.1, relative
    compiled = _layout_jit._cache_size()
    strict = ncjax.PipelineConfig().replace(checks={"max_height_uncertainty": 0.9 * relative})
    uncertain = ncjax.layout_from_boundaries(*rows, cam, config=strict, world="manhattan")
    assert int(uncertain.status) == ncjax.LayoutStatus.UNCERTAIN_SCALE and not bool(uncertain.ok)
    np.testing.assert_allclose(uncertain.ceiling_corners, layout.ceiling_corners, atol=1e-5)  # only the status differs
    # rows a tenth of which are 20 px off: the layout explains fewer of them; demanding more flags it,
    # its geometry kept; demanding less leaves it ok
    outliers = jnp.arange(WIDTH) % 10 == 0
    spoilt = (jnp.where(outliers, rows[0] + 20.0, rows[0]), rows[1], rows[2])
    kept = ncjax.layout_from_boundaries(*spoilt, cam, world="manhattan")
    explained = float(kept.explained_fraction)
    assert bool(kept.ok) and 0.6 < explained < 0.95, explained
    demanding = ncjax.PipelineConfig().replace(checks={"min_explained_fraction": min(1.0, explained + 0.02)})
    flagged = ncjax.layout_from_boundaries(*spoilt, cam, config=demanding, world="manhattan")
    assert int(flagged.status) == ncjax.LayoutStatus.LOW_CONFIDENCE and not bool(flagged.ok)
    np.testing.assert_allclose(flagged.ceiling_corners, kept.ceiling_corners, atol=1e-5)
    # thresholds are traced: another value reuses the compiled pipeline, and acts
    assert float(jnp.max(rows[2])) < 1.0
    blind = ncjax.PipelineConfig().replace(corners={"threshold": 1.0, "fallback_threshold": 1.0})
    assert (
        int(ncjax.layout_from_boundaries(*rows, cam, config=blind, world="manhattan").status)
        == ncjax.LayoutStatus.NO_CORNERS
    )
    assert _layout_jit._cache_size() == compiled


def _one_peak_for_the_narrowest_wall(label):
    """The corner target with the two corners of the narrowest wall replaced by one peak between them."""
    corners = np.asarray(label.corner_u)[np.asarray(label.corner_mask)]
    gaps = (np.roll(corners, -1) - corners) % WIDTH
    narrow = int(np.argmin(gaps))
    peak = (corners[narrow] + gaps[narrow] / 2) % WIDTH
    kept = np.append(np.delete(corners, [narrow, (narrow + 1) % len(corners)]), peak)
    return corner_target(kept, np.ones(len(kept), bool), WIDTH), peak, narrow


@pytest.mark.extended
def test_merged_corner_pair_beside_an_unfitted_wall_gets_its_wall_back():
    """The two corners of a Manhattan room's narrowest wall given as one peak (as the network's lobes merge
    close corners), the wall after that peak one that RANSAC could not fit (a narrow wall's usual fate) and
    the boundaries' jump at the peak lost in the rows' noise (no occlusion seen). The unfitted wall votes
    with the direction of its plan line at the fitted walls' heights, the walls around the peak get one
    class, and the wall between them is inserted. Merging the two walls instead (as for a spurious corner)
    would lose both corners."""
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 1), pick(labels, 1)
    cam = room.camera(WIDTH, HEIGHT)
    count = int(np.sum(np.asarray(label.corner_mask)))
    target, peak, narrow = _one_peak_for_the_narrowest_wall(label)
    config = ncjax.PipelineConfig()
    evidence = gather_evidence(Rows(label.ceiling_v, label.floor_v, target), cam, jax.random.key(0), config)
    slots = np.flatnonzero(np.asarray(evidence.corner_mask))
    assert len(slots) == count - 1
    at_peak = slots[
        np.argmin(np.abs((np.asarray(evidence.corner_columns)[slots] - peak + WIDTH / 2) % WIDTH - WIDTH / 2))
    ]
    assert bool(evidence.fitted[at_peak])
    unfitted = evidence.fitted.at[at_peak].set(False)
    wrong = jnp.array([math.cos(0.7), math.sin(0.7)], evidence.walls.direction.dtype)
    evidence = eqx.tree_at(
        lambda e: (e.fitted, e.both_fitted, e.same_plane, e.occluded, e.weights, e.walls.direction),
        evidence,
        (
            unfitted,
            unfitted & unfitted[(jnp.arange(unfitted.shape[0]) - 1) % len(slots)],
            jnp.zeros_like(evidence.same_plane),
            jnp.zeros_like(evidence.occluded),
            evidence.weights.at[at_peak].set(0.0),
            evidence.walls.direction.at[at_peak].set(wrong),
        ),
    )
    directions, support = _segment_directions(evidence)
    after = np.asarray(label.ceiling_corners)[[(narrow + 1) % count, (narrow + 2) % count], :2]
    true_direction = (after[1] - after[0]) / np.linalg.norm(after[1] - after[0])
    estimate = np.asarray(directions[at_peak])
    assert abs(estimate[0] * true_direction[1] - estimate[1] * true_direction[0]) < math.sin(math.radians(1.0))
    assert float(support[at_peak]) > 0
    others = slots[slots != at_peak]
    np.testing.assert_array_equal(np.asarray(directions)[others], np.asarray(evidence.walls.direction)[others])
    layout = branch_layout(manhattan_walls, evidence, config)
    assert bool(layout.ok) and int(jnp.sum(layout.inserted)) == 1
    result = metrics.evaluate_layout(layout, room)
    assert result["ce"] < 0.1 and result["iou3d"] > 0.95, result


def branch_layout(branch_walls, evidence, config):
    """One branch's layout (step 4, then steps 5-6) from given evidence."""
    walls = branch_walls(evidence, config.branches, config.ransac.sample_size, config.checks.max_room_height)
    return finish_layout(evidence, walls, config)


@pytest.mark.slow
def test_corner_offsets_are_zero_at_the_true_corners_and_inf_for_parallel_walls():
    batch, _ = rooms("manhattan", "none")
    room = pick(batch, 0)
    cam = room.camera(WIDTH, HEIGHT)
    directions, distances = ncjax.synth.room_walls(room)[:2]
    corners = jnp.concatenate([room.corners, jnp.full((room.corners.shape[0], 1), room.ceiling_height)], -1)
    columns, _ = ncjax.geometry.project(cam, corners)
    mask = room.mask
    offsets = corner_offsets(cam, directions, distances, mask, jnp.where(mask, columns, 0.0))
    assert float(jnp.max(jnp.where(mask, offsets, 0.0))) < 1e-2
    # without wall 1, walls 0 and 2 (parallel in a Manhattan room) do not meet
    keep = np.flatnonzero(np.asarray(mask))
    keep = np.delete(keep, 1)
    dropped = corner_offsets(cam, directions[keep], distances[keep], jnp.ones(len(keep), bool), columns[keep])
    assert np.isinf(float(dropped[1])) and np.all(np.isfinite(np.asarray(dropped)[np.arange(len(keep)) != 1]))


@pytest.mark.extended
def test_atlanta_peak_whose_walls_meet_elsewhere_gets_a_wall_inserted():
    """An Atlanta room's narrowest wall given as one peak and no boundary jump seen there: its two walls
    meet far from the peak's column (or not at all), so a wall is inserted between them in the corner
    ray's plane, and the layout has every corner; with a huge ``max_corner_offset`` it has one fewer, and
    so with rows as noisy as the walls' boundaries are apart there. Where the jump is seen at the exact
    target's peak, it alone decides: one that does not stand out of its noise inserts no wall."""
    batch, labels = rooms("atlanta", "none")

    def one_narrow_wall(index):
        corners = np.asarray(pick(labels, index).corner_u)[np.asarray(pick(labels, index).corner_mask)]
        gaps = np.sort((np.roll(corners, -1) - corners) % WIDTH)
        return 2 <= gaps[0] and gaps[1] > 3 * gaps[0]

    index = next(i for i in range(6) if bool(pick(labels, i).ok) and one_narrow_wall(i))
    room, label = pick(batch, index), pick(labels, index)
    cam = room.camera(WIDTH, HEIGHT)
    target, _, _ = _one_peak_for_the_narrowest_wall(label)
    evidence = gather_evidence(
        Rows(label.ceiling_v, label.floor_v, target), cam, jax.random.key(0), ncjax.PipelineConfig()
    )
    evidence = eqx.tree_at(lambda e: e.occluded, evidence, jnp.zeros_like(evidence.occluded))

    unseen = eqx.tree_at(lambda e: e.jump_seen, evidence, jnp.zeros_like(evidence.jump_seen))

    def layout(config, evidence=unseen):
        return branch_layout(atlanta_walls, evidence, config)

    count = int(np.sum(np.asarray(label.corner_mask)))
    found = layout(ncjax.PipelineConfig())
    assert bool(found.ok) and int(jnp.sum(found.mask)) == count and int(jnp.sum(found.inserted)) == 1
    result = metrics.evaluate_layout(found, label)
    assert result["iou3d"] > 0.95, result
    missed = layout(ncjax.PipelineConfig().replace(branches={"max_corner_offset": 1e6}))
    assert int(jnp.sum(missed.mask)) == count - 1 and int(jnp.sum(missed.inserted)) == 0
    # rows as noisy as the walls' boundaries are apart at the peak: their far meeting may be the noise's
    noisy = eqx.tree_at(lambda e: e.row_noise, unseen, jnp.asarray(1e3, evidence.row_noise.dtype))
    lost = layout(ncjax.PipelineConfig(), noisy)
    assert int(jnp.sum(lost.mask)) == count - 1 and int(jnp.sum(lost.inserted)) == 0
    # the exact rows' jump is seen at the peak and stands out, whatever the rows' noise; told it does not, no
    # wall goes in however far apart the walls meet
    seen = eqx.tree_at(lambda e: e.row_noise, evidence, noisy.row_noise)
    assert int(jnp.sum(layout(ncjax.PipelineConfig(), seen).inserted)) == 1
    flat = eqx.tree_at(lambda e: e.jump_stands_out, seen, jnp.zeros_like(evidence.jump_stands_out))
    kept = layout(ncjax.PipelineConfig(), flat)
    assert int(jnp.sum(kept.mask)) == count - 1 and int(jnp.sum(kept.inserted)) == 0


@pytest.mark.parametrize("rc", [0.0, 0.8])
def test_side_extrapolation_follows_a_near_walls_curved_boundary(rc):
    """A wall 0.3 m beyond the camera's circle, seen 70 degrees off its normal: ``h / R`` extrapolated from the
    8 columns 3 to 10 columns right of a corner gives its value at the corner column to 1e-5 (its boundary rows
    curve there: a line through 8 of them misses the corner's row by 0.55 px when central)."""
    cam = ncjax.NonCentralPanorama(rc=rc, width=1024, height=512)
    direction = jnp.array([np.cos(1.6), np.sin(1.6)])
    distance = -(rc + 0.3)
    height = 1.2
    corner = 300.4
    radial = rc + range_along(cam, direction, distance, column_directions(cam, jnp.arange(1024.0)))
    _, _, seen = wall_boundary_rows(cam, direction, distance, height, -height, jnp.arange(1024.0))
    usable = seen & (radial > rc)
    assert bool(usable[296:312].all())
    value, ok, spread = side_extrapolation(
        height / radial, usable, jnp.asarray(corner), 1, SideWindow(8, 2.0, 2 * np.pi / 1024)
    )
    truth = height / (rc + range_along(cam, direction, distance, column_directions(cam, jnp.asarray(corner))))
    assert bool(ok) and abs(float(value) - float(truth)) < 1e-5 * float(truth)
    assert float(spread) == pytest.approx(float(full_window_spread(8, 2.0)), rel=0.1)  # the corner is 0.4 off


@given(st.floats(0.0, 1.0), st.floats(0.0, 2 * np.pi), st.floats(0.2, 1.2), st.integers(1, 6), st.floats(0.0, 1.0))
def test_straight_wall_value_follows_a_wall_between_two_of_its_columns(rc, normal, beyond, span, where):
    """``h / R`` of a wall's boundary at two columns a few apart gives it at any column between (``a cos + b sin``
    of the azimuth, exact for the non-central rig, whose columns are radial half-planes)."""
    cam = ncjax.NonCentralPanorama(rc=rc, width=1024, height=512)
    direction = jnp.array([np.cos(normal + np.pi / 2), np.sin(normal + np.pi / 2)], jnp.float32)
    distance = -(rc + beyond)
    all_columns = jnp.arange(1024.0)
    reach = range_along(cam, direction, distance, column_directions(cam, all_columns))
    facing = int(jnp.argmin(jnp.where(jnp.isfinite(reach) & (reach > 0), reach, jnp.inf)))  # nearest the normal
    first = jnp.float32(facing + 40.0 * (2 * where - 1))
    columns = first + jnp.array([0.0, span * where, span], jnp.float32)
    radial = rc + range_along(cam, direction, distance, column_directions(cam, columns))
    value = 1.3 / radial
    angle = 2 * np.pi / 1024
    between = straight_wall_value(value[0], value[2], angle * span, angle * span * where)
    assert abs(float(between) - float(value[1])) < 1e-4 * float(value[1])


@pytest.mark.slow
def test_an_occlusion_beside_a_narrow_wall_is_found():
    """A room of experiments/pipeline_table.py whose labels put an occlusion at column 43.4, 1.5 columns from the
    next corner: the wall between is too narrow to extrapolate, and its one column's rows, off the straight wall
    between its neighbours' boundaries, show the occlusion at the corner of the nearer neighbour."""
    config = ncjax.RoomConfig(world="atlanta", occlusion="required", capacity=32, room_tries=4, camera_tries=128)
    room = pick(jax.vmap(lambda k: ncjax.synth.random_room(k, config))(jax.random.split(jax.random.key(8), 30)), 17)
    cam = room.camera(1024, 512)
    label = ncjax.synth.room_labels(room, cam)
    corners = np.asarray(label.corner_u)[np.asarray(label.corner_mask & label.corner_is_occlusion)]
    assert np.allclose(corners, 43.4, atol=0.1)  # the occlusion's near and far points
    evidence = jax.jit(gather_evidence)(
        Rows(label.ceiling_v, label.floor_v, label.corner_target), cam, jax.random.key(0), ncjax.PipelineConfig()
    )
    columns = np.asarray(evidence.corner_columns)[np.asarray(evidence.corner_mask)]
    occluded = np.asarray(evidence.occluded)[np.asarray(evidence.corner_mask)]
    narrow = np.abs(columns - 43.4) < 0.1
    assert narrow.sum() == 1 and np.any(np.abs(columns - 44.9) < 0.1)  # both corners of the peak
    assert occluded[narrow].all() and not bool(
        evidence.jump_seen[np.flatnonzero(np.asarray(evidence.corner_mask))[narrow]].any()
    )


@pytest.mark.extended
def test_noisy_rows_do_not_fake_occlusions():
    """2 px of white noise on the rows of rooms without occlusions: a fixed 4 px jump threshold sees
    occlusions at most corners; scaled by the rows' own noise (the default) it sees almost none."""
    batch, labels = rooms("manhattan", "none")
    noise = 2.0 * jax.random.normal(jax.random.key(5), (2,) + labels.ceiling_v.shape)
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(batch)
    keys = jax.random.split(jax.random.key(0), labels.ceiling_v.shape[0])

    def occluded_fraction(config):
        evidence = jax.jit(jax.vmap(lambda c, f, p, cam, k: gather_evidence(Rows(c, f, p), cam, k, config)))(
            labels.ceiling_v + noise[0], labels.floor_v + noise[1], labels.corner_target, cams, keys
        )
        return float(jnp.sum(evidence.occluded) / jnp.sum(evidence.corner_mask))

    assert occluded_fraction(ncjax.PipelineConfig()) < 0.1
    assert occluded_fraction(ncjax.PipelineConfig().replace(occlusion={"noise_factor": 0.0})) > 0.4


@pytest.mark.extended
def test_joint_solver_weights_follow_the_row_noise():
    """Floor rows three times noisier than the ceiling's: the evidence weighs the floor down for the joint
    solvers (the ceiling keeps 1); a huge ``min_boundary_noise`` turns the weighting off."""
    batch, labels = rooms("manhattan", "none")
    noise = jax.random.normal(jax.random.key(6), (2,) + labels.ceiling_v.shape) * jnp.array([0.3, 1.0])[:, None, None]
    cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(batch)
    keys = jax.random.split(jax.random.key(0), labels.ceiling_v.shape[0])

    def row_weights(config):
        evidence = jax.jit(jax.vmap(lambda c, f, p, cam, k: gather_evidence(Rows(c, f, p), cam, k, config)))(
            labels.ceiling_v + noise[0], labels.floor_v + noise[1], labels.corner_target, cams, keys
        )
        return np.asarray(evidence.row_weights)

    weights = row_weights(ncjax.PipelineConfig())
    np.testing.assert_array_equal(weights[:, 0], 1.0)
    assert np.all(weights[:, 1] < 0.5), weights  # (0.3 / 1)^2 = 0.09, more as the inlier cut trims the floor's errors
    np.testing.assert_array_equal(
        row_weights(ncjax.PipelineConfig().replace(adjustment={"min_boundary_noise": 1e9})), 1.0
    )


def test_bad_arguments_raise():
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.5)
    rows = jnp.zeros(WIDTH)
    with pytest.raises(ValueError, match="world"):
        ncjax.layout_from_boundaries(rows, rows, rows, cam, world="gothic")
    with pytest.raises(ValueError, match="cam.width"):
        ncjax.layout_from_boundaries(rows[:-1], rows[:-1], rows[:-1], cam, world="manhattan")
    # A key of another shape than the batch's: the annotation refuses it under the tests' type checks, a
    # ValueError without them.
    with pytest.raises((ValueError, jaxtyping.TypeCheckError)):
        ncjax.layout_from_boundaries(rows, rows, rows, cam, key=jax.random.split(jax.random.key(0), 2))
    with pytest.raises((ValueError, jaxtyping.TypeCheckError)):
        images = np.zeros((2, 256, 512, 3), np.uint8)
        ncjax.reconstruct_batch(images, [0.5, 0.5], key=jax.random.split(jax.random.key(0), 3))
    with pytest.raises(ValueError, match="capacity"):
        ncjax.PipelineConfig(capacity=2)
    with pytest.raises(TypeError, match="corner_threshold is now corners.threshold"):
        ncjax.PipelineConfig(corner_threshold=0.4)  # a setting's name before the settings were grouped by stage
    with pytest.raises(ValueError, match="stride"):
        ncjax.PipelineConfig().replace(adjustment={"stride": 0})
    with pytest.raises(ValueError, match="noise_factor"):
        ncjax.PipelineConfig().replace(occlusion={"noise_factor": -1.0})
    with pytest.raises(ValueError, match="stray_noise_factor"):
        ncjax.PipelineConfig().replace(branches={"stray_noise_factor": -1.0})
    with pytest.raises(ValueError, match="max_height_uncertainty must be > 0"):
        ncjax.PipelineConfig().replace(checks={"max_height_uncertainty": 0.0})
    with pytest.raises(ValueError, match="needs uncertainty.covariance"):
        ncjax.PipelineConfig().replace(checks={"max_height_uncertainty": 0.1}, uncertainty={"covariance": False})
    with pytest.raises(ValueError, match="max_scale_conflict must be > 0"):
        ncjax.PipelineConfig().replace(prior={"max_scale_conflict": 0.0})
    with pytest.raises(ValueError, match="min_corners"):
        ncjax.PipelineConfig().replace(corners={"min_corners": 33})
    with pytest.raises(ValueError, match="min_corners"):
        ncjax.PipelineConfig().replace(corners={"min_corners": 20})  # more than the compact first run's 16 slots
    assert ncjax.PipelineConfig(compact_capacity=0).replace(corners={"min_corners": 20}).corners.min_corners == 20
    with pytest.raises(ValueError, match="fallback_threshold"):
        ncjax.PipelineConfig().replace(corners={"fallback_threshold": -0.1})
    # probabilities and fractions in [0, 1], limits positive (NaN refused by each)
    for part, field, values in (
        ("corners", "threshold", (2.0, -1.0, math.nan)),
        ("corners", "fallback_threshold", (1.5,)),
        ("occlusion", "merge_fraction", (1.2, 0.0)),
        ("checks", "min_finite_fraction", (1.5, -0.1)),
        ("checks", "max_room_height", (0.0, math.nan)),
        ("checks", "max_corner_distance", (-1.0,)),
        ("checks", "max_corner_range_ratio", (0.0, math.nan)),
    ):
        for value in values:
            with pytest.raises(ValueError, match=f"{field} must be"):
                ncjax.PipelineConfig().replace(**{part: {field: value}})
    assert (
        ncjax.PipelineConfig().replace(corners={"threshold": 1.0, "fallback_threshold": 0.0}).corners.threshold == 1.0
    )


@pytest.mark.extended
def test_gradients_through_the_pipeline_are_finite_and_match_finite_differences():
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 1), pick(labels, 1)
    cam = room.camera(WIDTH, HEIGHT)

    def height(ceiling_v):
        return ncjax.layout_from_boundaries(
            ceiling_v, label.floor_v, label.corner_target, cam, world="manhattan"
        ).ceiling_height

    gradient = jax.grad(height)(label.ceiling_v)
    assert bool(jnp.all(jnp.isfinite(gradient))) and float(jnp.abs(gradient).sum()) > 0
    # raising every ceiling row (moving the boundary down) lowers the recovered ceiling
    step = 0.5
    finite_difference = (height(label.ceiling_v + step) - height(label.ceiling_v - step)) / (2 * step)
    assert float(jnp.sum(gradient)) < 0 and float(finite_difference) < 0
    np.testing.assert_allclose(float(jnp.sum(gradient)), float(finite_difference), rtol=0.2)


@pytest.mark.slow
@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 6))
def test_cyclic_labels_are_the_least_cost_labelling(seed, count):
    """Dynamic programming on the wall cycle against all 2^n labellings."""
    rng = np.random.default_rng(seed)
    capacity = 6
    unary = rng.uniform(0, 1, (capacity, 2))
    same_cost, turn_cost = rng.uniform(0, 1, capacity), rng.uniform(0, 1, capacity)
    valid = np.zeros(capacity, bool)
    valid[:count] = True

    def cost(labels):
        total = sum(unary[j, labels[j]] for j in range(count))
        return total + sum((same_cost if labels[j - 1] == labels[j] else turn_cost)[j] for j in range(count))

    labels = np.asarray(
        cyclic_binary_labels(jnp.asarray(unary), jnp.asarray(same_cost), jnp.asarray(turn_cost), jnp.asarray(valid))
    )
    best = min(cost(candidate) for candidate in itertools.product((0, 1), repeat=count))
    np.testing.assert_allclose(cost(labels[:count]), best, rtol=1e-6)


@pytest.mark.slow
@given(st.integers(0, 2**31 - 1))
@settings(max_examples=10)
def test_plan_lines_per_segment_match_one_line_each(seed):
    """Each segment's line is the principal axis of its own weighted points (numpy); other ids are dropped."""
    rng = np.random.default_rng(seed)
    points = jnp.asarray(rng.normal(size=(40, 2)) * [3.0, 0.5] + rng.normal(size=2), jnp.float32)
    weights = jnp.asarray(rng.uniform(0.0, 2.0, 40) * (rng.uniform(size=40) > 0.2), jnp.float32)
    segments = jnp.asarray(rng.integers(-1, 6, 40))  # 5 segments; -1 and 5 belong to none
    directions, distances = fit_plan_lines(points, weights, segments, 5)
    for s in range(5):
        w = np.where(np.asarray(segments) == s, np.asarray(weights, np.float64), 0.0)
        if np.sum(w > 0) < 3:
            continue  # no principal axis
        centroid = w @ np.asarray(points, np.float64) / w.sum()
        centred = np.asarray(points, np.float64) - centroid
        direction = np.linalg.eigh((w[:, None] * centred).T @ centred)[1][:, -1]
        distance = direction[0] * centroid[1] - direction[1] * centroid[0]
        sign = np.sign(np.dot(direction, directions[s]))
        np.testing.assert_allclose(sign * directions[s], direction, atol=2e-4)
        np.testing.assert_allclose(sign * distances[s], distance, atol=2e-3)


@pytest.mark.slow
@pytest.mark.parametrize("weights", [np.zeros(4), np.array([0.0, 1.0, 0.0, 0.0])])
def test_plan_line_without_spread_has_finite_gradients(weights):
    """An empty or one-point wall has no direction; its gradient must still be finite (no atan2(0, 0) NaN)."""
    points = jnp.asarray(np.random.default_rng(0).normal(size=(4, 2)))

    def line(p):
        direction, distance = fit_plan_line(p, jnp.asarray(weights))
        return jnp.sum(direction) + distance

    gradient = jax.grad(line)(points)
    assert bool(jnp.all(jnp.isfinite(gradient)))


OK, LOW, SCALE, FAILED = (ncjax.LayoutStatus[s] for s in ("OK", "LOW_CONFIDENCE", "UNCERTAIN_SCALE", "NO_CORNERS"))


@pytest.mark.parametrize(
    "manhattan_status, atlanta_status, manhattan_explained, atlanta_explained, in_frame, expected",
    [
        (OK, OK, 0.9, 0.8, False, True),  # explains more
        (OK, OK, 0.8, 0.9, True, False),  # explains less, even in a Manhattan frame
        (OK, OK, 1.0, 1.0, True, True),  # tie: the frame decides
        (OK, OK, 1.0, 1.0, False, False),
        (OK, FAILED, 0.1, 0.9, False, True),  # the other branch failed
        (FAILED, OK, 0.9, 0.1, True, False),
        (OK, LOW, 0.1, 0.9, False, True),  # a layout that is ok beats a flagged one
        (SCALE, OK, 0.9, 0.1, True, False),
        (LOW, FAILED, 0.1, 0.9, False, True),  # a flagged layout is still written: it beats a failure
        (FAILED, SCALE, 0.9, 0.1, True, False),
        (LOW, LOW, 0.5, 0.1, False, True),  # two flagged layouts compare as two ok ones
        (LOW, SCALE, 0.1, 0.5, True, False),
        (FAILED, FAILED, 0.9, 0.1, True, True),
    ],
)
def test_auto_world_choice(
    manhattan_status, atlanta_status, manhattan_explained, atlanta_explained, in_frame, expected
):
    chosen = choose_manhattan(
        (jnp.int32(manhattan_status), jnp.int32(atlanta_status)),
        (jnp.float32(manhattan_explained), jnp.float32(atlanta_explained)),
        jnp.array(in_frame),
    )
    assert bool(chosen) is expected


@pytest.mark.parametrize(
    "manhattan_explained, atlanta_explained, margin, expected",
    [
        (0.85, 0.9, 0.1, True),  # within the margin: the simpler model
        (0.7, 0.9, 0.1, False),  # the Atlanta layout explains clearly more
        (1.0, 1.0, 0.1, False),  # a tie: the frame decides (not in one here), whatever the margin
        (0.85, 0.9, 0.0, False),
    ],
)
def test_auto_world_choice_margin(manhattan_explained, atlanta_explained, margin, expected):
    chosen = choose_manhattan(
        (jnp.int32(OK), jnp.int32(OK)),
        (jnp.float32(manhattan_explained), jnp.float32(atlanta_explained)),
        jnp.array(False),
        margin,
    )
    assert bool(chosen) is expected


def test_every_status_has_a_reason():
    reasons = [status.reason for status in ncjax.LayoutStatus]
    assert all(reasons) and len(set(reasons)) == len(reasons)


# --- step 0: floor rows the ceiling contradicts ----------------------------------------------------------


@pytest.mark.slow
@settings(max_examples=15, deadline=None)
@given(st.integers(0, 5), st.integers(0, WIDTH - 1), st.integers(1, WIDTH // 3), st.floats(3.0, 10.0), st.booleans())
def test_floor_rows_the_ceiling_contradicts_are_replaced_by_the_true_rows(room_index, start, length, offset, upwards):
    """In every column tan(ceiling elevation) / tan(floor elevation) = h_c / h_f, so a block of floor rows moved
    (furniture hiding the floor-wall line) is found and put back where the ceiling rows say it is."""
    room, label = pick(rooms("atlanta", "none"), room_index)
    cam = room.camera(WIDTH, HEIGHT)
    block = (np.arange(WIDTH) - start) % WIDTH < length
    moved = np.where(block, label.floor_v + (-offset if upwards else offset), label.floor_v)
    floor_v, replaced = ceiling_consistent_floor(cam, label.ceiling_v, jnp.asarray(moved), 4.0)  # 2 px at 256 rows
    np.testing.assert_array_equal(np.asarray(replaced), block)
    np.testing.assert_allclose(np.asarray(floor_v), np.asarray(label.floor_v), atol=1e-2)


def test_floor_consistency_keeps_exact_and_missing_rows():
    room, label = pick(rooms("manhattan", "none"), 0)
    cam = room.camera(WIDTH, HEIGHT)
    floor_v, replaced = ceiling_consistent_floor(cam, label.ceiling_v, label.floor_v, 0.05)
    assert not np.any(np.asarray(replaced))
    ceiling_v = label.ceiling_v.at[:20].set(jnp.nan)  # no ceiling row: nothing to say about the floor's
    moved = label.floor_v.at[:20].add(-8.0).at[20:40].set(jnp.nan)
    floor_v, replaced = ceiling_consistent_floor(cam, ceiling_v, moved, 2.0)
    np.testing.assert_array_equal(np.asarray(floor_v[:20]), np.asarray(moved[:20]))
    assert np.all(np.isnan(np.asarray(floor_v[20:40]))) and not np.any(np.asarray(replaced))
    # rows all above the horizon (no floor seen): the ratio is positive and says nothing
    floor_v, replaced = ceiling_consistent_floor(cam, label.ceiling_v, jnp.full(WIDTH, HEIGHT / 4), 2.0)
    assert not np.any(np.asarray(replaced))
    below = label.ceiling_v.at[:10].set(HEIGHT * 0.9)  # ceiling outliers below the horizon
    floor_v, replaced = ceiling_consistent_floor(cam, below, label.floor_v, 2.0)
    assert not np.any(np.asarray(replaced))


@pytest.mark.slow
def test_floor_rows_hidden_by_furniture_do_not_bias_the_layout():
    """A block of floor rows 1.3 px too high (at 256 rows: within RANSAC's inlier cut) biases the layout; step 0
    puts them back for the walls' fits and keeps them out of the final adjustment."""
    batch, labels = rooms("manhattan", "none")
    room, label = pick(batch, 0), pick(labels, 0)
    cam = room.camera(WIDTH, HEIGHT)
    hidden = (np.arange(WIDTH) >= 100) & (np.arange(WIDTH) < 220)
    floor_v = jnp.where(hidden, label.floor_v - 1.3, label.floor_v)
    errors = {}
    for threshold in (math.inf, 2.0):
        config = ncjax.PipelineConfig().replace(floor_check={"threshold": threshold})
        layout = ncjax.layout_from_boundaries(
            label.ceiling_v, floor_v, label.corner_target, cam, world="manhattan", config=config
        )
        assert bool(layout.ok)
        errors[threshold] = metrics.evaluate_layout(layout, room)["ce"]
    assert errors[math.inf] > 3e-3 and errors[2.0] < 1e-4, errors  # measured: 8 mm and 1 um


def test_panorama_keys_split_one_key_or_keep_one_per_panorama():
    from ncjax.pipeline.batch import panorama_keys

    key = jax.random.key(7)
    split = jax.random.key_data(jax.random.split(key, 6))
    for key_in in (key, jax.random.PRNGKey(7)):  # typed or raw
        np.testing.assert_array_equal(jax.random.key_data(panorama_keys(key_in, (2, 3))), split)
    per_panorama = jax.random.split(jax.random.key(8), 6).reshape(2, 3)
    for key_in in (per_panorama, jax.random.key_data(per_panorama)):
        np.testing.assert_array_equal(
            jax.random.key_data(panorama_keys(key_in, (2, 3))), jax.random.key_data(per_panorama.reshape(-1))
        )
    np.testing.assert_array_equal(jax.random.key_data(panorama_keys(key, ())), jax.random.key_data(key))
    with pytest.raises(ValueError, match="one per panorama"):
        panorama_keys(jax.random.split(key, 2), (3,))
