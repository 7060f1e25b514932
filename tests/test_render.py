"""The renderer and the scenes: labels on the rendered edges, analytic depth,
furniture placement, supersampling, augmentations."""

import functools
import hashlib
import json
import pathlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from _synth import BATCH, CONFIG, HEIGHT, WIDTH, batch, render_scenes
from hypothesis import assume, given
from hypothesis import strategies as st

import ncjax
from ncjax.synth.furniture import PARTS_PER_PIECE
from ncjax.synth.placement import Rectangle

WALL_LIKE = (ncjax.synth.Semantic.WALL, ncjax.synth.Semantic.OPENING)


def _edge_errors(semantic: np.ndarray, labels, window: int = 3):
    """Per column: |semantic edge - label row| for the ceiling and the floor
    boundary, NaN where an object lies within ``window`` rows of the label."""
    rows = np.arange(semantic.shape[0])
    errors = []
    for label_rows, upper, lower in (
        (labels.ceiling_v, (ncjax.synth.Semantic.CEILING,), WALL_LIKE),
        (labels.floor_v, WALL_LIKE, (ncjax.synth.Semantic.FLOOR,)),
    ):
        column_errors = np.full(semantic.shape[1], np.nan)
        for u, row in enumerate(np.asarray(label_rows)):
            near = (rows >= row - window) & (rows <= row + window)
            classes = semantic[near, u]
            if np.any(classes == ncjax.synth.Semantic.OBJECT) or not near.any():
                continue
            # The edge: the first row of the window whose class is below the boundary.
            below = np.isin(classes, lower)
            if not below.any() or not np.isin(classes[: np.argmax(below)], upper).all():
                column_errors[u] = np.inf
                continue
            # Row r is centred at v = r: the boundary above the first row below is at r - 0.5.
            column_errors[u] = abs(rows[near][np.argmax(below)] - 0.5 - row)
        errors.append(column_errors)
    return errors


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_semantic_edges_sit_on_the_exact_label_rows(seed):
    scenes, renderings, labels = batch(seed)
    tested, within = 0, 0
    for i in range(BATCH):
        assert bool(labels.ok[i])
        label = jax.tree.map(lambda x: x[i], labels)
        for errors in _edge_errors(np.asarray(renderings.semantic[i]), label):
            seen = ~np.isnan(errors)
            tested += seen.sum()
            within += (errors[seen] <= 1.0).sum()
    assert tested >= 0.5 * 2 * BATCH * WIDTH  # furniture hides at most half of the edges
    assert within >= 0.99 * tested


def _empty_box_room(scenes, half_x, half_y, rc):
    """The generated scenes emptied (no furniture, lamps or openings) and their
    rooms replaced by axis-aligned rectangles [-half_x, half_x] x [-half_y, half_y]."""
    capacity = scenes.room.corners.shape[1]
    corners = np.zeros((BATCH, capacity, 2), np.float32)
    for i in range(BATCH):
        corners[i, :4] = [
            [half_x[i], -half_y[i]],
            [half_x[i], half_y[i]],
            [-half_x[i], half_y[i]],
            [-half_x[i], -half_y[i]],
        ]
    mask = np.broadcast_to(np.arange(capacity) < 4, (BATCH, capacity))
    scenes = eqx.tree_at(
        lambda s: (s.room.corners, s.room.mask, s.room.rc), scenes, (corners, mask, np.asarray(rc, np.float32))
    )
    scenes = eqx.tree_at(lambda s: s.boxes.mask, scenes, jnp.zeros_like(scenes.boxes.mask))
    return eqx.tree_at(lambda s: s.openings.mask, scenes, jnp.zeros_like(scenes.openings.mask))


def _sha256(arrays) -> str:
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_default_scenes_reproduce_the_basic_generator_bit_for_bit(seed):
    """The default configuration (no decor) must draw and render exactly the basic
    generator's rooms, on which the published figures were measured: the stored
    digests were taken from that generator (see the fixture's "about"). A
    mismatch means the default data changed; never update the digests to pass."""
    with open(pathlib.Path(__file__).parent / "data" / "synth_basic_digests.json") as file:
        expected = json.load(file)[str(seed)]
    scenes, renderings, labels = batch(seed)
    assert scenes.decor is None
    digests = {
        "rgb8": _sha256([np.round(np.asarray(renderings.rgb) * 255).astype(np.uint8)]),
        "depth": _sha256([np.asarray(renderings.depth, np.float32)]),
        "semantic": _sha256([np.asarray(renderings.semantic, np.int32)]),
        "labels": _sha256(jax.tree.leaves(labels)),
        "scenes": _sha256(jax.tree.leaves(scenes)),
    }
    assert digests == expected


