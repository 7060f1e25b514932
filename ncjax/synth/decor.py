"""Generators of what dresses a furnished room up: ceiling lights of several
kinds (flush lamps, pendants, fans, flush light panels), wall decals (posters,
pictures, whiteboards), sun patches through the windows, the leaves of open
doors and beams across the ceiling.

None of them changes the room's layout: decals and panels are flat on a wall
or the ceiling, sunlight is a light term, and lamps, door leaves and beams are boxes
inside the room (objects, like furniture). Each is a pure function of a key,
in fixed-capacity arrays with masks (see :mod:`ncjax.synth.scene`).
"""

from __future__ import annotations

import enum
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..geometry.polygon import perpendicular, point_in_polygon
from .elements import FRAME_WIDTH, Boxes, DecalKind, Decals, Doorways, Lights, Openings, Panels, SunPatches
from .furniture import piece_materials
from .materials import Material, Pattern, colour_in_hsv_box
from .placement import (
    Footprints,
    Rectangle,
    between,
    categorical,
    no_footprints,
    pack_footprints,
    rectangle_distance_to_point,
    rectangle_in_room,
    rectangles_overlap,
    room_frame,
    wall_position,
)
from .rooms import Room, distance_to_walls, ray_hits

LAMP_PARTS = 4  # boxes per ceiling light slot (a fan needs four)


class LampKind(enum.IntEnum):
    """Kinds of ceiling light."""

    FLUSH = 0  # an emissive box against the ceiling
    PENDANT = 1  # an emissive shade hanging on a cord
    FAN = 2  # a ceiling fan: two crossed blades, a rod and an emissive bowl
    PANEL = 3  # an emissive rectangle flush in the ceiling (no box)


def plan_axis(room: Room) -> Float[Array, 2]:
    """Unit direction of the room's longest wall: the axis floor boards, tiles and
    suspended-ceiling grids follow (a rotated room's walls are not along x)."""
    _, direction, _, length, _, _ = room_frame(room)
    return direction[jnp.argmax(length)]


def _plan_coordinates(xy: Float[Array, "*n 2"], room: Room, axis: Float[Array, 2]) -> Float[Array, "*n 2"]:
    """Camera-frame points in the world frame's plan coordinates along ``axis``
    (the coordinates the floor and ceiling textures use)."""
    world = xy + room.camera_position[:2]
    return jnp.stack([world @ axis, world @ perpendicular(axis)], -1)


def _from_plan_coordinates(ab: Float[Array, "*n 2"], room: Room, axis: Float[Array, 2]) -> Float[Array, "*n 2"]:
    return ab[..., :1] * axis + ab[..., 1:] * perpendicular(axis) - room.camera_position[:2]


def _blocked_below(footprints: Footprints, bottom, standing: Boxes) -> Array:
    """Per candidate: whether a box standing under its footprint reaches within 10 cm of its bottom."""
    obstacles = Rectangle(standing.centre[:, :2], standing.half_size[:, :2], standing.rotation)
    tops = standing.centre[:, 2] + standing.half_size[:, 2]

    def one(rectangle, low):
        hits = jax.vmap(rectangles_overlap, in_axes=(0, None, None))(obstacles, rectangle, 0.05)
        return jnp.any(hits & standing.mask & (tops > low - 0.1))

    return jax.vmap(one)(footprints.rectangles, bottom)


def _panel_shape(uniform, centre_ab, grid_scale, is_grid):
    """Half size and (plan-coordinate) centre of a light panel: 0.6 x 0.6, 1.2 x 0.3
    or 1.2 x 0.6 m; in a suspended ceiling one or two whole grid cells, snapped to the grid."""
    free = jnp.array([[0.3, 0.3], [0.6, 0.15], [0.6, 0.3]])[jnp.minimum(jnp.floor(3 * uniform), 2).astype(jnp.int32)]
    cells = jnp.where(uniform < 0.6, jnp.array([1.0, 1.0]), jnp.array([2.0, 1.0]))
    # A one-cell side is centred in a cell, a two-cell side on a grid line.
    snapped = jnp.where(
        cells == 1.0,
        (jnp.floor(centre_ab / grid_scale) + 0.5) * grid_scale,
        jnp.round(centre_ab / grid_scale) * grid_scale,
    )
    half = jnp.where(is_grid, cells * grid_scale / 2 - 0.015, free)
    return half, jnp.where(is_grid, snapped, centre_ab)


