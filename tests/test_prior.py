"""Scale from a height prior: central panoramas (rc = 0) and radii too small to fix the scale."""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_export import L_SHAPE, make_layout

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.pipeline.floor_check import ceiling_floor_ratio
from ncjax.pipeline.prior import (
    PRIOR_KINDS,
    PRIOR_RELATIVE_SIGMA,
    HeightPrior,
    prior_heights,
    prior_quantity,
    rescale_to_prior,
    scale_conflict,
    scale_layout,
    virtual_rows,
)

WIDTH, HEIGHT = 512, 256


@functools.cache
def rooms(world: str, rc_range: tuple[float, float], count: int = 4):
    config = ncjax.RoomConfig(
        world=world, rc_range=rc_range, occlusion="none", max_walls=8, room_tries=2, camera_tries=64
    )
    batch = jax.jit(jax.vmap(lambda k: ncjax.synth.random_room(k, config)))(jax.random.split(jax.random.key(3), count))
    labels = jax.jit(jax.vmap(lambda r: ncjax.synth.room_labels(r, r.camera(WIDTH, HEIGHT))))(batch)
    return batch, labels


@settings(max_examples=30, deadline=None)
@given(st.floats(0.3, 3.0), st.floats(-2.5, -0.3), st.sampled_from(PRIOR_KINDS))
def test_prior_heights_keep_the_ratio_and_the_stated_height(ceiling, floor, kind):
    truth = prior_quantity(kind, ceiling, floor)
    h_c, h_f = prior_heights(jnp.asarray(ceiling / floor), HeightPrior(kind, truth))
    np.testing.assert_allclose([h_c, h_f], [ceiling, floor], rtol=1e-5)


@pytest.mark.parametrize("value", [0.0, -1.6, float("nan"), float("inf")])
def test_a_height_prior_must_be_a_positive_height(value):
    with pytest.raises(ValueError, match="camera height must be a finite height > 0"):
        HeightPrior("camera_height", value)
    with pytest.raises(ValueError, match="height prior must be one of"):
        HeightPrior("eye_height", 1.6)


@pytest.mark.slow
@pytest.mark.parametrize("rc", [0.0, 0.05])
def test_ratio_and_virtual_rows_are_exact_on_a_room(rc):
    """The median ratio is the room's h_c / h_f, and the virtual rig sees the room's boundaries at its rows."""
    room, labels = rooms("manhattan", (rc, rc), 1)
    room, labels = jax.tree.map(lambda x: x[0], (room, labels))
    cam = room.camera(WIDTH, HEIGHT)
    ratio = ceiling_floor_ratio(cam, labels.ceiling_v, labels.floor_v)
    np.testing.assert_allclose(ratio, room.ceiling_height / room.floor_height, rtol=1e-4)
    virtual, ceiling_v, floor_v = virtual_rows(
        cam, labels.ceiling_v, labels.floor_v, room.ceiling_height, room.floor_height
    )
    assert float(virtual.rc) > 0.1
    truth = ncjax.synth.room_labels(room, virtual)
    seen = np.isfinite(ceiling_v) & np.isfinite(floor_v)
    assert seen.mean() > 0.9
    np.testing.assert_allclose(ceiling_v[seen], truth.ceiling_v[seen], atol=2e-2)
    np.testing.assert_allclose(floor_v[seen], truth.floor_v[seen], atol=2e-2)


def test_scale_layout_scales_lengths_and_covariances():
    layout = make_layout(L_SHAPE)
    layout = dataclasses.replace(layout, corner_covariance=jnp.ones_like(layout.corner_covariance))
    scaled = scale_layout(layout, 2.0)
    np.testing.assert_allclose(scaled.floor_corners, 2 * layout.floor_corners, rtol=1e-6)
    np.testing.assert_allclose(scaled.corner_covariance, 4 * layout.corner_covariance, rtol=1e-6)
    np.testing.assert_allclose(scaled.floor_lines[..., :3], layout.floor_lines[..., :3])
    # the scaled lines are the scaled room's: a line through the corner p along u has the moment p x u
    mask = np.asarray(layout.mask)
    corners = np.asarray(scaled.floor_corners)[mask]
    lines = np.asarray(scaled.floor_lines)[mask]
    np.testing.assert_allclose(np.cross(corners, lines[:, :3]), lines[:, 3:], atol=1e-4)
    again = rescale_to_prior(scaled, HeightPrior("camera_height", float(-layout.floor_height)))
    np.testing.assert_allclose(again.floor_corners, layout.floor_corners, rtol=1e-5, atol=1e-6)


