"""The plan layout: walls read robustly off the floor rows' plan where a branch's layout is flagged LOW_CONFIDENCE."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_prior import HEIGHT, WIDTH, rooms

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.geometry.polygon import is_simple, point_in_polygon
from ncjax.geometry.reprojection import fit_plan_lines
from ncjax.io.export import branch_name
from ncjax.pipeline import run
from ncjax.pipeline.config import ChecksConfig, PipelineConfig, PlanConfig
from ncjax.pipeline.plan import plan_layout, robust_plan_lines, segment_medians
from ncjax.pipeline.prior import HeightPrior
from ncjax.pipeline.run import fit_walls
from ncjax.pipeline.types import Rows

POINTS = 240  # two walls of 120 points each, fixed so that the line fits compile once
CAPACITY = 4


def two_walls(displaced: float, offset: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points on the walls y = 2 (columns 0-119) and x = 3 (120-239) with 1 cm of noise; a ``displaced`` fraction of
    the first wall's points lies ``offset`` beyond it (a floor row run through a doorway to the next room's floor)."""
    rng = np.random.default_rng(seed)
    half = POINTS // 2
    first = np.stack([np.linspace(-2.5, 2.5, half), np.full(half, 2.0)], -1)
    second = np.stack([np.full(half, 3.0), np.linspace(-2.5, 1.5, half)], -1)
    points = np.concatenate([first, second]) + rng.normal(0.0, 0.01, (POINTS, 2))
    doorway = np.arange(int(0.2 * half), int(0.2 * half) + round(displaced * half))  # one stretch, as a doorway is
    points[doorway, 1] += offset
    column_wall = np.repeat(np.arange(2), half).astype(np.int32)
    return points.astype(np.float32), np.ones(POINTS, bool), column_wall


@jax.jit
def fitted_lines(points, counted, column_wall):
    return robust_plan_lines(points, counted, column_wall, CAPACITY, PlanConfig())


def line_distance(directions, distances, wall: int, point: tuple[float, float]) -> float:
    """Distance of a point from wall ``wall``'s line."""
    d = np.asarray(directions)[wall]
    return abs(d[0] * point[1] - d[1] * point[0] - float(distances[wall]))


