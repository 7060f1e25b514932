"""Synthetic rooms and their exact labels: hand-computed box room, invariants on random rooms."""

import dataclasses
import functools
import math
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ncjax
from ncjax.geometry.polygon import polygon_area
from ncjax.synth.rooms import distance_to_walls, ray_hits

W, H = 256, 128


def _box_room(half=2.0, h_c=1.0, h_f=-1.5, rc=0.5, capacity=8):
    corners = (
        jnp.zeros((capacity, 2)).at[:4].set(jnp.array([[half, -half], [half, half], [-half, half], [-half, -half]]))
    )
    return ncjax.synth.Room(
        corners=corners,
        mask=jnp.arange(capacity) < 4,
        ceiling_height=jnp.array(h_c),
        floor_height=jnp.array(h_f),
        rc=jnp.array(rc),
        camera_position=jnp.array([0.0, 0.0, -h_f]),
        is_atlanta=jnp.array(False),
        status=jnp.array(0, jnp.int32),
    )


@pytest.mark.slow
def test_box_room_labels_by_hand(x64):
    room = _box_room()
    cam = ncjax.NonCentralPanorama(width=W, height=H, rc=0.5)
    labels = ncjax.synth.room_labels(room, cam)
    assert bool(labels.ok)
    # Column 0 looks at azimuth pi - pi/W, onto the wall x = -2 (wall 2, from (-2, 2) to (-2, -2)).
    azimuth = math.pi - math.pi / W
    cosine = -math.cos(azimuth)
    t = (2.0 - 0.5 * cosine) / cosine
    expected_ceiling = (math.pi / 2 - math.atan2(1.0, t)) / math.pi * H - 0.5
    expected_floor = (math.pi / 2 - math.atan2(-1.5, t)) / math.pi * H - 0.5
    assert float(labels.ceiling_v[0]) == pytest.approx(expected_ceiling, abs=1e-9)
    assert float(labels.floor_v[0]) == pytest.approx(expected_floor, abs=1e-9)
    assert int(labels.wall_index[0]) == 2
    # Corners at azimuths 135, 45, -45, -135 degrees, left to right.
    expected_u = [
        (math.pi - a) / (2 * math.pi) * W - 0.5 for a in (3 * math.pi / 4, math.pi / 4, -math.pi / 4, -3 * math.pi / 4)
    ]
    assert int(labels.corner_mask.sum()) == 4
    np.testing.assert_allclose(labels.corner_u[:4], expected_u, atol=1e-9)
    np.testing.assert_allclose(labels.ceiling_corners[:4], [[-2, 2, 1], [2, 2, 1], [2, -2, 1], [-2, -2, 1]], atol=1e-9)
    np.testing.assert_allclose(labels.floor_corners[:4, 2], -1.5)
    assert not np.any(labels.corner_is_occlusion)
    # Corner target: 0.96 ** distance to the nearest corner column, with wrap-around.
    np.testing.assert_allclose(labels.corner_target[0], 0.96 ** expected_u[0], rtol=1e-9)
    np.testing.assert_allclose(labels.corner_target[W - 1], 0.96 ** (W - 1 - expected_u[3]), rtol=1e-9)
    np.testing.assert_allclose(labels.corner_target[32], 0.96 ** abs(32 - expected_u[0]), rtol=1e-9)
    # Wall sequence left to right: x = -2, y = 2, x = 2, y = -2 and back.
    changes = np.flatnonzero(np.diff(np.asarray(labels.wall_index)))
    assert list(np.asarray(labels.wall_index)[changes + 1]) == [1, 0, 3, 2]


@pytest.mark.slow
def test_walls_of_box_room_follow_design_convention():
    direction, distance, ceiling, floor = ncjax.synth.room_walls(_box_room())
    np.testing.assert_allclose(direction[:4], [[0, 1], [-1, 0], [0, -1], [1, 0]], atol=1e-7)
    np.testing.assert_allclose(distance[:4], -2.0)
    ceiling_corners, floor_corners = ncjax.synth.room_corners_3d(_box_room())
    for i in range(4):
        line = ncjax.geometry.line_from_point_direction(ceiling_corners[i], jnp.append(direction[i], 0.0))
        np.testing.assert_allclose(ceiling[i], line, atol=1e-6)
        line = ncjax.geometry.line_from_point_direction(floor_corners[i], jnp.append(direction[i], 0.0))
        np.testing.assert_allclose(floor[i], line, atol=1e-6)