def with_heights(layout, ceiling, floor, covariance, status=ncjax.LayoutStatus.OK):
    return dataclasses.replace(
        layout,
        ceiling_height=jnp.float32(ceiling),
        floor_height=jnp.float32(floor),
        height_covariance=jnp.asarray(covariance, jnp.float32),
        status=jnp.int32(status),
        ok=jnp.asarray(status == ncjax.LayoutStatus.OK),
    )


def heights_covariance(sigma_c: float, sigma_f: float, rho: float) -> np.ndarray:
    """The (h_c, h_f) covariance of those standard deviations and correlation."""
    return np.array([[sigma_c**2, rho * sigma_c * sigma_f], [rho * sigma_c * sigma_f, sigma_f**2]])


def quantity_gradient(kind: str, ceiling: float, floor: float, step: float = 1e-6) -> np.ndarray:
    """The gradient of the prior's quantity in (h_c, h_f), by central differences."""
    return np.array(
        [
            prior_quantity(kind, ceiling + step, floor) - prior_quantity(kind, ceiling - step, floor),
            prior_quantity(kind, ceiling, floor + step) - prior_quantity(kind, ceiling, floor - step),
        ]
    ) / (2 * step)


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.3, 3.0),
    st.floats(-2.5, -0.3),
    st.sampled_from(PRIOR_KINDS),
    st.floats(0.3, 5.0),
    st.floats(0.001, 1.0),
    st.floats(0.001, 1.0),
    st.floats(-0.9, 0.9),
)
def test_scale_conflict_is_the_log_distance_over_both_spreads(ceiling, floor, kind, value, sigma_c, sigma_f, rho):
    covariance = heights_covariance(sigma_c, sigma_f, rho)
    geometry = with_heights(make_layout(L_SHAPE), ceiling, floor, covariance)
    measured = prior_quantity(kind, ceiling, floor)
    gradient = quantity_gradient(kind, ceiling, floor)
    spread = np.sqrt(gradient @ covariance @ gradient / measured**2 + PRIOR_RELATIVE_SIGMA**2)
    expected = abs(np.log(measured / value)) / spread
    np.testing.assert_allclose(scale_conflict(geometry, HeightPrior(kind, value)), expected, rtol=1e-4, atol=1e-5)


def test_no_measured_height_is_no_conflict():
    layout = make_layout(L_SHAPE)
    free = with_heights(layout, 0.3, -0.25, np.full((2, 2), np.inf))
    unknown = with_heights(layout, 0.3, -0.25, np.full((2, 2), np.nan))
    below = with_heights(layout, -0.5, -1.0, np.eye(2) * 1e-4)  # a "ceiling" below the camera: no room height
    assert float(scale_conflict(free, HeightPrior("camera_height", 1.6))) == 0.0
    assert float(scale_conflict(unknown, HeightPrior("camera_height", 1.6))) == 0.0
    assert float(scale_conflict(below, HeightPrior("ceiling_height", 1.0))) == 0.0


def test_a_fallback_layout_is_flagged_where_the_geometry_confidently_measured_another_room():
    """The prior's layout is flagged only where it replaced an UNCERTAIN_SCALE geometry of a non-central
    panorama that measured a height many sigmas from the prior's (a 0.25 m camera against 1.6 m)."""
    from ncjax.pipeline.prior import flag_scale_conflicts

    layout = make_layout(L_SHAPE)
    low = with_heights(layout, 0.3, -0.25, np.diag([0.01, 0.01]), ncjax.LayoutStatus.UNCERTAIN_SCALE)
    near = with_heights(layout, 1.2, -1.4, np.diag([0.04, 0.04]), ncjax.LayoutStatus.UNCERTAIN_SCALE)
    failed = dataclasses.replace(low, status=jnp.int32(ncjax.LayoutStatus.SOLVER_FAILED))
    central = dataclasses.replace(low, status=jnp.int32(ncjax.LayoutStatus.NO_SCALE))  # rc = 0: the prior's anyway
    geometry = jax.tree.map(lambda *x: jnp.stack(x), low, near, failed, central, low)
    good = with_heights(layout, 1.9, -1.6, np.eye(2) * 0.01)
    unsure = with_heights(layout, 1.9, -1.6, np.eye(2) * 0.01, ncjax.LayoutStatus.LOW_CONFIDENCE)
    written = jax.tree.map(lambda *x: jnp.stack(x), good, good, good, good, unsure)
    prior = HeightPrior("camera_height", 1.6)  # one value for the batch
    assert float(scale_conflict(low, prior)) > 4
    assert float(scale_conflict(near, prior)) < 1
    flagged = flag_scale_conflicts(written, geometry, prior, 3.0)
    conflict, low_confidence = ncjax.LayoutStatus.SCALE_CONFLICT, ncjax.LayoutStatus.LOW_CONFIDENCE
    np.testing.assert_array_equal(flagged.status, [conflict, 0, 0, 0, low_confidence])
    np.testing.assert_array_equal(flagged.ok, [False, True, True, True, False])
    np.testing.assert_array_equal(flagged.floor_corners, written.floor_corners)
    off = flag_scale_conflicts(written, geometry, prior, np.inf)
    np.testing.assert_array_equal(off.status, written.status)