@given(st.floats(0.0, 0.4), st.floats(0.5, 2.0), st.integers(0, 2**31 - 1))
def test_robust_lines_stay_on_the_wall_past_a_doorway(displaced, offset, seed):
    points, counted, column_wall = two_walls(displaced, offset, seed)
    directions, distances, counts = fitted_lines(jnp.asarray(points), jnp.asarray(counted), jnp.asarray(column_wall))
    np.testing.assert_array_equal(counts, [POINTS // 2, POINTS // 2, 0, 0])
    # both walls' lines pass within 1 cm of the walls' points (0, 2), (2, 2) and (3, 0), (3, 1)
    for wall, on_it in ((0, [(0.0, 2.0), (2.0, 2.0)]), (1, [(3.0, 0.0), (3.0, 1.0)])):
        for point in on_it:
            assert line_distance(directions, distances, wall, point) < 0.01


def test_plain_least_squares_follow_the_doorway():
    """The same points' total-least-squares line, the robust fit's start, leaves the wall: the reweighting matters."""
    points, counted, column_wall = two_walls(0.3, 1.0, 0)
    directions, distances = fit_plan_lines(jnp.asarray(points), jnp.ones(POINTS), jnp.asarray(column_wall), CAPACITY)
    assert line_distance(directions, distances, 0, (0.0, 2.0)) > 0.1


def test_plan_config_rejects_bad_values():
    with pytest.raises(ValueError, match="iterations"):
        PlanConfig(iterations=0)
    with pytest.raises(ValueError, match="samples"):
        PlanConfig(samples=1)
    with pytest.raises(ValueError, match="min_turn"):
        PlanConfig(min_turn=0.0)


@pytest.mark.slow
@pytest.mark.parametrize("rc", [0.0, 0.05])
def test_the_plan_layout_of_exact_rows_is_the_room(rc):
    """On a room's exact rows the plan layout is the room, central (a camera-height prior's virtual rig) or not."""
    batch, labels = rooms("manhattan", (rc, rc), 4)
    config = PipelineConfig()
    for index in range(4):
        room, label = jax.tree.map(lambda x, i=index: x[i], (batch, labels))
        cam = room.camera(WIDTH, HEIGHT)
        rows = Rows(label.ceiling_v, label.floor_v, label.corner_target)
        prior = HeightPrior("camera_height", -room.floor_height) if rc == 0 else None
        walls = fit_walls(rows, cam, prior, jax.random.key(0), config, "atlanta")
        heights = walls.prior_heights if prior is not None else jnp.stack([room.ceiling_height, room.floor_height])
        layout = plan_layout(walls.evidence, heights, jnp.zeros((2, 2)), config)
        assert int(layout.status) == ncjax.LayoutStatus.OK
        assert metrics.iou_3d(layout, room) > 0.99


@pytest.mark.slow
def test_a_low_confidence_layout_is_replaced_by_the_plan_layout():
    """Rows that leave one wall through a doorway: with every layout that leaves a row unexplained flagged, the plan
    layout (no corner covariance) replaces the branch's and holds the room; unflagged, nothing changes."""
    batch, labels = rooms("manhattan", (0.0, 0.0), 4)
    room, label = jax.tree.map(lambda x: x[0], (batch, labels))
    cam = room.camera(WIDTH, HEIGHT)
    floor_v = np.asarray(label.floor_v).copy()
    doorway = slice(WIDTH // 8, WIDTH // 8 + WIDTH // 32)
    floor_v[doorway] -= 6.0  # the next room's floor line, nearer the horizon
    rows = (label.ceiling_v, jnp.asarray(floor_v), label.corner_target)
    prior = HeightPrior("camera_height", -room.floor_height)

    def layout(fallback, min_explained_fraction):
        config = PipelineConfig(
            plan=PlanConfig(fallback=fallback), checks=ChecksConfig(min_explained_fraction=min_explained_fraction)
        )
        return ncjax.layout_from_boundaries(*rows, cam, "auto", config, prior=prior)

    flagged = layout(False, 1.0)
    replaced = layout(True, 1.0)
    assert int(flagged.status) == ncjax.LayoutStatus.LOW_CONFIDENCE
    assert np.all(np.isfinite(np.asarray(flagged.corner_covariance)[np.asarray(flagged.mask)]))
    assert np.all(np.isinf(np.asarray(replaced.corner_covariance)[np.asarray(replaced.mask)]))
    assert branch_name(flagged) != "plan" and branch_name(replaced) == "plan"
    assert metrics.iou_3d(replaced, room) > 0.97
    unflagged = [layout(fallback, 0.0) for fallback in (False, True)]
    jax.tree.map(np.testing.assert_array_equal, *unflagged)


@given(st.floats(0.5, 5.0), st.floats(0.5, 5.0), st.integers(0, 3))
def test_a_rectangle_is_simple_and_its_bow_tie_is_not(width, depth, start):
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, depth], [0.0, depth]])
    corners = np.roll(corners, start, axis=0)
    junk = np.array([[-7.0, 0.3 * depth], [9.0, 0.6 * depth], [2.0, -3.0]])  # empty slots' edges would cross
    padded = jnp.asarray(np.concatenate([corners, junk]), jnp.float32)
    mask = jnp.array([True] * 4 + [False] * 3)
    assert bool(is_simple(padded, mask))
    bow_tie = padded.at[jnp.array([1, 2])].set(padded[jnp.array([2, 1])])
    assert not bool(is_simple(bow_tie, mask))


@given(st.floats(0.5, 5.0), st.floats(0.5, 5.0), st.floats(0.01, 0.99), st.floats(0.01, 0.99), st.integers(0, 3))
def test_a_rectangle_holds_its_inner_points_and_not_those_beyond_a_wall(width, depth, u, v, start):
    corners = np.roll(np.array([[0.0, 0.0], [width, 0.0], [width, depth], [0.0, depth]]), start, axis=0)
    # empty slots hold whatever they hold: these edges would cross the test points' lines if they counted
    junk = np.array([[-7.0, 0.3 * depth], [9.0, 0.6 * depth], [2.0, -3.0]])
    padded = jnp.asarray(np.concatenate([corners, junk]), jnp.float32)
    mask = jnp.array([True] * 4 + [False] * 3)
    assert bool(point_in_polygon(jnp.array([u * width, v * depth]), padded, mask))
    for outside in ([-u, v * depth], [width + u, v * depth], [u * width, -v], [u * width, depth + v]):
        assert not bool(point_in_polygon(jnp.array(outside, jnp.float32), padded, mask))


