"""Furnished, lit scenes around a synthetic room (paper Section 5.1, dataset).

A :class:`Scene` is a :class:`~ncjax.synth.Room` plus what the paper's generator adds
to it: furniture from a pool of types, placed either against a wall at a fixed
orientation (beds, desks, wardrobes, TV units, shelves) or free-standing at
any orientation (chairs, sofas, tables, carpets), never overlapping one
another and never over the camera; doors and windows drawn on walls; ceiling
lamps with point lights; skirting boards; procedural materials for the floor,
walls, ceiling and furniture, and an ambient light. The pieces of furniture are
drawn by :mod:`ncjax.synth.furniture`, the surfaces' materials by
:func:`~ncjax.synth.materials.surface_materials`.

Realistic scenes (``SceneConfig(decor=True)``) add decor
(:mod:`ncjax.synth.decor`): open doors showing a room behind them and their
leaves swung into the room; posters, pictures and whiteboards on walls;
ceiling lights of several kinds (flush lamps, pendants, fans or light panels
flush in the ceiling); suspended-ceiling grids and popcorn ceilings among the
ceiling materials; sunlight through the windows; counters and desks with
monitors among the furniture. The decor draws its random numbers from a key
of its own, so a key's room, furniture and materials are drawn the same way
with or without it, and the basic scenes (the default) stay exactly as they
are.

Everything lives in fixed-capacity arrays with masks and is a pure function of
a ``jax.random`` key (:func:`random_scene`), so scenes are generated under
``jax.jit(jax.vmap(...))``: same key, same scene. Placement is rejection
sampling with a fixed number of candidates, accepted greedily in order
(a ``lax.scan``): when the room is small, fewer pieces fit, and the masks
say so.

Coordinates are the room's camera frame (metres, z up, floor at
``room.floor_height``); a piece of furniture is a composite of up to
:data:`PARTS_PER_PIECE` boxes that can rotate about z.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from ..geometry.polygon import point_in_polygon
from .decor import LAMP_PARTS, ceiling_beams, ceiling_lights, door_leaves, plan_axis, random_decals, sun_patches
from .elements import Boxes, Decor, Doorways, Lights, Openings
from .furniture import FURNITURE_TYPES, PARTS_PER_PIECE, TEMPLATES, furniture_candidate, piece_boxes, piece_materials
from .materials import Material, Pattern, colour_in_hsv_box, surface_materials
from .placement import (
    Footprints,
    between,
    no_footprints,
    pack_footprints,
    room_frame,
    wall_position,
    wall_position_at_camera,
)
from .rooms import Room, distance_to_walls

# fold_in data of the decor's random key (far above any split count of the basic draws).
_DECOR_STREAM = 0xDEC0
_BEAM_STREAM = 0xBEA3
# fold_in data of the passage draw: its own stream, so that rooms drawn without passages stay those of earlier scenes.
_PASSAGE_STREAM = 0xDA55


def _check_furniture_weights(weights: tuple[tuple[str, float], ...]) -> None:
    """Raise on a :attr:`SceneConfig.furniture_weights` entry of an unknown type or a negative weight."""
    names = [t.name for t in FURNITURE_TYPES]
    for name, weight in weights:
        if name not in names:
            raise ValueError(f"furniture_weights: unknown type {name!r} (known: {', '.join(names)})")
        if weight < 0:
            raise ValueError(f"furniture_weights: negative weight {weight} for {name!r}")


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Static configuration of :func:`random_scene` (hashable: a jit static argument).

    Attributes:
        decor: realistic scenes: decor over the basic furnished room (see
            :mod:`ncjax.synth.scene`); the settings from ``decal_slots`` to
            ``sun_probability`` and the beams' apply to them only.
        furniture_slots: F, the most pieces of furniture (each up to
            :data:`PARTS_PER_PIECE` boxes).
        lamp_slots: L, the most ceiling lights (each a box and a point light; with
            decor, up to :data:`~ncjax.synth.decor.LAMP_PARTS` boxes or a flush panel).
        opening_slots: D, the most doors and windows.
        decal_slots: E, the most posters, pictures and whiteboards.
        sun_slots: S, the most windows the sun shines through.
        candidates_per_slot: placement candidates drawn per slot (rejection sampling).
        camera_clearance: horizontal distance kept between the circle of optical
            centres and any furniture except carpets, metres.
        furniture_probability: chance that each furniture slot is wanted at all
            (some rooms are sparse, some crowded).
        furniture_weights: ``(name, weight)`` pairs that replace the relative frequency
            of the furniture types they name (:data:`~ncjax.synth.furniture.FURNITURE_TYPES`;
            e.g. the closet shelving, which no other scene has).
        door_probability: chance that an opening is a door rather than a window.
        open_door_probability: chance that a door is open, showing the room behind it.
        door_leaf_probability: chance that an open door's leaf stands swung into the room.
        passage_probability: chance that a door is instead a wide passage to the next room
            (decor only): an opening ``passage_width_range`` wide, up to 0.05-0.4 m below the
            ceiling, with no leaf, as between the rooms of an open plan or at the mouth of a
            walk-in closet; the label's boundary stays in the wall plane across it, as
            labellers of real panoramas draw it.
        passage_width_range: width of a passage, metres.
        passage_at_camera: (decor only) the first opening is a passage in the wall nearest the
            camera, centred on the camera's foot (as wide as the wall holds): a room photographed from
            its doorway, as closets are (with :attr:`~ncjax.synth.RoomConfig.doorway_distance`).
        decal_probability: chance that each decal slot is wanted.
        panel_probability: chance that a room is lit by flush light panels
            rather than lamps.
        pendant_probability, fan_probability: chance that a lamp is a pendant, a
            ceiling fan (otherwise it is flush with the ceiling).
        suspended_ceiling_probability, stipple_ceiling_probability: chance of a
            suspended-ceiling grid, a popcorn ceiling (otherwise paint, plaster or tiles).
        sun_probability: chance that the sun shines in through the windows.
        beam_slots, beam_probability: the most beams across the ceiling (or dropped headers) and the chance that
            a room has any (:func:`~ncjax.synth.decor.ceiling_beams`; with 0, the default, a scene has no slots
            for them).
        neutral_paint_probability: chance that the walls are painted white, off-white or
            a pale grey or beige (flat paint or plaster), as in most homes: the wall meets
            a ceiling of nearly the same colour and only the shading shows the edge.
    """

    decor: bool = False
    furniture_slots: int = 8
    lamp_slots: int = 3
    opening_slots: int = 5
    decal_slots: int = 4
    sun_slots: int = 2
    candidates_per_slot: int = 3
    camera_clearance: float = 0.3
    furniture_probability: float = 0.75
    furniture_weights: tuple[tuple[str, float], ...] = ()
    door_probability: float = 0.35
    open_door_probability: float = 0.6
    door_leaf_probability: float = 0.7
    passage_probability: float = 0.0
    passage_width_range: tuple[float, float] = (1.2, 3.0)
    passage_at_camera: bool = False
    decal_probability: float = 0.6
    panel_probability: float = 0.25
    pendant_probability: float = 0.25
    fan_probability: float = 0.15
    suspended_ceiling_probability: float = 0.2
    stipple_ceiling_probability: float = 0.15
    sun_probability: float = 0.4
    neutral_paint_probability: float = 0.0
    beam_slots: int = 2
    beam_probability: float = 0.0

    def __post_init__(self):
        for name in (
            "furniture_slots",
            "lamp_slots",
            "opening_slots",
            "decal_slots",
            "sun_slots",
            "beam_slots",
            "candidates_per_slot",
        ):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.camera_clearance < 0:
            raise ValueError(f"camera_clearance must be >= 0, got {self.camera_clearance}")
        _check_furniture_weights(self.furniture_weights)
        if self.passage_at_camera and not self.decor:
            raise ValueError("passage_at_camera needs decor=True (passages are decor)")
        if not 0 < self.passage_width_range[0] <= self.passage_width_range[1]:
            raise ValueError(
                f"passage_width_range must be (low, high) with 0 < low <= high, got {self.passage_width_range}"
            )
        probabilities = (
            "furniture_probability",
            "door_probability",
            "open_door_probability",
            "door_leaf_probability",
            "passage_probability",
            "decal_probability",
            "panel_probability",
            "pendant_probability",
            "fan_probability",
            "suspended_ceiling_probability",
            "stipple_ceiling_probability",
            "sun_probability",
            "neutral_paint_probability",
            "beam_probability",
        )
        for name in probabilities:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")
        for first, second in (
            ("pendant_probability", "fan_probability"),
            ("suspended_ceiling_probability", "stipple_ceiling_probability"),
        ):
            if getattr(self, first) + getattr(self, second) > 1.0:
                raise ValueError(f"{first} + {second} must be at most 1")

    @property
    def box_slots(self) -> int:
        """B, the box capacity: furniture parts, then ceiling lights (then, with decor, door leaves, then beams
        where a room may have them)."""
        if self.decor:
            beams = self.beam_slots if self.beam_probability > 0.0 else 0
            return self.furniture_slots * PARTS_PER_PIECE + self.lamp_slots * LAMP_PARTS + self.opening_slots + beams
        return self.furniture_slots * PARTS_PER_PIECE + self.lamp_slots