@functools.cache
def _generator(config):
    return jax.jit(jax.vmap(partial(ncjax.synth.random_room, config=config)))


def _generate(config, n, seed=0):
    return _generator(config)(jax.random.split(jax.random.key(seed), n))


MIXED = ncjax.RoomConfig(world="mix", camera_tries=64)


@pytest.fixture(scope="module")
def mixed_rooms():
    return _generate(MIXED, 100, seed=1)


@pytest.mark.slow
def test_same_key_same_room():
    a = _generate(MIXED, 100, seed=7)
    b = _generate(MIXED, 100, seed=7)
    for leaf_a, leaf_b in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(leaf_a, leaf_b)
    assert not np.allclose(a.corners[0], a.corners[1])


@pytest.mark.slow
def test_random_rooms_are_valid(mixed_rooms):
    rooms = mixed_rooms
    assert np.all(np.asarray(rooms.status) == ncjax.synth.RoomStatus.OK)
    walls = np.asarray(rooms.num_walls)
    manhattan = ~np.asarray(rooms.is_atlanta)
    assert 0 < manhattan.sum() < len(walls)
    assert walls.min() >= 4 and walls[manhattan].max() <= 14 and np.all(walls[manhattan] % 2 == 0)
    height = np.asarray(rooms.ceiling_height - rooms.floor_height)
    assert np.all((height >= 2.4) & (height <= 3.5))
    assert np.all((-np.asarray(rooms.floor_height) >= 1.0) & (-np.asarray(rooms.floor_height) <= 1.8))
    assert np.all((np.asarray(rooms.rc) >= 0.3) & (np.asarray(rooms.rc) <= 1.0))
    for i in range(len(walls)):
        room = jax.tree.map(lambda leaf: leaf[i], rooms)
        assert float(polygon_area(room.corners, room.mask)) > 0
        assert float(distance_to_walls(jnp.zeros(2), room.corners, room.mask)) > float(room.rc) + 0.3 - 1e-5
        direction, *_ = ncjax.synth.room_walls(room)
        direction = np.asarray(direction)[: walls[i]]
        cosines = np.abs(direction @ direction.T)
        axis_aligned = np.isclose(cosines, 0, atol=1e-5) | np.isclose(cosines, 1, atol=1e-5)
        # Manhattan: every pair parallel or perpendicular; Atlanta: some oblique wall.
        assert np.all(axis_aligned) == bool(manhattan[i])


def test_labels_are_exact_projections_of_boundary_points(mixed_rooms, x64):
    rooms = jax.tree.map(
        lambda leaf: jnp.asarray(np.asarray(leaf).astype(np.float64) if np.asarray(leaf).dtype == np.float32 else leaf),
        mixed_rooms,
    )

    def check(room):
        cam = room.camera(W, H)
        labels = ncjax.synth.room_labels(room, cam)
        columns = jnp.arange(W, dtype=jnp.float64)
        u_c, v_c = ncjax.geometry.project(cam, labels.ceiling_points)
        u_f, v_f = ncjax.geometry.project(cam, labels.floor_points)
        column_error = jnp.max(jnp.abs(jnp.stack([u_c, u_f]) - columns))
        row_error = jnp.maximum(jnp.max(jnp.abs(v_c - labels.ceiling_v)), jnp.max(jnp.abs(v_f - labels.floor_v)))
        # Each boundary point lies on the wall the label names.
        edges = ncjax.synth.rooms.polygon_edges(room.corners, room.mask)[labels.wall_index]
        a, b, p = edges[:, 0], edges[:, 1], labels.ceiling_points[:, :2]
        off_wall = jnp.abs(ncjax.synth.rooms._cross2(b - a, p - a)) / jnp.linalg.norm(b - a, axis=-1)
        return labels.ok, column_error, row_error, jnp.max(off_wall)

    ok, column_error, row_error, off_wall = jax.jit(jax.vmap(check))(rooms)
    assert np.all(ok)
    assert float(column_error.max()) < 1e-6
    assert float(row_error.max()) < 1e-3
    assert float(off_wall.max()) < 1e-9