def _lamp_parts(kind, centre, reach, axis, ceiling, uniform):
    """The LAMP_PARTS boxes of one ceiling light (centres (LAMP_PARTS, 3), half sizes,
    rotations, which are emissive, mask) and its point light's height.

    ``reach`` is the lamp's half width (a fan's blade length)."""
    thickness = between(uniform[0], 0.04, 0.12)
    drop = between(uniform[1], 0.3, 0.9)
    shade_height = between(uniform[2], 0.12, 0.25)
    yaw = 2 * math.pi * uniform[3]
    blade_a, blade_b = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)]), jnp.stack([-jnp.sin(yaw), jnp.cos(yaw)])
    flat = jnp.array([1.0, 0.0])
    pendant_bottom = ceiling - drop
    bowl_bottom = ceiling - 0.2 - 0.5 * drop
    # Rows: (centre z, half x, half y, half z, rotation, emissive), one per part.
    flush = [(ceiling - thickness / 2, reach, reach, thickness / 2, axis, True)]
    cord = (drop - shade_height) / 2
    pendant = [
        (pendant_bottom + shade_height / 2, reach, reach, shade_height / 2, axis, True),
        (ceiling - cord, 0.006, 0.006, cord, flat, False),
    ]
    rod = (ceiling - bowl_bottom - 0.08) / 2
    fan = [
        (bowl_bottom + 0.04, 0.1, 0.1, 0.04, axis, True),
        (ceiling - rod, 0.02, 0.02, rod, flat, False),
        (bowl_bottom + 0.1, reach, 0.065, 0.008, blade_a, False),
        (bowl_bottom + 0.1, reach, 0.065, 0.008, blade_b, False),
    ]

    def table(rows):
        unused = (ceiling, 0.01, 0.01, 0.01, flat, False)
        mask = jnp.arange(LAMP_PARTS) < len(rows)
        rows = rows + [unused] * (LAMP_PARTS - len(rows))
        return (
            jnp.stack([jnp.asarray(r[0]) for r in rows]),
            jnp.stack([jnp.stack([jnp.asarray(r[1]), jnp.asarray(r[2]), jnp.asarray(r[3])]) for r in rows]),
            jnp.stack([jnp.asarray(r[4]) for r in rows]),
            jnp.array([r[5] for r in rows]),
            mask,
        )

    flush, pendant, fan = table(flush), table(pendant), table(fan)
    z, half, rotation, emissive, mask = (
        jnp.where(kind == LampKind.PENDANT, pendant[i], jnp.where(kind == LampKind.FAN, fan[i], flush[i]))
        for i in range(5)
    )
    light_z = jnp.where(
        kind == LampKind.PENDANT,
        pendant_bottom,
        jnp.where(kind == LampKind.FAN, bowl_bottom, ceiling - jnp.where(kind == LampKind.PANEL, 0.05, thickness)),
    )
    centre3 = jnp.concatenate([jnp.broadcast_to(centre, (LAMP_PARTS, 2)), z[:, None]], -1)
    return centre3, half, rotation, emissive, mask & (kind != LampKind.PANEL), light_z - 0.1