def test_depth_of_an_empty_box_room_is_analytic():
    scenes, _, _ = batch(0)
    half_x, half_y = np.array([2.0, 3.5, 1.7, 4.0]), np.array([1.5, 2.0, 2.6, 1.9])
    rc = np.array([0.0, 0.3, 0.6, 1.0])  # rc = 0: the central equirectangular panorama
    renderings = render_scenes(_empty_box_room(scenes, half_x, half_y, rc))
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    azimuth, elevation = np.pi - 2 * np.pi * u / WIDTH, np.pi / 2 - np.pi * v / HEIGHT
    direction = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    for i in range(BATCH):
        origin = rc[i] * np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros_like(azimuth)], -1)
        bounds = np.array(
            [
                [-half_x[i], half_x[i]],
                [-half_y[i], half_y[i]],
                [float(scenes.room.floor_height[i]), float(scenes.room.ceiling_height[i])],
            ]
        )
        with np.errstate(divide="ignore"):
            # Inside a box, the ray leaves through the plane ahead on each axis.
            exits = (np.where(direction > 0, bounds[:, 1], bounds[:, 0]) - origin) / direction
        expected = np.min(np.where(np.isfinite(exits) & (exits > 0), exits, np.inf), -1)
        np.testing.assert_allclose(np.asarray(renderings.depth[i]), expected, rtol=2e-5, atol=2e-5)
        assert set(np.unique(renderings.semantic[i])) <= {0, 1, 2}