def test_corners_sit_where_the_visible_wall_changes(mixed_rooms):
    labels = jax.jit(jax.vmap(lambda room: ncjax.synth.room_labels(room, room.camera(W, H))))(mixed_rooms)
    for i in range(mixed_rooms.corners.shape[0]):
        wall = np.asarray(labels.wall_index[i])
        changes = np.flatnonzero(wall != np.roll(wall, -1))  # change between column c and c + 1
        corner_u = np.asarray(labels.corner_u[i])[np.asarray(labels.corner_mask[i])]
        assert np.all(np.diff(corner_u) >= 0), "corners must be in image order"
        # The wall seen changes between columns c and c + 1 exactly where a corner lies
        # (a wall too short to fill a column puts two corners between the same columns).
        between = np.unique(np.floor(corner_u).astype(int) % W)
        np.testing.assert_array_equal(between, np.sort(changes))


@pytest.mark.slow
@pytest.mark.parametrize("occlusion", ["none", "required"])
def test_occlusion_option(occlusion):
    config = ncjax.RoomConfig(world="mix", occlusion=occlusion, camera_tries=64)
    rooms = _generate(config, 24, seed=3)
    assert np.all(np.asarray(rooms.status) == ncjax.synth.RoomStatus.OK)
    labels = jax.vmap(lambda room: ncjax.synth.room_labels(room, room.camera(W, H)))(rooms)
    occluded = np.asarray(labels.corner_is_occlusion).any(1)
    assert np.all(occluded) if occlusion == "required" else not np.any(occluded)
    # An occlusion shows as two corners in one column: near and far.
    for i in np.flatnonzero(occluded):
        u = np.asarray(labels.corner_u[i])[np.asarray(labels.corner_is_occlusion[i])]
        assert len(u) % 2 == 0
        np.testing.assert_allclose(u[0::2], u[1::2], atol=1e-5)


@pytest.mark.slow
def test_failure_is_reported_not_hidden():
    # A 3.5 m room cannot hold a 1.5 m circle of centres with a 1 m margin: say so.
    config = ncjax.RoomConfig(size_range=(3.5, 3.6), rc_range=(1.5, 1.5), camera_margin=1.0, room_tries=1)
    rooms = _generate(config, 4)
    statuses = set(np.asarray(rooms.status).tolist())
    assert statuses <= {ncjax.synth.RoomStatus.OK, ncjax.synth.RoomStatus.CAMERA_NOT_PLACED}


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(world="paris"),
        dict(occlusion="maybe"),
        dict(min_walls=5),
        dict(max_walls=16),
        dict(height_range=(3.0, 2.0)),
        dict(width_range=(1.5, 1.0)),
        dict(width_range=(1.0, 4.0)),  # wider than the shortest length
        dict(doorway_distance=(0.2, 0.1)),
    ],
)
def test_bad_config_is_rejected(kwargs):
    with pytest.raises(ValueError):
        ncjax.RoomConfig(**kwargs)


@pytest.mark.slow
def test_small_room_source_gives_closets_and_corridors():
    from ncjax.training.data import SYNTH_SOURCES

    config = dataclasses.replace(SYNTH_SOURCES["synth-decor-small"].room, camera_tries=64)
    rooms = _generate(config, 32, seed=3)
    assert np.all(np.asarray(rooms.status) == ncjax.synth.RoomStatus.OK)
    manhattan = ~np.asarray(rooms.is_atlanta)
    assert np.all(np.asarray(rooms.rc) == 0) and 0 < manhattan.sum() < 32
    assert np.asarray(rooms.num_walls)[manhattan].max() <= 6
    for i in range(32):
        corners = np.asarray(rooms.corners[i])[np.asarray(rooms.mask[i])]
        diameter = np.linalg.norm(corners[:, None] - corners[None], axis=-1).max()
        assert diameter <= 4.0 * math.sqrt(2) + 1e-4 and 0 < float(polygon_area(rooms.corners[i], rooms.mask[i])) <= 16
        assert float(distance_to_walls(jnp.zeros(2), rooms.corners[i], rooms.mask[i])) > 0.3 - 1e-5