def ceiling_lights(key, room: Room, config, axis, ceiling: Material, standing: Boxes, overhead: Footprints):
    """Ceiling lights, away from walls and apart, clear of the ``standing`` boxes (furniture, door leaves) under
    the hanging ones and of the ``overhead`` footprints (beams): boxes (LAMP_PARTS per slot), their point lights
    and the flush panels.

    A room has either light panels (chance ``config.panel_probability``) or lamps,
    each flush, a pendant or a fan (``config.pendant_probability``,
    ``config.fan_probability``). In a suspended ceiling the panels fill grid cells.
    """
    slots = config.lamp_slots
    n = slots * config.candidates_per_slot * 2
    u = jax.random.uniform(key, (n, 6))
    v = jax.random.uniform(jax.random.fold_in(key, 1), (slots, 11))
    panel_room = v[0, 9] < config.panel_probability
    _, _, _, _, low_xy, high_xy = room_frame(room)
    centre = between(u[:, :2], low_xy, high_xy)
    kind = jnp.where(
        panel_room,
        LampKind.PANEL,
        jnp.where(
            u[:, 2] < config.pendant_probability,
            LampKind.PENDANT,
            jnp.where(u[:, 2] < config.pendant_probability + config.fan_probability, LampKind.FAN, LampKind.FLUSH),
        ),
    ).astype(jnp.int32)
    is_grid = ceiling.pattern == Pattern.GRID
    panel_half, panel_ab = jax.vmap(_panel_shape, in_axes=(0, 0, None, None))(
        u[:, 3], _plan_coordinates(centre, room, axis), ceiling.scale, is_grid
    )
    reach = jnp.where(kind == LampKind.FAN, between(u[:, 3], 0.5, 0.65), between(u[:, 3], 0.12, 0.3))
    is_panel = (kind == LampKind.PANEL)[:, None]
    centre = jnp.where(is_panel, _from_plan_coordinates(panel_ab, room, axis), centre)
    half = jnp.where(is_panel, panel_half, reach[:, None] * jnp.ones((1, 2)))
    rotation = jnp.broadcast_to(axis, (n, 2))
    margin = jnp.where(kind == LampKind.PANEL, 0.3 + jnp.max(half, -1), 0.6 + 1.5 * reach)
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(centre, room.corners, room.mask)
    away = jax.vmap(distance_to_walls, in_axes=(0, None, None))(centre, room.corners, room.mask) > margin
    # A hanging light's lowest point: 0.9 m below the ceiling at most, 0.4 m above the camera at least.
    bottom = jnp.where(
        kind == LampKind.PENDANT,
        room.ceiling_height - 0.9,
        jnp.where(kind == LampKind.FAN, room.ceiling_height - 0.65, room.ceiling_height),
    )
    candidates = Footprints(centre, half, rotation, inside & away & (bottom > 0.4))
    clear = ~_blocked_below(candidates, bottom, standing)
    candidates = Footprints(centre, half, rotation, candidates.mask & clear)
    chosen, filled = pack_footprints(candidates, slots, overhead, 0.8)
    filled = filled & (jnp.arange(slots) <= jnp.floor(v[0, 10] * slots) + panel_room)
    kind, centre, half, reach = kind[chosen], centre[chosen], half[chosen], reach[chosen]
    centre3, half3, rotation3, emissive, mask, light_z = jax.vmap(_lamp_parts, in_axes=(0, 0, 0, None, None, 0))(
        kind, centre, reach, axis, room.ceiling_height, v[:, :4]
    )
    power = between(v[:, 7:8], 1.5, 5.0)
    tint = jax.vmap(lambda w: colour_in_hsv_box(w, (0.05, 0.15), (0.0, 0.35), (1.0, 1.0)))(v[:, 4:7])
    fittings = jnp.where(v[:, 8:9] < 0.5, 0.9, 0.25) * jnp.ones((1, 3))
    colour = jnp.where(emissive[..., None], 1.0, fittings[:, None, :])
    boxes = Boxes(
        centre=centre3.reshape(-1, 3),
        half_size=half3.reshape(-1, 3),
        rotation=rotation3.reshape(-1, 2),
        material=Material(
            jnp.full(slots * LAMP_PARTS, Pattern.PAINT, jnp.int32),
            colour.reshape(-1, 3),
            colour.reshape(-1, 3),
            jnp.ones(slots * LAMP_PARTS),
        ),
        emission=(jnp.where(emissive[..., None], 2.0 * tint[:, None, :], 0.0)).reshape(-1, 3),
        mask=(mask & filled[:, None]).reshape(-1),
    )
    lights = Lights(position=jnp.concatenate([centre, light_z[:, None]], -1), colour=power * tint, mask=filled)
    panels = Panels(
        centre=centre,
        half_size=half,
        rotation=jnp.broadcast_to(axis, (slots, 2)),
        emission=4.0 * tint,
        mask=filled & (kind == LampKind.PANEL),
    )
    return boxes, lights, panels