class Scene(eqx.Module):
    """A furnished, lit room (all fields traced; batch with ``jax.vmap``).

    Attributes:
        room: the :class:`~ncjax.synth.Room` (camera frame).
        boxes: furniture parts, then ceiling lights (then, with decor, door leaves, then any beams), :class:`Boxes`.
        openings: doors and windows, :class:`Openings`.
        lights: :class:`Lights`.
        floor, ceiling, walls: their :class:`~ncjax.synth.materials.Material`.
        skirting_height: height of the skirting boards above the floor (0: none), metres.
        skirting_colour: (3,).
        ambient: (3,) ambient radiance.
        ambient_direction: (3,) unit vector the ambient light comes from most.
        seed: integer that decorrelates the texture noise of different scenes.
        decor: a realistic scene's :class:`~ncjax.synth.elements.Decor`; None in a
            basic scene (a static difference: the renderer compiles the decor only
            for scenes that have it).
    """

    room: Room
    boxes: Boxes
    openings: Openings
    lights: Lights
    floor: Material
    ceiling: Material
    walls: Material
    skirting_height: Float[Array, ""]
    skirting_colour: Float[Array, 3]
    ambient: Float[Array, 3]
    ambient_direction: Float[Array, 3]
    seed: Int[Array, ""]
    decor: Decor | None = None