def test_a_float32_ray_through_a_corner_always_meets_a_wall():
    """Rays from a circle of optical centres aimed exactly at a corner of a convex room meet its two walls at s = 1
    and s = 0 of their segments, which float32 rounding puts just outside [0, 1] for some (a label column that sees
    no wall: ``synth-decor-open`` seed 81, sample 539, was such a room)."""
    count, sides, rc = 2000, 6, 0.3
    keys = jax.random.split(jax.random.key(0), 3)
    jitter = jax.random.uniform(keys[0], (count, sides), minval=-0.3, maxval=0.3)
    angles = (jnp.arange(sides) + jitter) * 2 * jnp.pi / sides + jitter[:, :1]  # gaps under pi: the camera inside
    radii = jax.random.uniform(keys[1], (count, 1), minval=2.0, maxval=5.0)  # convex: every corner in sight
    corners = jnp.stack([radii * jnp.cos(angles), radii * jnp.sin(angles)], -1).astype(jnp.float32)
    target = corners[jnp.arange(count), jax.random.randint(keys[2], (count,), 0, sides)]
    azimuth = jnp.arctan2(target[:, 1], target[:, 0])
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    hits = jax.vmap(ray_hits)(rc * direction, direction, corners, jnp.ones((count, sides), bool))
    nearest = jnp.min(hits, axis=1)
    assert bool(jnp.all(jnp.isfinite(nearest)))
    # the wall met is the corner's: at its distance from the ray's origin
    np.testing.assert_allclose(nearest, jnp.linalg.norm(target, axis=1) - rc, rtol=1e-4)


@pytest.mark.slow
def test_corridors_are_narrow_and_long():
    from ncjax.training.data import SYNTH_SOURCES

    config = dataclasses.replace(SYNTH_SOURCES["synth-decor-hall"].room, camera_tries=64)
    rooms = _generate(config, 32, seed=5)
    assert np.all(np.asarray(rooms.status) == ncjax.synth.RoomStatus.OK)
    assert np.all(np.asarray(rooms.rc) == 0) and np.asarray(rooms.num_walls).max() <= 6
    extents = []
    for i in range(32):
        room = jax.tree.map(lambda leaf: leaf[i], rooms)
        # The room's own axes: the camera frame is rotated from them.
        direction = np.asarray(ncjax.synth.room_walls(room)[0][0])
        axes = np.stack([direction, [-direction[1], direction[0]]])
        along_axes = np.asarray(room.corners)[np.asarray(room.mask)] @ axes.T
        extents.append(along_axes.max(0) - along_axes.min(0))
        assert float(distance_to_walls(jnp.zeros(2), rooms.corners[i], rooms.mask[i])) > 0.2 - 1e-5
    extents = np.array(extents)
    narrow, long = extents.min(1), extents.max(1)
    assert np.all((narrow >= 0.9 - 1e-4) & (narrow <= 1.6 + 1e-4))
    assert np.all((long >= 3.0 - 1e-4) & (long <= 7.5 + 1e-4))


@pytest.mark.slow
def test_a_camera_in_a_doorway_stands_that_far_from_one_wall_and_clear_of_the_others():
    config = ncjax.RoomConfig(world="mix", size_range=(2.0, 5.0), doorway_distance=(0.05, 0.1), camera_tries=64)
    rooms = _generate(config, 24, seed=11)
    assert np.all(np.asarray(rooms.status) == ncjax.synth.RoomStatus.OK)
    for i in range(24):
        room = jax.tree.map(lambda leaf: leaf[i], rooms)
        distances = np.sort(np.asarray(ncjax.synth.rooms.wall_distances(jnp.zeros(2), room.corners, room.mask)))
        rc = float(room.rc)
        assert rc + 0.05 - 1e-5 <= distances[0] <= rc + 0.1 + 1e-5 and distances[1] > rc + config.camera_margin - 1e-5