def _decal_candidate(uniform: Float[Array, 17], room: Room):
    """One poster, picture or whiteboard: its fields and its footprint along the wall."""
    u = uniform
    kind = categorical(u[0], jnp.array([0.35, 0.45, 0.2]))
    size = jnp.stack(
        [
            jnp.stack([between(u[1], 0.4, 0.8), between(u[2], 0.55, 1.0)]),
            jnp.stack([between(u[1], 0.3, 1.2), between(u[2], 0.3, 0.9)]),
            jnp.stack([between(u[1], 1.2, 2.4), between(u[2], 0.9, 1.2)]),
        ]
    )[kind]
    width, height = size[0], size[1]
    bottom = jnp.where(kind == DecalKind.WHITEBOARD, between(u[3], 0.8, 1.0), between(u[3], 1.35, 1.75) - height / 2)
    # Above the skirting, below the ceiling (the layout's edges stay wall pixels).
    bottom = jnp.maximum(bottom, 0.3)
    height = jnp.minimum(height, room.ceiling_height - room.floor_height - 0.2 - bottom)
    wall, along, fits, start, direction, normal = wall_position(u[4:6], room, width, 0.1)
    poster = colour_in_hsv_box(u[6:9], (0.0, 1.0), (0.4, 0.9), (0.3, 0.95))
    frames = jnp.stack(
        [jnp.full(3, 0.95), colour_in_hsv_box(u[9:12], (0.05, 0.12), (0.0, 0.7), (0.05, 0.8)), jnp.full(3, 0.7)]
    )
    fields = dict(
        wall=wall.astype(jnp.int32),
        span=jnp.stack([along, along + width]),
        z_range=room.floor_height + jnp.stack([bottom, bottom + height]),
        kind=kind.astype(jnp.int32),
        colour_a=jnp.where(kind == DecalKind.WHITEBOARD, jnp.full(3, 0.93), poster),
        colour_b=colour_in_hsv_box(u[12:15], (0.0, 1.0), (0.1, 0.8), (0.1, 0.9)),
        frame_colour=frames[kind],
        frame_width=jnp.stack([0.015, between(u[15], 0.03, 0.07), 0.02])[kind],
    )
    centre = start + (along + width / 2) * direction + 0.05 * normal
    footprint = Footprints(centre, jnp.stack([width / 2, 0.05]), direction, fits & (height > 0.2))
    return fields, footprint


def random_decals(key, room: Room, config, obstacles: Footprints) -> Decals:
    """Posters, pictures and whiteboards on the walls, apart and off the doors and
    windows (``obstacles``); each slot is wanted with chance ``config.decal_probability``."""
    n = config.decal_slots * config.candidates_per_slot
    u = jax.random.uniform(key, (n + 1, 17))
    fields, footprints = jax.vmap(lambda w: _decal_candidate(w, room))(u[:n])
    chosen, filled = pack_footprints(footprints, config.decal_slots, obstacles, 0.2)
    filled = filled & (u[n, : config.decal_slots] < config.decal_probability)
    return Decals(**{name: value[chosen] for name, value in fields.items()}, mask=filled)