# ---------------------------------------------------------------- generation
# Each generator draws ONE array of uniforms and reads its numbers from it: every
# jax.random call adds a threefry instance to the compiled program, and dozens of
# them made the scene generator take a minute to compile.


def _opening_candidate(key, room: Room, config: SceneConfig, at_camera: bool = False):
    """One door or window: its fields, (with decor) its doorway's, its footprint on
    the wall and (doors) the keep-out area in front of it (with decor, as deep as
    an open door's leaf is wide). With ``at_camera`` (static), a passage at the camera's foot."""
    u = jax.random.uniform(key, (10,))
    is_window = (u[0] >= config.door_probability) & (not at_camera)
    door = jnp.stack([between(u[1], 0.75, 1.0), 0.0, between(u[2], 1.95, 2.15)])
    window = jnp.stack([between(u[1], 0.6, 2.2), between(u[2], 0.5, 1.1), between(u[3], 0.8, 1.6)])
    width, bottom, height = jnp.where(is_window, window, door)
    room_height = room.ceiling_height - room.floor_height
    height = jnp.minimum(height, room_height - 0.15 - bottom)
    p = jax.random.uniform(jax.random.fold_in(key, _PASSAGE_STREAM), (3,))
    is_passage = config.decor & ~is_window & ((p[0] < config.passage_probability) | at_camera)
    passage = jnp.stack([between(p[1], *config.passage_width_range), 0.0, room_height - between(p[2], 0.05, 0.4)])
    width, bottom, height = jnp.where(is_passage, passage, jnp.stack([width, bottom, height]))
    if at_camera:
        # A closet's opening takes up nearly all of its wall.
        wall, along, width, start, direction, normal = wall_position_at_camera(room, width, 0.05)
        fits = width >= 0.5
    else:
        wall, along, fits, start, direction, normal = wall_position(u[4:6], room, width, 0.15)
    centre = start + (along + width / 2) * direction + 0.05 * normal
    colour = jnp.where(
        is_window,
        colour_in_hsv_box(u[6:9], (0.55, 0.62), (0.1, 0.45), (0.75, 1.0)),
        colour_in_hsv_box(u[6:9], (0.0, 1.0), (0.0, 0.5), (0.25, 0.95)),
    )
    fields = dict(
        wall=wall.astype(jnp.int32),
        span=jnp.stack([along, along + width]),
        z_range=room.floor_height + jnp.stack([bottom, bottom + height]),
        is_window=is_window,
        colour=colour,
        frame_colour=jnp.where(u[9] < 0.5, jnp.full(3, 0.9), 0.7 * colour),
    )
    footprint = Footprints(centre, jnp.stack([width / 2 + 0.1, 0.05]), direction, fits & (height > 0.5))
    if not config.decor:
        keep_out = Footprints(centre + 0.45 * normal, jnp.stack([width / 2, 0.45]), direction, ~is_window)
        return fields, None, footprint, keep_out
    w = jax.random.uniform(jax.random.fold_in(key, _DECOR_STREAM), (7,))
    is_open = is_passage | (~is_window & (w[0] < config.open_door_probability))
    doorway = dict(
        is_open=is_open,
        is_passage=is_passage,
        wall_thickness=between(w[1], 0.1, 0.25),
        room_depth=between(w[2], 1.2, 4.0),
        room_sides=between(w[3:5], 0.3, 2.5),
        room_ceiling=jnp.maximum(room.ceiling_height + between(w[5], -0.3, 0.3), fields["z_range"][1] + 0.1),
        room_light=between(w[6], 0.35, 1.8),
    )
    depth = jnp.where(is_open & ~is_passage, jnp.maximum(0.45, width / 2 + 0.05), 0.45)
    if at_camera:
        depth = 0.02  # the camera stands in it, and shelves reach up to a closet's opening
    keep_out = Footprints(centre + depth * normal, jnp.stack([width / 2 + 0.05, depth]), direction, ~is_window)
    return fields, doorway, footprint, keep_out