@pytest.mark.extended  # the central mode's end to end run in the default tier is test_app.py's
@pytest.mark.parametrize("world", ["manhattan", "atlanta"])
def test_central_rooms_from_exact_rows_and_the_true_camera_height(world):
    """rc = 0 and rc = 2-5 cm, one compiled program: the layout is the room, its floor at the prior's height.

    Rooms without occlusions: the prior changes only the scale's source, the pipeline's occlusion
    handling is the non-central one's (experiments/central_table.py measures occluded rooms).
    """
    for rc_range in ((0.0, 0.0), (0.02, 0.05)):
        batch, labels = rooms(world, rc_range)
        cams = jax.vmap(lambda r: r.camera(WIDTH, HEIGHT))(batch)
        camera = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=cams.rc)
        prior = HeightPrior("camera_height", -batch.floor_height)
        layouts = ncjax.layout_from_boundaries(
            labels.ceiling_v, labels.floor_v, labels.corner_target, camera, world=world, prior=prior
        )
        truth = batch if world == "manhattan" else labels
        for i in range(batch.rc.shape[0]):
            layout = jax.tree.map(lambda x: np.asarray(x[i]), layouts)
            assert layout.ok, ncjax.LayoutStatus(int(layout.status)).reason
            np.testing.assert_allclose(layout.floor_height, batch.floor_height[i], rtol=1e-5)
            scores = metrics.evaluate_layout(layout, jax.tree.map(lambda x: np.asarray(x[i]), truth))
            assert scores["iou3d"] > 0.99, (rc_range, i, scores)