def sun_patches(key, room: Room, openings: Openings, config) -> SunPatches:
    """Sunlight through up to ``config.sun_slots`` windows (chance
    ``config.sun_probability`` that the sun shines in a scene): one sun,
    20-55 degrees high, within 50 degrees of facing the first window; the other
    windows it reaches light patches too."""
    u = jax.random.uniform(key, (7,))
    start, direction, normal, _, _, _ = room_frame(room)
    windows = openings.mask & openings.is_window
    first = jnp.argmax(windows)
    turn = between(u[1], -0.87, 0.87)
    elevation = between(u[2], 0.35, 0.96)
    n = normal[openings.wall[first]]
    horizontal = jnp.cos(turn) * n + jnp.sin(turn) * perpendicular(n)
    sun = jnp.concatenate([jnp.cos(elevation) * horizontal, -jnp.sin(elevation)[None]])
    lit = windows & (normal[openings.wall] @ horizontal > 0.25) & (u[0] < config.sun_probability)
    # The first lit windows (a stable sort keeps the slot order).
    order = jnp.argsort(~lit, stable=True)[: config.sun_slots]
    wall = openings.wall[order]
    colour = between(u[3], 1.0, 2.5) * colour_in_hsv_box(u[4:7], (0.08, 0.13), (0.1, 0.4), (1.0, 1.0))
    return SunPatches(
        origin=start[wall],
        axis=direction[wall],
        normal=normal[wall],
        span=openings.span[order],
        z_range=openings.z_range[order],
        direction=jnp.broadcast_to(sun, (config.sun_slots, 3)),
        colour=jnp.broadcast_to(colour, (config.sun_slots, 3)),
        mask=lit[order],
    )


def door_leaves(key, room: Room, openings: Openings, doorways: Doorways, config) -> Boxes:
    """The leaves of open doors (one box per opening slot, chance
    ``config.door_leaf_probability``; passages have none): hinged at one side of the doorway and
    swung 30-90 degrees into the room, inside the keep-out area in front of the
    door, clear of the camera and of the leaves before them."""
    d = openings.mask.shape[0]
    u = jax.random.uniform(key, (d, 3))
    start, direction, normal, _, _, _ = room_frame(room)
    wall_start, wall_direction, wall_normal = start[openings.wall], direction[openings.wall], normal[openings.wall]
    width = openings.span[:, 1] - openings.span[:, 0] - 2 * FRAME_WIDTH
    at_start = u[:, 0] < 0.5
    hinge_along = jnp.where(at_start, openings.span[:, 0] + FRAME_WIDTH, openings.span[:, 1] - FRAME_WIDTH)
    hinge = wall_start + hinge_along[:, None] * wall_direction
    angle = between(u[:, 1:2], math.pi / 6, math.pi / 2)
    towards = jnp.where(at_start[:, None], wall_direction, -wall_direction)
    leaf_axis = jnp.cos(angle) * towards + jnp.sin(angle) * wall_normal
    # 3 cm off the wall plane, so that the 4 cm leaf's back corner stays in the room.
    centre = hinge + (width[:, None] / 2) * leaf_axis + 0.03 * wall_normal
    half = jnp.stack([width / 2, jnp.full(d, 0.02)], -1)
    bottom = openings.z_range[:, 0] + 0.01
    top = openings.z_range[:, 1] - FRAME_WIDTH
    valid = (
        openings.mask
        & doorways.is_open
        & ~doorways.is_passage
        & (u[:, 2] < config.door_leaf_probability)
        & jax.vmap(rectangle_in_room, in_axes=(0, 0, 0, None))(centre, half, leaf_axis, room)
        & (
            jax.vmap(rectangle_distance_to_point, in_axes=(None, 0, 0, 0))(jnp.zeros(2), centre, half, leaf_axis)
            > room.rc + config.camera_clearance
        )
    )
    leaves = Rectangle(centre, half, leaf_axis)
    overlap = jax.vmap(jax.vmap(rectangles_overlap, in_axes=(None, 0, None)), in_axes=(0, None, None))(
        leaves, leaves, 0.02
    )
    earlier = jnp.arange(d)[None, :] < jnp.arange(d)[:, None]
    valid = valid & ~jnp.any(overlap & earlier & valid[None, :], axis=1)
    return Boxes(
        centre=jnp.concatenate([centre, ((bottom + top) / 2)[:, None]], -1),
        half_size=jnp.concatenate([half, ((top - bottom) / 2)[:, None]], -1),
        rotation=leaf_axis,
        material=Material(jnp.full(d, Pattern.PAINT, jnp.int32), openings.colour, 0.9 * openings.colour, jnp.ones(d)),
        emission=jnp.zeros((d, 3)),
        mask=valid,
    )