def _openings(key, room: Room, config: SceneConfig):
    """Doors and windows on the walls, apart; (with decor) their doorways, else
    None; their footprints on the walls; and the keep-out footprints in front of
    the doors."""
    key_candidates, key_count = jax.random.split(key)
    n = config.opening_slots * config.candidates_per_slot
    fields, doorways, footprints, keep_out = jax.vmap(lambda k: _opening_candidate(k, room, config))(
        jax.random.split(key_candidates, n)
    )
    if config.passage_at_camera:
        # First in line, so that the packing takes it before any other opening.
        at_camera = _opening_candidate(jax.random.fold_in(key, _PASSAGE_STREAM), room, config, at_camera=True)
        candidates = (fields, doorways, footprints, keep_out)
        fields, doorways, footprints, keep_out = jax.tree.map(
            lambda first, rest: jnp.concatenate([first[None], rest]), at_camera, candidates
        )
    chosen, filled = pack_footprints(footprints, config.opening_slots, no_footprints(), 0.3)
    wanted = 1 + jnp.floor(jax.random.uniform(key_count) * config.opening_slots)
    filled = filled & (jnp.arange(config.opening_slots) < wanted)
    openings = Openings(**{name: value[chosen] for name, value in fields.items()}, mask=filled)
    if doorways is not None:
        doorways = Doorways(**{name: value[chosen] for name, value in doorways.items()})
    footprints, keep_out = jax.tree.map(lambda x: x[chosen], (footprints, keep_out))
    footprints = eqx.tree_at(lambda f: f.mask, footprints, filled)
    return openings, doorways, footprints, eqx.tree_at(lambda f: f.mask, keep_out, keep_out.mask & filled)


