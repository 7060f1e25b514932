"""Decor of the realistic synthetic scenes (``SceneConfig(decor=True)``): decals,
ceiling light panels, sunlight, open doors with the rooms behind them, door
leaves and ceiling lights; each changes only the pixels it covers and none
moves the layout's edges."""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from _synth import BATCH, CONFIG, HEIGHT, WIDTH
from test_render import _edge_errors

import ncjax
from ncjax.synth.decor import LAMP_PARTS
from ncjax.synth.elements import FRAME_WIDTH
from ncjax.synth.render import _batched_render, _batched_scenes

# The shared test configuration with decor: its own two compiled calls.
DECOR = dataclasses.replace(CONFIG, scene=ncjax.synth.SceneConfig(decor=True))


@functools.cache
def batch(seed: int):
    """(scenes, renderings, labels) of BATCH random realistic samples."""
    keys = jax.random.split(jax.random.key(seed), BATCH)
    return jax.device_get(ncjax.synthesize_batch(keys, DECOR))


def render_scenes(scenes):
    """Render a batch of BATCH (modified) realistic scenes."""
    return jax.device_get(_batched_render(DECOR)(scenes))


def _points(scenes, renderings, i):
    """Camera-frame hit points (H, W, 3) of scene i's pixels, from the depth image."""
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    azimuth, elevation = np.pi - 2 * np.pi * u / WIDTH, np.pi / 2 - np.pi * v / HEIGHT
    direction = np.stack(
        [np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], -1
    )
    rc = float(scenes.room.rc[i])
    origin = rc * np.stack([np.cos(azimuth), np.sin(azimuth), np.zeros_like(azimuth)], -1)
    return origin + np.asarray(renderings.depth[i])[..., None] * direction


def _wall(scenes, i, wall):
    """First corner, unit direction and inward normal of wall ``wall`` of scene i."""
    corners, mask = np.asarray(scenes.room.corners[i]), np.asarray(scenes.room.mask[i])
    start, end = corners[wall], corners[(wall + 1) % mask.sum()]
    direction = (end - start) / np.linalg.norm(end - start)
    return start, direction, np.array([-direction[1], direction[0]])


def _without_decor(scenes):
    """The scenes without decals, panels, sunlight, open doors or ceiling lights and door leaves."""
    decor = scenes.decor
    scenes = eqx.tree_at(
        lambda s: (s.decor.decals.mask, s.decor.panels.mask, s.decor.sun.mask, s.decor.doorways.is_open),
        scenes,
        (
            np.zeros_like(decor.decals.mask),
            np.zeros_like(decor.panels.mask),
            np.zeros_like(decor.sun.mask),
            np.zeros_like(decor.doorways.is_open),
        ),
    )
    furniture = DECOR.scene.furniture_slots * ncjax.synth.furniture.PARTS_PER_PIECE
    keep = np.arange(scenes.boxes.mask.shape[1]) < furniture
    return eqx.tree_at(lambda s: s.boxes.mask, scenes, np.asarray(scenes.boxes.mask) & keep)