def ceiling_beams(key, room: Room, config, axis: Float[Array, 2], ceiling: Material) -> tuple[Boxes, Footprints]:
    """Beams and dropped headers across the ceiling (``config.beam_slots`` boxes; a room has them with chance
    ``config.beam_probability``), as in garages, basements, older homes and between the parts of an open plan.

    One to ``beam_slots`` parallel beams, all along the room's plan axis or all across it, each through a random
    point of the room 0.5 m or more from its walls and from wall to wall along its line (through the walls of a
    room that is not convex, as beams run), 0.1-0.4 m wide and 0.1-0.35 m deep, its top on the ceiling, 0.3 m or
    more apart; cased in the ceiling's material or bare wood. The label's ceiling stays the room's: a beam hides
    the wall-ceiling edge where it meets a wall, as furniture hides the floor's.

    Returns:
        The beams' boxes and their plan footprints (for the hanging lights to keep clear of).
    """
    slots = config.beam_slots
    n = slots * config.candidates_per_slot
    u = jax.random.uniform(key, (n, 4))
    v = jax.random.uniform(jax.random.fold_in(key, 1), (4,))
    direction = jnp.where(v[0] < 0.5, axis, perpendicular(axis))
    _, _, _, _, low_xy, high_xy = room_frame(room)
    through = between(u[:, :2], low_xy, high_xy)
    ahead = jax.vmap(lambda p: jnp.min(ray_hits(p, direction, room.corners, room.mask)))(through)
    behind = jax.vmap(lambda p: jnp.min(ray_hits(p, -direction, room.corners, room.mask)))(through)
    spans = jnp.isfinite(ahead + behind)
    ahead, behind = jnp.where(spans, ahead, 0.0), jnp.where(spans, behind, 0.0)
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(through, room.corners, room.mask)
    away = jax.vmap(distance_to_walls, in_axes=(0, None, None))(through, room.corners, room.mask) > 0.5
    width, depth = between(u[:, 2], 0.1, 0.4), between(u[:, 3], 0.1, 0.35)
    candidates = Footprints(
        centre=through + ((ahead - behind) / 2)[:, None] * direction,
        half_size=jnp.stack([(ahead + behind) / 2, width / 2], -1),
        rotation=jnp.broadcast_to(direction, (n, 2)),
        mask=inside & away & spans & (room.ceiling_height - depth > 0.4),
    )
    chosen, filled = pack_footprints(candidates, slots, no_footprints(), 0.3)
    wanted = (v[1] < config.beam_probability) & (jnp.arange(slots) <= jnp.floor(v[2] * slots))
    footprints = Footprints(
        candidates.centre[chosen], candidates.half_size[chosen], candidates.rotation[chosen], filled & wanted
    )
    wood, _ = piece_materials(jax.random.fold_in(key, 2), jnp.array(False))
    cased = Material(jnp.int32(Pattern.PAINT), ceiling.colour_a, ceiling.colour_a, ceiling.scale)
    material = jax.tree.map(
        lambda c, w: jnp.broadcast_to(jnp.where(v[3] < 0.6, c, w), (slots, *jnp.shape(c))), cased, wood
    )
    beams = Boxes(
        centre=jnp.concatenate([footprints.centre, (room.ceiling_height - depth[chosen] / 2)[:, None]], -1),
        half_size=jnp.concatenate([footprints.half_size, (depth[chosen] / 2)[:, None]], -1),
        rotation=footprints.rotation,
        material=material,
        emission=jnp.zeros((slots, 3)),
        mask=footprints.mask,
    )
    return beams, footprints