@pytest.mark.slow
def test_a_plan_layout_that_leaves_the_camera_outside_is_not_used(monkeypatch):
    """The doorway's rows of test_a_low_confidence_layout_is_replaced_by_the_plan_layout, with the plan layout moved
    10 m along x (still a simple polygon, its corners far from the rig): the camera would stand outside the room, so
    the flagged layout stays."""
    batch, labels = rooms("manhattan", (0.0, 0.0), 4)
    room, label = jax.tree.map(lambda x: x[0], (batch, labels))
    floor_v = np.asarray(label.floor_v).copy()
    floor_v[WIDTH // 8 : WIDTH // 8 + WIDTH // 32] -= 6.0
    shift = jnp.array([10.0, 0.0, 0.0])

    def moved_plan(*args):
        plan = plan_layout(*args)
        corners = (plan.ceiling_corners + shift, plan.floor_corners + shift)
        return eqx.tree_at(lambda layout: (layout.ceiling_corners, layout.floor_corners), plan, corners)

    monkeypatch.setattr(run, "plan_layout", moved_plan)
    config = PipelineConfig(plan=PlanConfig(fallback=True), checks=ChecksConfig(min_explained_fraction=1.0))
    prior = HeightPrior("camera_height", -room.floor_height)
    rows = (label.ceiling_v, jnp.asarray(floor_v), label.corner_target)
    jax.clear_caches()  # a cached trace would call the original
    try:
        layout = ncjax.layout_from_boundaries(*rows, room.camera(WIDTH, HEIGHT), "auto", config, prior=prior)
    finally:
        jax.clear_caches()  # and a later test must not get this one's
    assert int(layout.status) == ncjax.LayoutStatus.LOW_CONFIDENCE and branch_name(layout) != "plan"


@pytest.mark.slow
def test_the_fallback_leaves_the_gradients_of_a_layout_it_does_not_replace():
    """The plan layout carries no gradient: where it is not chosen the layout's gradient is the branches' alone."""
    batch, labels = rooms("manhattan", (0.05, 0.05), 2)
    room, label = jax.tree.map(lambda x: x[1], (batch, labels))
    cam = room.camera(WIDTH, HEIGHT)
    prior = HeightPrior("camera_height", 1.5)

    def gradient(fallback):
        config = PipelineConfig(plan=PlanConfig(fallback=fallback))

        def spread(floor_v):
            layout = ncjax.layout_from_boundaries(
                label.ceiling_v, floor_v, label.corner_target, cam, "auto", config, prior=prior
            )
            return jnp.sum(layout.floor_corners[..., :2] ** 2)

        return jax.grad(spread)(label.floor_v + 0.3)

    with_fallback = gradient(True)
    assert bool(jnp.all(jnp.isfinite(with_fallback))) and float(jnp.abs(with_fallback).sum()) > 0
    np.testing.assert_allclose(with_fallback, gradient(False), rtol=1e-5, atol=1e-6)


@given(st.lists(st.tuples(st.integers(-1, 4), st.floats(-5.0, 5.0, width=32)), min_size=12, max_size=12))
def test_segment_medians_are_numpys(pairs):
    segments = np.array([segment for segment, _ in pairs], np.int32)
    values = np.array([value for _, value in pairs], np.float32)
    medians = np.asarray(segment_medians_of_twelve(jnp.asarray(values), jnp.asarray(segments)))
    for segment in range(4):
        inside = values[segments == segment]
        expected = np.median(inside) if len(inside) else np.nan
        np.testing.assert_allclose(medians[segment], expected, rtol=1e-6, atol=1e-6)


@jax.jit
def segment_medians_of_twelve(values, segments):
    return segment_medians(values, segments, 4)  # segment 4 (and -1): no segment