@pytest.mark.slow
def test_the_prior_replaces_the_scale_only_where_the_geometry_cannot_fix_it(tmp_path):
    """rc 2-5 cm: the geometry's layout stays unless its status is one of SCALE_FAILURES, then the prior's replaces it,
    the same through saved programs (the CLI's route), and flagged SCALE_CONFLICT after an UNCERTAIN_SCALE geometry
    whose height is too far from the prior's.

    The geometry's layouts stand in as the prior's scaled by 1.1 (what a geometry with a wrong scale would give),
    with the status the scale test gave: one compiled pipeline, the prior's.
    """
    from ncjax.reconstruction import (
        GEOMETRY,
        PRIOR_FALLBACK,
        SCALE_FAILURES,
        _Chunk,
        _chunk_layouts,
        _geometry,
        _Route,
        _SavedGeometry,
        _scale_sources,
    )

    batch, labels = rooms("manhattan", (0.02, 0.05))
    rc = np.asarray(batch.rc, np.float32)
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=jnp.asarray(rc))
    prior = HeightPrior("camera_height", -batch.floor_height)
    key = jax.random.key(0)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)
    config = ncjax.PipelineConfig()
    from_prior = ncjax.layout_from_boundaries(*rows, cam, "manhattan", config, key=key, prior=prior)
    assert np.all(np.asarray(from_prior.ok))
    # One key per panorama: the keys one key is split into give the same layouts.
    keys = jax.random.split(key, rc.shape[0])
    per_panorama = ncjax.layout_from_boundaries(*rows, cam, "manhattan", config, key=keys, prior=prior)
    np.testing.assert_array_equal(per_panorama.floor_corners, from_prior.floor_corners)
    np.testing.assert_allclose(from_prior.floor_height, batch.floor_height, rtol=1e-5)
    host_rows = jax.tree.map(lambda x: np.asarray(x, np.float32), ncjax.Rows(*(jnp.asarray(x) for x in rows)))
    chunk = _Chunk(rc, np.asarray(jax.random.key_data(keys)), np.asarray(prior.value, np.float32))
    for status, expected in [(ncjax.LayoutStatus.OK, GEOMETRY)] + [(s, PRIOR_FALLBACK) for s in SCALE_FAILURES]:
        measured = dataclasses.replace(scale_layout(from_prior, 1.1), status=jnp.full(rc.shape, int(status)))

        def stand_in(rows, chunk, kind, measured=measured):
            return from_prior if kind else measured

        prior_settings = ("camera_height", config.prior.max_scale_conflict)
        layout, own = _chunk_layouts(host_rows, chunk, stand_in, "fallback", prior_settings)
        assert np.all(_scale_sources("fallback", rc, own) == expected), status
        np.testing.assert_array_equal(own.floor_corners, measured.floor_corners)
        chosen = from_prior if expected == PRIOR_FALLBACK else measured
        np.testing.assert_allclose(layout.floor_corners, chosen.floor_corners, atol=1e-6)
        np.testing.assert_array_equal(layout.status, chosen.status)
    # The geometry 1.1 times too large: log(1.1) / 0.15 = 0.64 sigmas from the prior (exact rows: a tiny covariance).
    measured = dataclasses.replace(
        scale_layout(from_prior, 1.1), status=jnp.full(rc.shape, int(ncjax.LayoutStatus.UNCERTAIN_SCALE))
    )
    np.testing.assert_allclose(jax.vmap(scale_conflict)(measured, prior), np.log(1.1) / PRIOR_RELATIVE_SIGMA, rtol=0.02)
    strict = config.replace(prior={"max_scale_conflict": 0.5})
    route = _Route(HEIGHT, str(jax.random.key_impl(keys)), "manhattan", None)
    saved_geometry = _SavedGeometry(tmp_path, (len(rc), WIDTH), strict, route)

    def jitted(rows, chunk, kind):  # the prior's route of the pipeline; the geometry's stands in as measured
        return _geometry(rows, chunk, strict, route._replace(prior_kind=kind)) if kind else measured

    def saved(rows, chunk, kind):  # the same through the saved programs (the CLI's and the API's default)
        return saved_geometry(rows, chunk, kind) if kind else measured

    from_jitted, _ = _chunk_layouts(host_rows, chunk, jitted, "fallback", ("camera_height", 0.5))
    from_saved, _ = _chunk_layouts(host_rows, chunk, saved, "fallback", ("camera_height", 0.5))
    assert np.all(from_jitted.status == ncjax.LayoutStatus.SCALE_CONFLICT)
    np.testing.assert_array_equal(from_saved.status, from_jitted.status)
    # one run with all the slots here, a compact run first in layout_from_boundaries: the same to 1e-4
    np.testing.assert_allclose(from_saved.floor_corners, from_prior.floor_corners, atol=1e-4)
    np.testing.assert_allclose(from_jitted.floor_corners, from_prior.floor_corners, atol=1e-4)


@pytest.mark.slow
def test_the_size_limits_apply_at_the_scale_of_the_prior():
    """``prior_room_height`` (set by the prior's route, whose virtual rig solves at an arbitrary scale): the room
    height and corner distance limits judge the layout scaled to it, not at its own scale."""
    batch, labels = rooms("manhattan", (0.3, 1.0))
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=batch.rc)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)
    lowest = float(np.min(np.asarray(batch.ceiling_height - batch.floor_height)))

    def statuses(prior_room_height, max_room_height=1e6):
        config = ncjax.PipelineConfig().replace(
            checks={"max_room_height": max_room_height}, prior={"room_height": prior_room_height}
        )
        return np.asarray(ncjax.layout_from_boundaries(*rows, cam, "manhattan", config).status)

    # at its own scale every room is too tall for this limit; at half the lowest one's height none is
    assert np.all(statuses(0.0, 0.6 * lowest) == ncjax.LayoutStatus.DEGENERATE_LAYOUT)
    assert np.all(statuses(0.5 * lowest, 0.6 * lowest) == ncjax.LayoutStatus.OK)
    # within max_corner_distance (50 m) at its own scale, a thousand times beyond it at the prior's
    assert np.all(statuses(0.0) == ncjax.LayoutStatus.OK)
    assert np.all(statuses(1000.0 * lowest) == ncjax.LayoutStatus.DEGENERATE_LAYOUT)