def _lamps(key, room: Room, config: SceneConfig):
    """Ceiling lamps (boxes) and their point lights, away from walls and apart."""
    n = config.lamp_slots * config.candidates_per_slot * 2
    slots = config.lamp_slots
    u = jax.random.uniform(key, (n, 3))
    v = jax.random.uniform(jax.random.fold_in(key, 1), (slots, 2 + 3 + 1))
    _, room_direction, _, _, low_xy, high_xy = room_frame(room)
    centre = between(u[:, :2], low_xy, high_xy)
    half = between(u[:, 2:3], 0.12, 0.3) * jnp.ones((1, 2))
    rotation = jnp.broadcast_to(room_direction[0], (n, 2))
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(centre, room.corners, room.mask)
    away = (
        jax.vmap(distance_to_walls, in_axes=(0, None, None))(centre, room.corners, room.mask) > 0.6 + 1.5 * half[:, 0]
    )
    chosen, filled = pack_footprints(Footprints(centre, half, rotation, inside & away), slots, no_footprints(), 0.8)
    filled = filled & (jnp.arange(slots) <= jnp.floor(v[0, 5] * slots))
    thickness = between(v[:, 0], 0.04, 0.12)
    power = between(v[:, 1:2], 1.5, 5.0)
    tint = jax.vmap(lambda w: colour_in_hsv_box(w, (0.05, 0.15), (0.0, 0.35), (1.0, 1.0)))(v[:, 2:5])
    boxes = Boxes(
        centre=jnp.concatenate([centre[chosen], (room.ceiling_height - thickness / 2)[:, None]], -1),
        half_size=jnp.concatenate([half[chosen], thickness[:, None] / 2], -1),
        rotation=rotation[chosen],
        material=Material(
            jnp.full(slots, Pattern.PAINT, jnp.int32), jnp.ones((slots, 3)), jnp.ones((slots, 3)), jnp.ones(slots)
        ),
        emission=2.0 * tint,
        mask=filled,
    )
    lights = Lights(
        position=jnp.concatenate([centre[chosen], (room.ceiling_height - thickness - 0.1)[:, None]], -1),
        colour=power * tint,
        mask=filled,
    )
    return boxes, lights


class _BasicDraws(NamedTuple):
    """What a realistic scene draws as a basic one does, and its decor goes round (:func:`_decorate`)."""

    pieces: Boxes  # the furniture's boxes
    openings: Openings  # doors and windows
    doorways: Doorways
    opening_footprints: Footprints  # the doors' and windows' footprints on the walls
    floor: Material
    ceiling: Material


def _decorate(key, lamps_key, room: Room, config: SceneConfig, basic: _BasicDraws) -> tuple[Boxes, Lights, Decor]:
    """The decor of a realistic scene around its furniture, doors and windows (``basic``): all its boxes
    (furniture, ceiling lights, door leaves), its point lights and its :class:`~ncjax.synth.elements.Decor`.
    The ceiling lights are drawn from ``lamps_key`` (the basic lamps' key), the rest from ``key``."""
    pieces, openings, doorways, opening_footprints, floor, ceiling = basic
    keys = jax.random.split(key, 5)
    leaves = door_leaves(keys[0], room, openings, doorways, config)
    axis = plan_axis(room)
    beams, overhead = [], no_footprints()
    if config.beam_probability > 0.0:  # static: scenes that never have beams keep their shapes and draws
        beam_boxes, overhead = ceiling_beams(jax.random.fold_in(key, _BEAM_STREAM), room, config, axis, ceiling)
        beams = [beam_boxes]
    # Hanging lights keep clear of the furniture and door leaves under them and of the beams.
    standing = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pieces, leaves)
    lamps, lights, panels = ceiling_lights(lamps_key, room, config, axis, ceiling, standing, overhead)
    next_floor, _, next_walls = surface_materials(keys[1], config)
    # Half the rooms behind open doors continue this room's floor (open plans, corridors).
    same_floor = jax.random.uniform(keys[2]) < 0.5
    next_floor = jax.tree.map(lambda a, b: jnp.where(same_floor, a, b), floor, next_floor)
    decor = Decor(
        doorways=doorways,
        decals=random_decals(keys[3], room, config, opening_footprints),
        panels=panels,
        sun=sun_patches(keys[4], room, openings, config),
        next_floor=next_floor,
        next_walls=next_walls,
        plan_axis=axis,
    )
    return jax.tree.map(lambda *parts: jnp.concatenate(parts), pieces, lamps, leaves, *beams), lights, decor