@pytest.mark.slow
def test_same_key_same_scene_and_the_decor_is_there():
    keys = jax.random.split(jax.random.key(0), BATCH)
    again = jax.device_get(_batched_scenes(DECOR)(keys))
    scenes, _, labels = batch(0)
    for a, b in zip(jax.tree.leaves((scenes, labels)), jax.tree.leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.asarray(scenes.decor.decals.mask).any()
    assert scenes.boxes.mask.shape[1] == DECOR.scene.box_slots


@functools.cache
def _plain():
    scenes = _without_decor(batch(0)[0])
    return scenes, render_scenes(scenes)


@pytest.mark.slow
def test_decals_change_only_wall_pixels_inside_their_rectangles():
    plain_scenes, plain = _plain()
    scenes = eqx.tree_at(lambda s: s.decor.decals.mask, plain_scenes, np.asarray(batch(0)[0].decor.decals.mask))
    renderings = render_scenes(scenes)
    changed_total = 0
    for i in range(BATCH):
        changed = np.any(np.asarray(renderings.rgb[i]) != np.asarray(plain.rgb[i]), -1)
        np.testing.assert_array_equal(renderings.semantic[i], plain.semantic[i])
        np.testing.assert_array_equal(renderings.depth[i], plain.depth[i])
        points = _points(scenes, renderings, i)[changed]
        assert np.all(np.asarray(renderings.semantic[i])[changed] == ncjax.synth.Semantic.WALL)
        inside = np.zeros(len(points), bool)
        decals = scenes.decor.decals
        for e in np.nonzero(np.asarray(decals.mask[i]))[0]:
            start, direction, normal = _wall(scenes, i, int(decals.wall[i, e]))
            along = (points[:, :2] - start) @ direction
            span, z_range = np.asarray(decals.span[i, e]), np.asarray(decals.z_range[i, e])
            inside |= (
                (np.abs((points[:, :2] - start) @ normal) < 1e-3)
                & (along >= span[0] - 1e-3)
                & (along <= span[1] + 1e-3)
                & (points[:, 2] >= z_range[0] - 1e-3)
                & (points[:, 2] <= z_range[1] + 1e-3)
            )
        assert inside.all()
        changed_total += changed.sum()
    assert changed_total > 20


def test_light_panels_are_saturated_and_brighter_than_the_ceiling_around_them():
    plain_scenes, plain = _plain()
    panels = plain_scenes.decor.panels
    # A 60 cm panel towards the farthest wall (rays leave the circle of optical
    # centres outwards: the ceiling right above the camera is not seen).
    centre = np.zeros_like(panels.centre)
    for i in range(BATCH):
        room = shapely.Polygon(np.asarray(plain_scenes.room.corners[i])[np.asarray(plain_scenes.room.mask[i])])
        rc = float(plain_scenes.room.rc[i])
        headings = np.linspace(0, 2 * np.pi, 72, endpoint=False)
        reach = [
            shapely.LineString([(rc * np.cos(h), rc * np.sin(h)), (20 * np.cos(h), 20 * np.sin(h))])
            .intersection(room.exterior)
            .distance(shapely.Point(rc * np.cos(h), rc * np.sin(h)))
            for h in headings
        ]
        best = headings[int(np.argmax(reach))]
        centre[i, 0] = (rc + min(0.8, max(reach) / 2)) * np.array([np.cos(best), np.sin(best)])
    half = np.full_like(panels.half_size, 0.3)
    mask = np.zeros_like(panels.mask)
    mask[:, 0] = True
    rotation = np.broadcast_to(np.array([1.0, 0.0], np.float32), panels.rotation.shape)
    scenes = eqx.tree_at(
        lambda s: (
            s.decor.panels.centre,
            s.decor.panels.half_size,
            s.decor.panels.rotation,
            s.decor.panels.emission,
            s.decor.panels.mask,
        ),
        plain_scenes,
        (centre, half, rotation, np.full_like(panels.emission, 4.0), mask),
    )
    renderings = render_scenes(scenes)
    for i in range(BATCH):
        points = _points(scenes, renderings, i)
        ceiling = np.asarray(renderings.semantic[i]) == ncjax.synth.Semantic.CEILING
        distance = np.max(np.abs(points[..., :2] - centre[i, 0]), -1)  # to the square's centre, Chebyshev
        brightness = np.asarray(renderings.rgb[i]).mean(-1)
        inside = ceiling & (distance < 0.25)
        around = ceiling & (distance > 0.35) & (distance < 0.7)
        assert inside.sum() > 5 and around.sum() > 5
        assert brightness[inside].min() > 0.95
        assert brightness[inside].mean() > brightness[around].mean() + 0.1
        changed = np.any(np.asarray(renderings.rgb[i]) != np.asarray(plain.rgb[i]), -1)
        assert np.all(ceiling[changed] & (distance[changed] <= 0.3 + 1e-3))


def test_sunlight_brightens_only_what_sees_the_sun_through_the_window():
    plain_scenes, plain = _plain()
    sun = plain_scenes.decor.sun
    origin, axis, normal = (np.array(x) for x in (sun.origin, sun.axis, sun.normal))
    span, z_range, direction = np.array(sun.span), np.array(sun.z_range), np.array(sun.direction)
    mask = np.zeros_like(sun.mask)
    for i in range(BATCH):
        start, wall_direction, wall_normal = _wall(plain_scenes, i, 0)
        length = np.linalg.norm(np.asarray(plain_scenes.room.corners[i, 1] - plain_scenes.room.corners[i, 0]))
        floor = float(plain_scenes.room.floor_height[i])
        origin[i, 0], axis[i, 0], normal[i, 0] = start, wall_direction, wall_normal
        span[i, 0] = [length / 2 - 0.6, length / 2 + 0.6]
        z_range[i, 0] = [floor + 0.9, floor + 2.1]
        # 40 degrees high, straight into the room.
        direction[i, 0] = np.concatenate([np.cos(0.7) * wall_normal, [-np.sin(0.7)]])
        mask[i, 0] = True
    scenes = eqx.tree_at(
        lambda s: (
            s.decor.sun.origin,
            s.decor.sun.axis,
            s.decor.sun.normal,
            s.decor.sun.span,
            s.decor.sun.z_range,
            s.decor.sun.direction,
            s.decor.sun.mask,
        ),
        plain_scenes,
        (origin, axis, normal, span, z_range, direction, mask),
    )
    renderings = render_scenes(scenes)
    lit_floor = 0
    for i in range(BATCH):
        rgb, before = np.asarray(renderings.rgb[i]), np.asarray(plain.rgb[i])
        changed = np.any(rgb != before, -1)
        assert np.all(rgb[changed] >= before[changed] - 1e-6)
        np.testing.assert_array_equal(renderings.semantic[i], plain.semantic[i])
        # Each changed point, traced back towards the sun, meets the window's rectangle.
        points = _points(scenes, renderings, i)[changed]
        back = ((points[:, :2] - origin[i, 0]) @ normal[i, 0]) / (direction[i, 0, :2] @ normal[i, 0])
        on_wall = points - back[:, None] * direction[i, 0]
        along = (on_wall[:, :2] - origin[i, 0]) @ axis[i, 0]
        assert np.all((back > 0) & (along > span[i, 0, 0] - 1e-3) & (along < span[i, 0, 1] + 1e-3))
        assert np.all((on_wall[:, 2] > z_range[i, 0, 0] - 1e-3) & (on_wall[:, 2] < z_range[i, 0, 1] + 1e-3))
        lit_floor += (changed & (np.asarray(renderings.semantic[i]) == ncjax.synth.Semantic.FLOOR)).sum()
    assert lit_floor > 20


@functools.cache
def _one_door_per_room():
    """The plain scenes with one door 1 m wide in the middle of their first wall: (closed, opened)."""
    plain_scenes, _ = _plain()
    openings = plain_scenes.openings
    fields = {name: np.array(getattr(openings, name)) for name in ("wall", "span", "z_range", "is_window", "mask")}
    for i in range(BATCH):
        floor, ceiling = float(plain_scenes.room.floor_height[i]), float(plain_scenes.room.ceiling_height[i])
        length = np.linalg.norm(np.asarray(plain_scenes.room.corners[i, 1] - plain_scenes.room.corners[i, 0]))
        fields["wall"][i] = 0
        fields["span"][i] = [length / 2 - 0.5, length / 2 + 0.5]
        fields["z_range"][i] = [floor, min(floor + 2.05, ceiling - 0.15)]
        fields["is_window"][i] = False
        fields["mask"][i] = np.arange(openings.mask.shape[1]) == 0
    closed = eqx.tree_at(
        lambda s: tuple(getattr(s.openings, name) for name in fields), plain_scenes, tuple(fields.values())
    )
    opened = eqx.tree_at(
        lambda s: s.decor.doorways.is_open,
        closed,
        np.broadcast_to(np.arange(openings.mask.shape[1]) == 0, fields["mask"].shape),
    )
    return closed, opened


def _assert_edges_on_labels(semantic, labels):
    """In each image, the semantic ceiling and floor edges lie within 1 px of the label's rows in 99% of the
    columns where no object is near them."""
    for i in range(semantic.shape[0]):
        label = jax.tree.map(lambda x: x[i], labels)
        for errors in _edge_errors(np.asarray(semantic[i]), label):
            seen = ~np.isnan(errors)
            assert (errors[seen] <= 1.0).sum() >= 0.99 * seen.sum()


def test_open_doors_show_the_room_behind_and_keep_the_edges_on_the_labels():
    closed, opened = _one_door_per_room()
    before, after = render_scenes(closed), render_scenes(opened)
    _, _, labels = batch(0)
    behind = 0
    for i in range(BATCH):
        changed = np.any(np.asarray(after.rgb[i]) != np.asarray(before.rgb[i]), -1)
        # Only the door's pixels change, and they stay an opening: the labels' edges do not move.
        assert np.all(np.asarray(before.semantic[i])[changed] == ncjax.synth.Semantic.OPENING)
        np.testing.assert_array_equal(after.semantic[i], before.semantic[i])
        # Through the doorway the rays end behind the wall plane.
        start, _, normal = _wall(opened, i, 0)
        points = _points(opened, after, i)[changed]
        behind += ((points[:, :2] - start) @ normal < -0.05).sum()
    assert behind > 20
    _assert_edges_on_labels(after.semantic, labels)


def test_the_rooms_behind_open_doors_have_skirting_boards():
    """Skirting boards along the foot of the walls of the room behind a door, as along this room's: painted red,
    they change pixels seen through the door, all of them below the boards' top."""
    _, opened = _one_door_per_room()
    bare = eqx.tree_at(lambda s: s.skirting_height, opened, np.zeros(BATCH, np.float32))
    red = eqx.tree_at(
        lambda s: (s.skirting_height, s.skirting_colour),
        opened,
        (np.full(BATCH, 0.3, np.float32), np.tile(np.float32([1.0, 0.0, 0.0]), (BATCH, 1))),
    )
    without, with_boards = render_scenes(bare), render_scenes(red)
    behind = 0
    for i in range(BATCH):
        changed = np.any(np.asarray(with_boards.rgb[i]) != np.asarray(without.rgb[i]), -1)
        points = _points(red, with_boards, i)[changed]
        assert np.all(points[:, 2] - float(red.room.floor_height[i]) < 0.3 + 1e-3)
        through = np.asarray(with_boards.semantic[i])[changed] == ncjax.synth.Semantic.OPENING
        behind += through.sum()
    assert behind > 5


@functools.cache
def _decorated_scenes():
    config = ncjax.synth.SceneConfig(
        decor=True,
        door_probability=1.0,
        open_door_probability=1.0,
        door_leaf_probability=1.0,
        panel_probability=0.5,
        pendant_probability=0.5,
        fan_probability=0.5,
    )
    rooms = batch(0)[0].room
    keys = jax.random.split(jax.random.key(5), BATCH)
    generate = jax.jit(jax.vmap(lambda k, r: ncjax.synth.random_scene(k, r, config)))
    return config, jax.device_get(generate(keys, rooms))


@pytest.mark.extended  # compiles a scene generator of its own (about 20 s)
def test_door_leaves_hang_in_their_doorways_and_lamps_stay_up():
    config, scenes = _decorated_scenes()
    furniture = config.furniture_slots * ncjax.synth.furniture.PARTS_PER_PIECE
    lamps = config.lamp_slots * LAMP_PARTS
    leaves = jax.tree.map(lambda x: np.asarray(x)[:, furniture + lamps :], scenes.boxes)
    assert leaves.mask.sum() >= 2
    for i, d in zip(*np.nonzero(leaves.mask), strict=True):
        assert scenes.decor.doorways.is_open[i, d] and not scenes.openings.is_window[i, d]
        start, direction, normal = _wall(scenes, i, int(scenes.openings.wall[i, d]))
        # The leaf's ends: one on the hinge, at a side of the doorway inside its frame.
        ends = leaves.centre[i, d, :2] + np.array([-1, 1])[:, None] * leaves.half_size[i, d, 0] * leaves.rotation[i, d]
        hinge = ends[np.argmin(np.abs((ends - start) @ normal))]
        along = (hinge - start) @ direction
        sides = np.asarray(scenes.openings.span[i, d]) + [FRAME_WIDTH, -FRAME_WIDTH]
        assert np.min(np.abs(along - sides)) < 1e-3
        z_range = np.asarray(scenes.openings.z_range[i, d])
        z = leaves.centre[i, d, 2] + np.array([-1, 1]) * leaves.half_size[i, d, 2]
        assert z_range[0] < z[0] and z[1] < z_range[1] - FRAME_WIDTH + 1e-4
    lamp_boxes = jax.tree.map(lambda x: np.asarray(x)[:, furniture : furniture + lamps], scenes.boxes)
    bottom = lamp_boxes.centre[..., 2] - lamp_boxes.half_size[..., 2]
    assert np.all(np.where(lamp_boxes.mask, bottom > 0.3, True))  # above the camera
    assert np.all(np.where(lamp_boxes.mask, bottom < np.asarray(scenes.room.ceiling_height)[:, None], True))
    assert scenes.decor.panels.mask.any() or lamp_boxes.mask.any()


@pytest.mark.slow
def test_beams_cross_the_ceiling_from_wall_to_wall_and_keep_the_edges_on_the_labels():
    config = ncjax.synth.SceneConfig(decor=True, beam_probability=1.0)
    beam_config = dataclasses.replace(DECOR, scene=config)
    plain, _, labels = batch(0)
    keys = jax.random.split(jax.random.key(0), BATCH)
    scenes, _ = jax.device_get(_batched_scenes(beam_config)(keys))
    # The same room, furniture and door leaves as without beams; the beams after the other boxes.
    np.testing.assert_array_equal(scenes.room.corners, plain.room.corners)
    others = plain.boxes.mask.shape[1]
    assert scenes.boxes.mask.shape[1] == others + config.beam_slots
    furniture = config.furniture_slots * ncjax.synth.furniture.PARTS_PER_PIECE
    for part in (slice(0, furniture), slice(others - config.opening_slots, others)):
        np.testing.assert_array_equal(scenes.boxes.centre[:, part], plain.boxes.centre[:, part])
        np.testing.assert_array_equal(scenes.boxes.mask[:, part], plain.boxes.mask[:, part])
    beams = jax.tree.map(lambda x: np.asarray(x)[:, others:], scenes.boxes)
    assert beams.mask.sum() >= BATCH
    ceiling = np.asarray(scenes.room.ceiling_height)
    for i, b in zip(*np.nonzero(beams.mask), strict=True):
        top, bottom = beams.centre[i, b, 2] + np.array([1, -1]) * beams.half_size[i, b, 2]
        assert abs(top - ceiling[i]) < 1e-5 and 0.1 - 1e-5 <= top - bottom <= 0.35 + 1e-5 and bottom > 0.4
        walls = shapely.LinearRing(np.asarray(scenes.room.corners[i])[np.asarray(scenes.room.mask[i])])
        ends = beams.centre[i, b, :2] + np.array([-1, 1])[:, None] * beams.half_size[i, b, 0] * beams.rotation[i, b]
        assert max(walls.distance(shapely.Point(end)) for end in ends) < 1e-4  # wall to wall
    # A beam only hides what lies above the camera, and the edges stay on the labels where no object is near.
    with_beams = jax.device_get(_batched_render(beam_config)(scenes))
    no_beams = np.asarray(scenes.boxes.mask) & (np.arange(others + config.beam_slots) < others)
    without = jax.device_get(_batched_render(beam_config)(eqx.tree_at(lambda s: s.boxes.mask, scenes, no_beams)))
    changed = np.asarray(with_beams.depth) < np.asarray(without.depth) - 1e-4
    assert changed.sum() > 20 * BATCH
    assert not changed[:, HEIGHT // 2 :].any()
    np.testing.assert_array_equal(np.asarray(with_beams.depth) <= np.asarray(without.depth) + 1e-4, True)
    assert np.all(np.asarray(with_beams.semantic)[changed] == ncjax.synth.Semantic.OBJECT)
    _assert_edges_on_labels(with_beams.semantic, labels)


@pytest.mark.slow
def test_neutral_paint_gives_pale_walls_and_leaves_the_rest_of_the_scene_as_it_was():
    from ncjax.synth.materials import Pattern
    from ncjax.synth.scene import random_scene

    def scenes(config):
        def one(key):
            room_key, scene_key = jax.random.split(key)
            return random_scene(scene_key, ncjax.synth.random_room(room_key, CONFIG.room), config)

        return jax.device_get(jax.jit(jax.vmap(one))(jax.random.split(jax.random.key(5), 16)))

    plain = scenes(ncjax.synth.SceneConfig())
    neutral = scenes(ncjax.synth.SceneConfig(neutral_paint_probability=1.0))
    colour = neutral.walls.colour_a
    value, saturation = colour.max(-1), 1.0 - colour.min(-1) / colour.max(-1)
    assert np.all(saturation <= 0.12 + 1e-5) and np.all((value >= 0.75 - 1e-5) & (value <= 0.97 + 1e-5))
    assert set(np.unique(neutral.walls.pattern)) <= {Pattern.PAINT, Pattern.PLASTER}
    assert np.all(neutral.walls.colour_b <= neutral.walls.colour_a)
    # The plain scenes' walls were not all pale: the option changed them.
    assert np.any(1.0 - plain.walls.colour_a.min(-1) / plain.walls.colour_a.max(-1) > 0.12)
    # Only the walls change: same room, furniture, lights, floor and ceiling.
    for field in (f.name for f in dataclasses.fields(plain) if f.name != "walls"):
        for a, b in zip(jax.tree.leaves(getattr(plain, field)), jax.tree.leaves(getattr(neutral, field)), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=field)


@pytest.mark.slow
def test_passages_are_wide_open_leafless_and_keep_the_edges_on_the_labels():
    config = ncjax.synth.SceneConfig(decor=True, door_probability=1.0, passage_probability=1.0)
    scenes_batch, _, labels = batch(0)
    keys = jax.random.split(jax.random.key(7), BATCH)
    generate = jax.jit(jax.vmap(lambda k, r: ncjax.synth.random_scene(k, r, config)))
    scenes = jax.device_get(generate(keys, scenes_batch.room))
    openings, doorways = scenes.openings, scenes.decor.doorways
    filled = np.asarray(openings.mask)
    assert filled.sum() >= BATCH
    np.testing.assert_array_equal(np.asarray(doorways.is_passage)[filled], True)
    np.testing.assert_array_equal(np.asarray(doorways.is_open)[filled], True)
    width = np.diff(np.asarray(openings.span), axis=-1)[..., 0][filled]
    assert np.all((width >= 1.2 - 1e-5) & (width <= 3.0 + 1e-5))
    below_ceiling = (np.asarray(scenes.room.ceiling_height)[:, None] - np.asarray(openings.z_range)[..., 1])[filled]
    assert np.all((below_ceiling >= 0.05 - 1e-5) & (below_ceiling <= 0.4 + 1e-5))
    furniture = config.furniture_slots * ncjax.synth.furniture.PARTS_PER_PIECE
    leaves = np.asarray(scenes.boxes.mask)[:, furniture + config.lamp_slots * LAMP_PARTS :]
    assert not leaves.any()
    # Through a passage the next room shows, yet the edges stay on the wall plane's label rows.
    renderings = render_scenes(scenes)
    _assert_edges_on_labels(renderings.semantic, labels)
    assert np.sum(np.asarray(renderings.semantic) == ncjax.synth.Semantic.OPENING) > 0.02 * renderings.semantic.size


def _source_batch(kind: str, seed: int):
    """``2 BATCH`` rooms of a training source at the tests' size: its configuration, scenes, renderings and labels
    (all labels valid)."""
    from ncjax.training.data import SYNTH_SOURCES

    config = dataclasses.replace(SYNTH_SOURCES[kind], height=HEIGHT, width=WIDTH)
    keys = jax.random.split(jax.random.key(seed), 2 * BATCH)
    scenes, renderings, labels = jax.device_get(ncjax.synthesize_batch(keys, config))
    assert np.all(labels.ok)
    return config, scenes, renderings, labels


@pytest.mark.slow
def test_walk_in_closets_have_wide_passages_and_shelving_and_keep_the_edges_on_the_labels():
    closets, scenes, renderings, labels = _source_batch("synth-decor-closet", seed=3)
    openings, doorways = scenes.openings, scenes.decor.doorways
    passages = np.asarray(openings.mask & doorways.is_passage)
    assert passages.any(-1).mean() >= 0.5
    width = np.diff(np.asarray(openings.span), axis=-1)[..., 0][passages]
    assert np.all((width >= 0.9 - 1e-5) & (width <= 2.2 + 1e-5))
    filled, floating = _shelving(scenes.boxes, np.asarray(scenes.room.floor_height), closets)
    assert np.sum(filled & floating) >= BATCH
    # Scenes that do not ask for it never have it.
    plain = batch(0)[0]
    filled, floating = _shelving(plain.boxes, np.asarray(plain.room.floor_height), DECOR)
    assert filled.any() and not np.any(filled & floating)
    _assert_edges_on_labels(renderings.semantic, labels)


@pytest.mark.slow
def test_closets_are_photographed_from_their_opening_with_shelving_and_keep_the_edges_on_the_labels():
    closets, scenes, renderings, labels = _source_batch("synth-decor-closet-door", seed=3)
    openings, doorways = scenes.openings, scenes.decor.doorways
    # One opening each, a passage in the wall nearest the camera, 3-15 cm away, around the camera's foot.
    np.testing.assert_array_equal(np.asarray(openings.mask[:, 0] & doorways.is_passage[:, 0]), True)
    for i in range(2 * BATCH):
        room = jax.tree.map(lambda x: jnp.asarray(x[i]), scenes.room)
        distances = np.asarray(ncjax.synth.rooms.wall_distances(jnp.zeros(2), room.corners, room.mask))
        wall = int(openings.wall[i, 0])
        assert wall == np.argmin(distances) and 0.03 - 1e-5 <= distances[wall] <= 0.15 + 1e-5
        start, end = np.asarray(room.corners[wall]), np.asarray(room.corners[(wall + 1) % int(room.mask.sum())])
        foot = -start @ (end - start) / np.linalg.norm(end - start)
        span = np.asarray(openings.span[i, 0])
        assert span[0] - 1e-5 <= foot <= span[1] + 1e-5 and 0.5 <= span[1] - span[0] <= 2.2 + 1e-5
    filled, floating = _shelving(scenes.boxes, np.asarray(scenes.room.floor_height), closets)
    assert np.mean(np.any(filled & floating, axis=-1)) >= 0.75
    _assert_edges_on_labels(renderings.semantic, labels)


def _shelving(boxes, floor_height, config):
    """Which furniture slots are filled, and which hold closet shelving: the only furniture whose first box
    floats at head height (its top shelf)."""
    parts = ncjax.synth.furniture.PARTS_PER_PIECE
    first = slice(0, config.scene.furniture_slots * parts, parts)
    bottom = np.asarray(boxes.centre[:, first, 2] - boxes.half_size[:, first, 2]) - floor_height[:, None]
    return np.asarray(boxes.mask[:, first]), bottom >= 1.5


@pytest.mark.slow
def test_corridors_have_open_doors_along_them_and_keep_the_edges_on_the_labels():
    _, scenes, renderings, labels = _source_batch("synth-decor-hall", seed=4)
    openings, doorways = scenes.openings, scenes.decor.doorways
    doors = np.asarray(openings.mask & ~openings.is_window)
    # Most corridors open on a room behind, and most have doors on more than one wall.
    assert np.mean(np.any(doors & np.asarray(doorways.is_open), axis=-1)) >= 0.5
    walls_with_doors = [len(set(np.asarray(openings.wall[i])[doors[i]])) for i in range(2 * BATCH)]
    assert np.mean(np.array(walls_with_doors) >= 2) >= 0.5
    _assert_edges_on_labels(renderings.semantic, labels)