@pytest.mark.slow
def test_the_prior_route_judges_the_size_limits_at_the_prior_scale():
    """rc 2-5 cm with a camera-height prior: a room height limit just under the rooms' fails every layout,
    just over the tallest passes them (the layout scaled to the prior: exact rows, the true heights)."""
    batch, labels = rooms("manhattan", (0.02, 0.05))
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=batch.rc)
    prior = HeightPrior("camera_height", -batch.floor_height)
    room_height = np.asarray(batch.ceiling_height - batch.floor_height)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)

    def statuses(max_room_height):
        config = ncjax.PipelineConfig().replace(checks={"max_room_height": max_room_height})
        return np.asarray(ncjax.layout_from_boundaries(*rows, cam, "manhattan", config, prior=prior).status)

    assert np.all(statuses(0.99 * float(np.min(room_height))) == ncjax.LayoutStatus.DEGENERATE_LAYOUT)
    assert np.all(statuses(1.01 * float(np.max(room_height))) == ncjax.LayoutStatus.OK)


@pytest.mark.slow
def test_a_ceiling_or_floor_at_the_camera_is_implausible():
    """Exact rows: a clearance just over each room's nearer surface (ceiling or floor, as a fraction of its height)
    fails it with DEGENERATE_LAYOUT, just under it passes (a run-away adjustment's ceiling at the camera)."""
    batch, labels = rooms("manhattan", (0.0, 0.0))
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=batch.rc)
    prior = HeightPrior("camera_height", -batch.floor_height)
    room_height = batch.ceiling_height - batch.floor_height
    nearer = np.asarray(jnp.minimum(batch.ceiling_height, -batch.floor_height) / room_height)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)

    def statuses(fraction):
        config = ncjax.PipelineConfig().replace(checks={"min_height_fraction": fraction})
        return np.asarray(ncjax.layout_from_boundaries(*rows, cam, "manhattan", config, prior=prior).status)

    # (a camera half-way up fails any valid fraction: those stop below 0.5)
    assert np.all(statuses(min(1.01 * float(np.max(nearer)), 0.499)) == ncjax.LayoutStatus.DEGENERATE_LAYOUT)
    assert np.all(statuses(0.99 * float(np.min(nearer))) == ncjax.LayoutStatus.OK)


@pytest.mark.slow
def test_a_corner_beyond_what_the_rows_see_is_implausible():
    """Exact rows, rc 0 and a camera-height prior: every wall is seen, so a room's farthest corner lies at least
    as far as any of its rows' boundary points; a limit just under that fails every layout with
    DEGENERATE_LAYOUT, the network's (3 times the rows' 95th percentile) passes them all."""
    batch, labels = rooms("manhattan", (0.0, 0.0))
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=batch.rc)
    prior = HeightPrior("camera_height", -batch.floor_height)
    rows = (labels.ceiling_v, labels.floor_v, labels.corner_target)

    def statuses(ratio):
        config = ncjax.PipelineConfig().replace(checks={"max_corner_range_ratio": ratio})
        return np.asarray(ncjax.layout_from_boundaries(*rows, cam, "manhattan", config, prior=prior).status)

    assert np.all(statuses(0.99) == ncjax.LayoutStatus.DEGENERATE_LAYOUT)
    assert np.all(statuses(3.0) == ncjax.LayoutStatus.OK)