def random_scene(key: PRNGKeyArray, room: Room, config: SceneConfig = SceneConfig()) -> Scene:
    """Furnish and light ``room`` at random (paper Section 5.1), with decor when
    ``config.decor``; a pure function of ``key``.

    Args:
        key: a ``jax.random`` key.
        room: the room, e.g. from :func:`~ncjax.synth.random_room` (camera frame).
        config: static settings (see :class:`SceneConfig`).

    Returns:
        A :class:`Scene`. Jit with ``config`` static, vmap over keys and rooms.
    """
    keys = jax.random.split(key, 6)
    openings, doorways, opening_footprints, keep_out = _openings(keys[0], room, config)
    n = config.furniture_slots * config.candidates_per_slot
    kind, size, centre, rotation, valid = jax.vmap(lambda k: furniture_candidate(k, room, config))(
        jax.random.split(keys[1], n)
    )
    chosen, filled = pack_footprints(
        Footprints(centre, size[:, :2] / 2, rotation, valid), config.furniture_slots, keep_out, 0.1
    )
    u = jax.random.uniform(keys[2], (config.furniture_slots + 9,))
    filled = filled & (u[: config.furniture_slots] < config.furniture_probability)
    fabric = jnp.asarray(TEMPLATES["fabric"])[kind[chosen]]
    materials = jax.vmap(piece_materials)(jax.random.split(keys[3], config.furniture_slots), fabric)
    pieces = jax.vmap(piece_boxes, in_axes=(0, 0, 0, 0, None, 0))(
        kind[chosen], size[chosen], centre[chosen], rotation[chosen], room.floor_height, materials
    )
    pieces = eqx.tree_at(lambda b: b.mask, pieces, pieces.mask & filled[:, None])
    pieces = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), pieces)
    floor, ceiling, walls = surface_materials(keys[5], config)
    if config.decor:
        basic = _BasicDraws(pieces, openings, doorways, opening_footprints, floor, ceiling)
        boxes, lights, decor = _decorate(jax.random.fold_in(key, _DECOR_STREAM), keys[4], room, config, basic)
    else:
        lamps, lights = _lamps(keys[4], room, config)
        boxes, decor = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pieces, lamps), None
    extra = u[config.furniture_slots :]
    return Scene(
        room=room,
        boxes=boxes,
        openings=openings,
        lights=lights,
        floor=floor,
        ceiling=ceiling,
        walls=walls,
        skirting_height=jnp.where(extra[0] < 0.75, between(extra[1], 0.05, 0.14), 0.0),
        skirting_colour=jnp.where(extra[2] < 0.5, jnp.full(3, 0.92), 0.8 * floor.colour_a),
        ambient=colour_in_hsv_box(extra[3:6], (0.05, 0.6), (0.0, 0.15), (0.2, 0.5)),
        ambient_direction=jnp.array([jnp.cos(2 * math.pi * extra[7]), jnp.sin(2 * math.pi * extra[7]), 0.3]) / 1.044,
        seed=jnp.floor(extra[6] * 2**24).astype(jnp.int32),
        decor=decor,
    )