def test_furniture_never_overlaps_stays_inside_and_clears_the_camera():
    slots = CONFIG.scene.furniture_slots
    checked = 0
    for seed in (0, 1):
        scenes, _, _ = batch(seed)
        for i in range(BATCH):
            boxes = jax.tree.map(lambda x: np.asarray(x[i]), scenes.boxes)
            room = jax.tree.map(lambda x: np.asarray(x[i]), scenes.room)
            floor_plan = shapely.Polygon(room.corners[room.mask])
            rc = float(room.rc)
            footprints, z_ranges, pieces = [], [], []
            for b in np.nonzero(boxes.mask)[0]:
                c, s = boxes.rotation[b]
                axes = np.array([[c, s], [-s, c]])
                corners = (
                    boxes.centre[b, :2]
                    + (np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * boxes.half_size[b, :2]) @ axes
                )
                footprints.append(shapely.Polygon(corners))
                z_ranges.append(boxes.centre[b, 2] + np.array([-1, 1]) * boxes.half_size[b, 2])
                pieces.append(b // PARTS_PER_PIECE if b < slots * PARTS_PER_PIECE else slots + b)
            for a, (footprint, z_range, piece) in enumerate(zip(footprints, z_ranges, pieces, strict=True)):
                assert floor_plan.buffer(1e-4).contains(footprint)
                assert room.floor_height - 1e-5 <= z_range[0] and z_range[1] <= room.ceiling_height + 1e-5
                # The circle of optical centres (z = 0) is never inside a box.
                assert footprint.distance(shapely.Point(0, 0)) > rc or not z_range[0] <= 0 <= z_range[1]
                for other in range(a + 1, len(footprints)):
                    if pieces[other] == piece:
                        continue
                    overlap_2d = footprint.intersection(footprints[other]).area > 1e-8
                    overlap_z = min(z_range[1], z_ranges[other][1]) - max(z_range[0], z_ranges[other][0]) > 1e-6
                    assert not (overlap_2d and overlap_z)
                checked += 1
    assert checked > 8 * BATCH  # scenes do hold furniture


def test_rendering_shapes_ranges_and_columns_without_overflow():
    scenes, renderings, _ = batch(0)
    assert renderings.rgb.shape == (BATCH, HEIGHT, WIDTH, 3)
    assert renderings.depth.shape == renderings.semantic.shape == (BATCH, HEIGHT, WIDTH)
    assert np.all((renderings.rgb >= 0) & (renderings.rgb <= 1))
    assert np.all(np.isfinite(renderings.depth) & (renderings.depth > 0))
    assert set(np.unique(renderings.semantic)) <= set(range(len(ncjax.synth.Semantic)))
    assert np.std(renderings.rgb) > 0.05  # not a flat image
    overflow = jax.jit(jax.vmap(lambda s: ncjax.synth.box_overflow(s, s.room.camera(WIDTH, HEIGHT), CONFIG.render)))(
        scenes
    )
    assert not np.any(overflow)


@functools.cache
def _single_render(supersampling: int):
    config = ncjax.synth.RenderConfig(supersampling=supersampling, shadows=supersampling > 1)
    return jax.jit(lambda scene: ncjax.synth.render(scene, scene.room.camera(32, 16), config))


@pytest.mark.slow
def test_supersampling_keeps_depth_and_semantics_of_the_pixel_centre():
    scenes, _, _ = batch(0)
    scene = jax.tree.map(lambda x: x[0], scenes)
    plain, fine = _single_render(1)(scene), _single_render(3)(scene)
    np.testing.assert_allclose(np.asarray(fine.depth), np.asarray(plain.depth), rtol=1e-4)
    assert np.mean(np.asarray(fine.semantic) == np.asarray(plain.semantic)) > 0.99
    assert np.abs(np.asarray(fine.rgb) - np.asarray(plain.rgb)).mean() < 0.1


def test_configurations_reject_bad_values():
    with pytest.raises(ValueError, match="odd"):
        ncjax.synth.RenderConfig(supersampling=2)
    with pytest.raises(ValueError, match="positive"):
        ncjax.synth.SceneConfig(furniture_slots=0)
    with pytest.raises(ValueError, match="unknown type 'sofa bed'"):
        ncjax.synth.SceneConfig(furniture_weights=(("sofa bed", 1.0),))
    with pytest.raises(ValueError, match="negative weight"):
        ncjax.synth.SceneConfig(furniture_weights=(("bed", -1.0),))
    with pytest.raises(ValueError, match="passage_width_range"):
        ncjax.synth.SceneConfig(passage_width_range=(2.0, 1.0))
    with pytest.raises(ValueError, match="passage_at_camera needs decor"):
        ncjax.synth.SceneConfig(passage_at_camera=True)
    with pytest.raises(ValueError, match="image size"):
        ncjax.SynthConfig(width=2, height=2)


# ------------------------------------------------------------------ augmentations

_IMAGE = jax.random.uniform(jax.random.key(3), (16, 32, 3))


def test_neutral_augmentations_are_identities():
    np.testing.assert_allclose(ncjax.synth.adjust_exposure(_IMAGE, 1.0), _IMAGE, atol=1e-6)
    np.testing.assert_allclose(ncjax.synth.adjust_gamma(_IMAGE, 1.0), _IMAGE, atol=1e-6)
    np.testing.assert_allclose(ncjax.synth.white_balance(_IMAGE, jnp.ones(3)), _IMAGE, atol=1e-6)
    np.testing.assert_allclose(ncjax.synth.add_sensor_noise(jax.random.key(0), _IMAGE, 0.0, 0.0), _IMAGE, atol=1e-6)


def test_greyscale_and_blur():
    grey = np.asarray(ncjax.network.to_greyscale(_IMAGE))
    assert np.allclose(grey[..., 0], grey[..., 1]) and np.allclose(grey[..., 1], grey[..., 2])
    np.testing.assert_allclose(grey[..., 0], np.asarray(_IMAGE) @ np.array([0.299, 0.587, 0.114]), atol=1e-6)
    blurred = np.asarray(ncjax.network.gaussian_blur(_IMAGE, 1.0))
    # Wrapping horizontally, a blur of a horizontally constant image keeps it;
    # the mean of each row is kept (the kernel is normalised).
    np.testing.assert_allclose(
        blurred.mean(1),
        np.asarray(ncjax.network.gaussian_blur(_IMAGE.mean(1, keepdims=True) * jnp.ones_like(_IMAGE), 1.0)).mean(1),
        atol=1e-5,
    )
    assert blurred.std() < np.asarray(_IMAGE).std()


@pytest.mark.parametrize("sigma, radius", [(1.0, 3), (2.0, 8), (0.5, 1)])
def test_blur_matches_scipy_wrapping_horizontally_and_clamping_vertically(sigma, radius):
    from scipy import ndimage

    image = np.asarray(jax.random.uniform(jax.random.key(3), (12, 20, 3)))
    expected = ndimage.gaussian_filter1d(image, sigma, axis=1, mode="wrap", truncate=radius / sigma)
    expected = ndimage.gaussian_filter1d(expected, sigma, axis=0, mode="nearest", truncate=radius / sigma)
    np.testing.assert_allclose(ncjax.network.gaussian_blur(jnp.asarray(image), sigma, radius), expected, atol=2e-6)


@pytest.mark.slow
def test_random_augment_is_a_pure_batched_function():
    keys = jax.random.split(jax.random.key(1), 3)
    augment = jax.jit(jax.vmap(ncjax.synth.random_augment, in_axes=(0, None)))
    first, second = augment(keys, _IMAGE), augment(keys, _IMAGE)
    assert first.shape == (3,) + _IMAGE.shape
    np.testing.assert_array_equal(first, second)
    assert np.all((first >= 0) & (first <= 1))
    assert not np.allclose(first[0], first[1])


# ------------------------------------------------------------- geometry helpers

_coordinate = st.floats(-3.0, 3.0)
_half = st.floats(0.05, 1.5)
_angle = st.floats(0.0, 2 * np.pi)


def _rectangle(centre, half, angle):
    rotation = np.array([np.cos(angle), np.sin(angle)])
    corners = np.asarray(
        ncjax.synth.placement.rectangle_corners(jnp.asarray(centre), jnp.asarray(half), jnp.asarray(rotation))
    )
    return rotation, shapely.Polygon(corners)


@functools.cache
def _overlap():
    return jax.jit(ncjax.synth.placement.rectangles_overlap)


@given(_coordinate, _coordinate, _half, _half, _angle, _coordinate, _coordinate, _half, _half, _angle)
def test_rectangle_overlap_agrees_with_shapely(x1, y1, w1, h1, a1, x2, y2, w2, h2, a2):
    rotation_a, polygon_a = _rectangle((x1, y1), (w1, h1), a1)
    rotation_b, polygon_b = _rectangle((x2, y2), (w2, h2), a2)
    distance = polygon_a.distance(polygon_b)
    assume(abs(distance) > 1e-3 or polygon_a.intersection(polygon_b).area > 1e-3)
    overlap = bool(
        _overlap()(
            Rectangle(jnp.array([x1, y1]), jnp.array([w1, h1]), jnp.asarray(rotation_a)),
            Rectangle(jnp.array([x2, y2]), jnp.array([w2, h2]), jnp.asarray(rotation_b)),
            0.0,
        )
    )
    assert overlap == (distance == 0.0)


@functools.cache
def _interval():
    return jax.jit(ncjax.synth.raycast.box_interval_2d)


@given(_coordinate, _coordinate, _half, _half, _angle, _angle)
def test_box_interval_agrees_with_shapely(x, y, w, h, yaw, heading):
    rotation, polygon = _rectangle((x, y), (w, h), yaw)
    assume(polygon.distance(shapely.Point(0, 0)) > 1e-3)
    direction = np.array([np.cos(heading), np.sin(heading)])
    t_in, t_out, normal = (
        np.asarray(a)
        for a in _interval()(
            jnp.zeros(2), jnp.asarray(direction), jnp.array([x, y]), jnp.array([w, h]), jnp.asarray(rotation)
        )
    )
    ray = shapely.LineString([(0, 0), tuple(100 * direction)])
    crossing = ray.intersection(polygon)
    hit = t_in < t_out and t_out > 0
    assume(crossing.length > 1e-3 or crossing.is_empty)
    assert hit == (not crossing.is_empty)
    if hit:
        along = sorted(np.dot(np.asarray(crossing.coords), direction))
        np.testing.assert_allclose([t_in, t_out], along, atol=1e-4)
        assert np.dot(normal, direction) < 0  # the entry side faces the ray


def test_radiance_from_colours_inverts_the_tone_curve():
    from ncjax.synth.render import radiance_from_colours, tone_curve

    radiance = np.linspace(0.0, 5.0, 51)[:, None] * np.array([1.0, 0.5, 0.25])
    colours = np.asarray(tone_curve(radiance))
    np.testing.assert_allclose(colours, (1.0 - np.exp(-1.5 * radiance)) ** (1.0 / 2.2), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(radiance_from_colours(colours)), radiance, rtol=1e-3, atol=1e-5)