@pytest.mark.slow
@pytest.mark.parametrize("rc", [0.0, 0.3])
def test_seen_range_is_the_rows_ranges_95th_percentile(rc):
    """The rows' boundary points at the room's heights, their ranges from the axis by the pixel maps of
    docs/design.md in numpy (rc + h / tan(elevation)), over the usable columns: the same 95th percentile."""
    from ncjax.pipeline.assemble import seen_range
    from ncjax.pipeline.run import fit_walls
    from ncjax.pipeline.types import Rows

    room, labels = (jax.tree.map(lambda x: x[0], tree) for tree in rooms("manhattan", (rc, rc)))
    cam = room.camera(WIDTH, HEIGHT)
    rows = Rows(labels.ceiling_v, labels.floor_v, labels.corner_target)
    prior = HeightPrior("camera_height", -room.floor_height) if rc == 0 else None
    evidence = fit_walls(rows, cam, prior, jax.random.key(0), ncjax.PipelineConfig(), "manhattan").evidence
    # the prior's route runs on its virtual rig, whose rows see the same points from a larger circle
    cam, usable = evidence.cam, np.asarray(evidence.usable)
    heights = (float(room.ceiling_height), float(room.floor_height))
    ranges = [
        float(cam.rc) + height / np.tan(np.pi / 2 - np.pi * (np.asarray(row, np.float64)[usable] + 0.5) / HEIGHT)
        for row, height in zip((evidence.rows.ceiling, evidence.rows.floor), heights, strict=True)
    ]
    expected = np.quantile(np.concatenate(ranges), 0.95)
    np.testing.assert_allclose(seen_range(evidence, *heights), expected, rtol=1e-4)


@pytest.mark.slow
def test_a_prior_s_walls_reach_the_adjustment_at_its_room_height_with_their_shape():
    """Noisy rows leave the virtual rig's solve at some scale; the walls the adjustment starts from are at the
    prior's room height, their shape (directions, distance ratios, height ratio) kept."""
    from ncjax.pipeline.prior import prior_rows
    from ncjax.pipeline.run import _fit_walls_of_rows, fit_walls, prior_config
    from ncjax.pipeline.types import Rows

    room, labels = (jax.tree.map(lambda x: x[0], tree) for tree in rooms("manhattan", (0.0, 0.0)))
    cam = room.camera(WIDTH, HEIGHT)
    key = jax.random.key(0)
    noise = 2.0 * jax.random.normal(jax.random.key(1), (2, WIDTH))
    ceiling_v, floor_v = labels.ceiling_v + noise[0], labels.floor_v + noise[1]
    prior = HeightPrior("camera_height", 1.6)
    config = ncjax.NETWORK_PIPELINE_CONFIG
    virtual, ceiling_virtual, floor_virtual, heights = prior_rows(cam, ceiling_v, floor_v, prior)
    room_height = heights[0] - heights[1]
    virtual_rows = Rows(ceiling_virtual, floor_virtual, labels.corner_target)
    solved = _fit_walls_of_rows(virtual_rows, virtual, key, prior_config(config, room_height), "auto", heights).branches
    rows = Rows(ceiling_v, floor_v, labels.corner_target)
    started = fit_walls(rows, cam, prior, key, config, "auto").branches
    np.testing.assert_allclose(started.ceiling_height - started.floor_height, room_height, rtol=1e-5)
    factor = (started.ceiling_height - started.floor_height) / (solved.ceiling_height - solved.floor_height)
    np.testing.assert_allclose(started.distances, solved.distances * factor[:, None], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(started.floor_height, solved.floor_height * factor, rtol=1e-5)
    np.testing.assert_array_equal(started.directions, solved.directions)


@settings(max_examples=20, deadline=None)
@given(
    st.floats(0.5, 2.0),
    st.floats(-2.0, -0.5),
    st.sampled_from(PRIOR_KINDS),
    st.floats(0.01, 0.2),
    st.floats(0.01, 0.2),
    st.floats(-0.9, 0.9),
)
def test_rescaled_heights_covariance_is_that_of_the_heights_given_the_prior(
    ceiling, floor, kind, sigma_c, sigma_f, rho
):
    covariance = heights_covariance(sigma_c, sigma_f, rho)
    layout = with_heights(make_layout(L_SHAPE), ceiling, floor, covariance)
    prior = HeightPrior(kind, 1.7)
    rescaled = rescale_to_prior(layout, prior)
    result = np.asarray(rescaled.height_covariance, np.float64)
    # draws of the heights, each rescaled to the prior: their covariance to first order (small sigmas)
    rng = np.random.default_rng(0)
    draws = rng.multivariate_normal([ceiling, floor], covariance * 1e-4, size=20000)
    quantity = np.array([prior_quantity(kind, c, f) for c, f in draws])
    scaled = draws * (1.7 / quantity)[:, None]
    np.testing.assert_allclose(result * 1e-4, np.cov(scaled.T), rtol=0.1, atol=1e-9)
    # the height the prior states has no variance
    gradient = quantity_gradient(kind, ceiling, floor)
    assert gradient @ result @ gradient < 1e-6 * max(np.abs(result).max(), 1e-12) + 1e-10
