"""Furnished, lit scenes around a synthetic room (paper Section 5.1, dataset).

A :class:`Scene` is a :class:`~ncjax.Room` plus what the paper's generator adds
to it: furniture from a pool of types, placed either against a wall at a fixed
orientation (beds, desks, wardrobes, TV units, shelves) or free-standing at
any orientation (chairs, sofas, tables, carpets), never overlapping one
another and never over the camera; doors and windows drawn on walls; ceiling
lamps with point lights; skirting boards; procedural materials for the floor,
walls, ceiling and furniture, and an ambient light.

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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, PRNGKeyArray

from ._materials import Material, Pattern, colour_in_hsv_box
from ._rooms import Room, _segments_cross, distance_to_walls, point_in_polygon, polygon_edges, room_walls


@dataclasses.dataclass(frozen=True)
class _FurnitureType:
    """A furniture template: size ranges (width along its front, depth, height),
    and parts as boxes in fractions of the size, ``(x0, x1, y0, y1, z0, z1)``
    with y = 0 at the back (against the wall) and z = 0 on the floor; the last
    flag picks the piece's secondary material."""

    name: str
    against_wall: bool
    size_low: tuple[float, float, float]
    size_high: tuple[float, float, float]
    parts: tuple[tuple[float, float, float, float, float, float, bool], ...]
    fabric: bool = False
    weight: float = 1.0
    may_cover_camera: bool = False


_LEGS = tuple((x0, x0 + 0.08, y0, y0 + 0.08, 0.0, 0.94, True) for x0 in (0.02, 0.9) for y0 in (0.02, 0.9))

FURNITURE_TYPES: tuple[_FurnitureType, ...] = (
    _FurnitureType(
        "bed", True, (1.0, 1.9, 0.9), (1.9, 2.15, 1.2),
        ((0.0, 1.0, 0.03, 1.0, 0.0, 0.4, True), (0.03, 0.97, 0.05, 0.98, 0.4, 0.55, False),
         (0.0, 1.0, 0.0, 0.04, 0.0, 1.0, True), (0.12, 0.88, 0.06, 0.2, 0.55, 0.65, False)),
        fabric=True, weight=1.0,
    ),
    _FurnitureType(
        "wardrobe", True, (0.8, 0.5, 1.8), (2.0, 0.65, 2.3),
        ((0.0, 1.0, 0.0, 0.96, 0.0, 1.0, False), (0.01, 0.495, 0.96, 1.0, 0.04, 0.98, True),
         (0.505, 0.99, 0.96, 1.0, 0.04, 0.98, True)),
        weight=1.0,
    ),
    _FurnitureType(
        "desk", True, (1.0, 0.55, 0.72), (1.6, 0.8, 0.78),
        ((0.0, 1.0, 0.0, 1.0, 0.95, 1.0, False), (0.0, 0.04, 0.0, 1.0, 0.0, 0.95, True),
         (0.96, 1.0, 0.0, 1.0, 0.0, 0.95, True), (0.04, 0.96, 0.0, 0.05, 0.45, 0.95, True)),
        weight=1.0,
    ),
    _FurnitureType(
        "tv unit", True, (1.2, 0.35, 1.1), (2.0, 0.5, 1.4),
        ((0.0, 1.0, 0.0, 1.0, 0.0, 0.4, False), (0.15, 0.85, 0.25, 0.35, 0.5, 1.0, True),
         (0.45, 0.55, 0.25, 0.35, 0.4, 0.5, True)),
        weight=0.7,
    ),
    _FurnitureType(
        "shelves", True, (0.6, 0.3, 1.5), (1.2, 0.4, 2.2),
        ((0.0, 0.05, 0.0, 1.0, 0.0, 1.0, False), (0.95, 1.0, 0.0, 1.0, 0.0, 1.0, False),
         (0.05, 0.95, 0.0, 0.05, 0.0, 1.0, True), (0.05, 0.95, 0.0, 1.0, 0.0, 0.04, False),
         (0.05, 0.95, 0.0, 1.0, 0.48, 0.52, False), (0.05, 0.95, 0.0, 1.0, 0.96, 1.0, False)),
        weight=0.7,
    ),
    _FurnitureType(
        "sofa", False, (1.6, 0.8, 0.75), (2.4, 1.0, 0.9),
        ((0.0, 1.0, 0.2, 1.0, 0.0, 0.5, False), (0.0, 1.0, 0.0, 0.25, 0.0, 1.0, False),
         (0.0, 0.1, 0.2, 1.0, 0.0, 0.7, True), (0.9, 1.0, 0.2, 1.0, 0.0, 0.7, True)),
        fabric=True, weight=1.0,
    ),
    _FurnitureType(
        "table", False, (0.8, 0.7, 0.72), (1.8, 1.0, 0.78),
        ((0.0, 1.0, 0.0, 1.0, 0.94, 1.0, False),) + _LEGS,
        weight=1.0,
    ),
    _FurnitureType(
        "chair", False, (0.42, 0.42, 0.85), (0.5, 0.5, 1.0),
        ((0.0, 1.0, 0.0, 1.0, 0.45, 0.5, False), (0.0, 1.0, 0.0, 0.08, 0.5, 1.0, False))
        + tuple((x0, x0 + 0.1, y0, y0 + 0.1, 0.0, 0.45, True) for x0 in (0.0, 0.9) for y0 in (0.0, 0.9)),
        weight=1.5,
    ),
    _FurnitureType(
        "carpet", False, (1.2, 0.8, 0.01), (3.0, 2.0, 0.02),
        ((0.0, 1.0, 0.0, 1.0, 0.0, 1.0, False),),
        fabric=True, weight=0.8, may_cover_camera=True,
    ),
    _FurnitureType(
        "cabinet", False, (0.4, 0.4, 0.45), (0.9, 0.6, 1.0),
        ((0.0, 1.0, 0.0, 0.97, 0.0, 1.0, False), (0.03, 0.97, 0.97, 1.0, 0.05, 0.95, True)),
        weight=0.8,
    ),
)
PARTS_PER_PIECE = max(len(t.parts) for t in FURNITURE_TYPES)


def _template_arrays():
    parts = np.zeros((len(FURNITURE_TYPES), PARTS_PER_PIECE, 6), np.float32)
    secondary = np.zeros((len(FURNITURE_TYPES), PARTS_PER_PIECE), bool)
    mask = np.zeros((len(FURNITURE_TYPES), PARTS_PER_PIECE), bool)
    for t, kind in enumerate(FURNITURE_TYPES):
        for p, part in enumerate(kind.parts):
            parts[t, p], secondary[t, p], mask[t, p] = part[:6], part[6], True
    return dict(
        parts=parts,
        secondary=secondary,
        part_mask=mask,
        size_low=np.array([t.size_low for t in FURNITURE_TYPES], np.float32),
        size_high=np.array([t.size_high for t in FURNITURE_TYPES], np.float32),
        against_wall=np.array([t.against_wall for t in FURNITURE_TYPES]),
        fabric=np.array([t.fabric for t in FURNITURE_TYPES]),
        weight=np.array([t.weight for t in FURNITURE_TYPES], np.float32),
        may_cover_camera=np.array([t.may_cover_camera for t in FURNITURE_TYPES]),
    )


_TEMPLATES = _template_arrays()


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """Static configuration of :func:`random_scene` (hashable: a jit static argument).

    Attributes:
        furniture_slots: F, the most pieces of furniture (each up to
            :data:`PARTS_PER_PIECE` boxes).
        lamp_slots: L, the most ceiling lamps (each a box and a point light).
        opening_slots: D, the most doors and windows.
        candidates_per_slot: placement candidates drawn per slot (rejection sampling).
        camera_clearance: horizontal distance kept between the circle of optical
            centres and any furniture except carpets, metres.
        furniture_probability: chance that each furniture slot is wanted at all
            (some rooms are sparse, some crowded).
        door_probability: chance that an opening is a door rather than a window.
    """

    furniture_slots: int = 8
    lamp_slots: int = 3
    opening_slots: int = 5
    candidates_per_slot: int = 3
    camera_clearance: float = 0.3
    furniture_probability: float = 0.75
    door_probability: float = 0.35

    def __post_init__(self):
        for name in ("furniture_slots", "lamp_slots", "opening_slots", "candidates_per_slot"):
            if int(getattr(self, name)) != getattr(self, name) or getattr(self, name) < 1:
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)!r}")
        if self.camera_clearance < 0:
            raise ValueError(f"camera_clearance must be >= 0, got {self.camera_clearance}")
        for name in ("furniture_probability", "door_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {getattr(self, name)}")

    @property
    def box_slots(self) -> int:
        """B, the box capacity: furniture parts then lamps."""
        return self.furniture_slots * PARTS_PER_PIECE + self.lamp_slots


class Boxes(eqx.Module):
    """Boxes that rotate about z (all fields traced, leading axis B).

    Attributes:
        centre: (B, 3) camera frame, metres.
        half_size: (B, 3) half extents along the box's own axes.
        rotation: (B, 2) ``(cos, sin)`` of the yaw: the box's x axis in the camera frame.
        material: a :class:`~ncjax._materials.Material` with leading axis B.
        emission: (B, 3) emitted radiance (lamps), 0 for furniture.
        mask: (B,) which slots hold a box.
    """

    centre: Float[Array, "B 3"]
    half_size: Float[Array, "B 3"]
    rotation: Float[Array, "B 2"]
    material: Material
    emission: Float[Array, "B 3"]
    mask: Bool[Array, " B"]


class Openings(eqx.Module):
    """Doors and windows, rectangles on walls (leading axis D).

    Attributes:
        wall: (D,) index of the wall they are on.
        span: (D, 2) start and end along the wall from its first corner, metres.
        z_range: (D, 2) bottom and top, camera frame.
        is_window: (D,) window (glass, emits daylight) or door.
        colour: (D, 3) leaf (door) or sky (window) colour; frame_colour (D, 3).
        mask: (D,) which slots hold an opening.
    """

    wall: Int[Array, " D"]
    span: Float[Array, "D 2"]
    z_range: Float[Array, "D 2"]
    is_window: Bool[Array, " D"]
    colour: Float[Array, "D 3"]
    frame_colour: Float[Array, "D 3"]
    mask: Bool[Array, " D"]


class Lights(eqx.Module):
    """Point lights (leading axis L): position (L, 3), radiant colour (L, 3), mask (L,)."""

    position: Float[Array, "L 3"]
    colour: Float[Array, "L 3"]
    mask: Bool[Array, " L"]


class Scene(eqx.Module):
    """A furnished, lit room (all fields traced; batch with ``jax.vmap``).

    Attributes:
        room: the :class:`~ncjax.Room` (camera frame).
        boxes: furniture parts then lamps, :class:`Boxes`.
        openings: doors and windows, :class:`Openings`.
        lights: :class:`Lights`.
        floor, ceiling, walls: their :class:`~ncjax._materials.Material`.
        skirting_height: height of the skirting boards above the floor (0: none), metres.
        skirting_colour: (3,).
        ambient: (3,) ambient radiance.
        ambient_direction: (3,) unit vector the ambient light comes from most.
        seed: integer that decorrelates the texture noise of different scenes.
    """

    room: Room
    boxes: Boxes
    openings: Openings
    lights: Lights
    floor: Material
    ceiling: Material
    walls: Material
    skirting_height: Float[Array, ""]
    skirting_colour: Float[Array, "3"]
    ambient: Float[Array, "3"]
    ambient_direction: Float[Array, "3"]
    seed: Int[Array, ""]


# ----------------------------------------------------------------- 2D rectangles


def _perpendicular(v: Float[Array, "... 2"]) -> Float[Array, "... 2"]:
    return jnp.stack([-v[..., 1], v[..., 0]], -1)


def rectangle_corners(
    centre: Float[Array, "2"], half_size: Float[Array, "2"], rotation: Float[Array, "2"]
) -> Float[Array, "4 2"]:
    """Corners of a rotated rectangle (counter-clockwise)."""
    signs = jnp.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = signs * half_size
    return centre + local[:, :1] * rotation + local[:, 1:] * _perpendicular(rotation)


def rectangles_overlap(
    centre_a: Float[Array, "2"],
    half_a: Float[Array, "2"],
    rotation_a: Float[Array, "2"],
    centre_b: Float[Array, "2"],
    half_b: Float[Array, "2"],
    rotation_b: Float[Array, "2"],
    gap: Float[ArrayLike, ""] = 0.0,
) -> Bool[Array, ""]:
    """Whether two rotated rectangles come closer than ``gap`` along some axis
    (separating-axis theorem on the four edge normals)."""
    axes = jnp.stack([rotation_a, _perpendicular(rotation_a), rotation_b, _perpendicular(rotation_b)])

    def radius(half, rotation):
        return jnp.abs(half[0] * axes @ rotation) + jnp.abs(half[1] * axes @ _perpendicular(rotation))

    separation = jnp.abs(axes @ (centre_b - centre_a))
    return ~jnp.any(separation > radius(half_a, rotation_a) + radius(half_b, rotation_b) + gap)


def rectangle_distance_to_point(
    point: Float[Array, "2"], centre: Float[Array, "2"], half_size: Float[Array, "2"], rotation: Float[Array, "2"]
) -> Float[Array, ""]:
    """Distance from a point to a rotated rectangle (0 inside)."""
    offset = point - centre
    local = jnp.stack([offset @ rotation, offset @ _perpendicular(rotation)])
    outside = jnp.maximum(jnp.abs(local) - half_size, 0.0)
    return jnp.sqrt(jnp.sum(outside**2))


def rectangle_in_room(
    centre: Float[Array, "2"], half_size: Float[Array, "2"], rotation: Float[Array, "2"], room: Room
) -> Bool[Array, ""]:
    """The rectangle lies inside the room's floor plan: its corners are inside and
    no wall crosses its edges (a reflex corner of the room cannot poke in)."""
    corners = rectangle_corners(centre, half_size, rotation)
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(corners, room.corners, room.mask)
    walls = polygon_edges(room.corners, room.mask)
    sides = jnp.stack([corners, jnp.roll(corners, -1, axis=0)], 1)
    crossing = _segments_cross(sides[:, None, 0], sides[:, None, 1], walls[None, :, 0], walls[None, :, 1])
    return jnp.all(inside) & ~jnp.any(crossing & room.mask[None, :])


class _Footprints(eqx.Module):
    """Rotated rectangles (one, or a leading batch axis) and which are valid."""

    centre: Float[Array, "*n 2"]
    half_size: Float[Array, "*n 2"]
    rotation: Float[Array, "*n 2"]
    mask: Bool[Array, "*n"]


def _pack(candidates: _Footprints, capacity: int, obstacles: _Footprints, gap: float):
    """Greedy rejection sampling: accept the valid candidates in order while they
    overlap neither an accepted one nor an obstacle, up to ``capacity``.

    Returns ``(chosen, chosen_mask)``: candidate indices (capacity,) and which
    slots were filled.
    """

    def overlaps_any(footprints, centre, half, rotation):
        hits = jax.vmap(rectangles_overlap, in_axes=(0, 0, 0, None, None, None, None))(
            footprints.centre, footprints.half_size, footprints.rotation, centre, half, rotation, gap
        )
        return jnp.any(hits & footprints.mask)

    blocked = jax.vmap(lambda c, h, r: overlaps_any(obstacles, c, h, r))(
        candidates.centre, candidates.half_size, candidates.rotation
    )

    def step(carry, inputs):
        accepted, chosen, count = carry
        index, centre, half, rotation, valid, is_blocked = inputs
        take = valid & ~is_blocked & (count < capacity) & ~overlaps_any(accepted, centre, half, rotation)
        slot = jnp.minimum(count, capacity - 1)
        accepted = jax.tree.map(
            lambda field, value: field.at[slot].set(jnp.where(take, value, field[slot])),
            accepted,
            _Footprints(centre, half, rotation, jnp.array(True)),
        )
        chosen = chosen.at[slot].set(jnp.where(take, index, chosen[slot]))
        return (accepted, chosen, count + take), None

    empty = _Footprints(
        jnp.zeros((capacity, 2)), jnp.zeros((capacity, 2)), jnp.tile(jnp.array([1.0, 0.0]), (capacity, 1)),
        jnp.zeros(capacity, bool),
    )
    n = candidates.mask.shape[0]
    inputs = (jnp.arange(n), candidates.centre, candidates.half_size, candidates.rotation, candidates.mask, blocked)
    (accepted, chosen, _), _ = jax.lax.scan(step, (empty, jnp.zeros(capacity, jnp.int32), jnp.array(0)), inputs)
    return chosen, accepted.mask


# ---------------------------------------------------------------- generation
# Each generator draws ONE array of uniforms and reads its numbers from it: every
# jax.random call adds a threefry instance to the compiled program, and dozens of
# them made the scene generator take a minute to compile.


def _between(uniform: Array, low, high) -> Array:
    return low + uniform * (jnp.asarray(high) - low)


def _categorical(uniform: Float[Array, ""], weights: Float[Array, " n"]) -> Int[Array, ""]:
    """Index drawn with probability proportional to ``weights`` (inverse CDF)."""
    cumulative = jnp.cumsum(weights)
    return jnp.minimum(jnp.sum(uniform * cumulative[-1] >= cumulative), weights.shape[0] - 1)


def _room_frame(room: Room):
    """Wall starts, unit directions, inward normals and lengths (K each), and the
    room's bounding box."""
    direction, _, _, _ = room_walls(room)
    edges = polygon_edges(room.corners, room.mask)
    length = jnp.where(room.mask, jnp.linalg.norm(edges[:, 1] - edges[:, 0], axis=-1), 0.0)
    # Counter-clockwise polygon: the interior is to the left of each wall.
    normal = _perpendicular(direction)
    valid = jnp.where(room.mask[:, None], room.corners, room.corners[:1])
    return edges[:, 0], direction, normal, length, jnp.min(valid, 0), jnp.max(valid, 0)


def _wall_position(uniform: Float[Array, "2"], room: Room, width: Float[Array, ""], margin: float):
    """A wall (chosen with probability proportional to its length) and a start
    position along it that fits ``width`` with ``margin`` at both ends.

    Returns ``(wall, along, fits, wall_start, wall_direction, inward_normal)``.
    """
    start, direction, normal, length, _, _ = _room_frame(room)
    wall = _categorical(uniform[0], length)
    room_left = length[wall] - width - 2 * margin
    along = margin + uniform[1] * jnp.maximum(room_left, 0.0)
    return wall, along, room_left >= 0, start[wall], direction[wall], normal[wall]


def _furniture_candidate(key, room: Room, config: SceneConfig):
    """One random piece: (type, size (3,), centre (2,), rotation (2,), valid)."""
    u = jax.random.uniform(key, (11,))
    kind = _categorical(u[0], jnp.asarray(_TEMPLATES["weight"]))
    size = _between(u[1:4], jnp.asarray(_TEMPLATES["size_low"])[kind], jnp.asarray(_TEMPLATES["size_high"])[kind])
    size = size.at[2].min(room.ceiling_height - room.floor_height - 0.25)
    # Against a wall: the back 1 cm off the wall, the piece's x axis along it.
    wall, along, fits, start, direction, normal = _wall_position(u[4:6], room, size[0], 0.05)
    wall_centre = start + (along + size[0] / 2) * direction + (size[1] / 2 + 0.01) * normal
    # Free-standing: anywhere, aligned with the room (wall 0) more often than not.
    _, room_direction, _, _, low_xy, high_xy = _room_frame(room)
    free_centre = _between(u[6:8], low_xy, high_xy)
    aligned = jnp.arctan2(room_direction[0, 1], room_direction[0, 0]) + jnp.floor(4 * u[8]) * (math.pi / 2)
    angle = jnp.where(u[9] < 0.6, aligned, 2 * math.pi * u[10])
    free_rotation = jnp.stack([jnp.cos(angle), jnp.sin(angle)])
    against_wall = jnp.asarray(_TEMPLATES["against_wall"])[kind]
    centre = jnp.where(against_wall, wall_centre, free_centre)
    rotation = jnp.where(against_wall, direction, free_rotation)
    half = size[:2] / 2
    clear_of_camera = rectangle_distance_to_point(jnp.zeros(2), centre, half, rotation) > room.rc + config.camera_clearance
    valid = (
        rectangle_in_room(centre, half, rotation, room)
        & (clear_of_camera | jnp.asarray(_TEMPLATES["may_cover_camera"])[kind])
        & jnp.where(against_wall, fits, True)
    )
    return kind, size, centre, rotation, valid


def _piece_materials(key, fabric: Bool[Array, ""]):
    """Primary and secondary materials of a piece of furniture."""
    u = jax.random.uniform(key, (13,))
    wood = colour_in_hsv_box(u[0:3], (0.04, 0.11), (0.3, 0.75), (0.2, 0.75))
    painted = colour_in_hsv_box(u[3:6], (0.0, 1.0), (0.0, 0.6), (0.15, 0.95))
    cloth = colour_in_hsv_box(u[6:9], (0.0, 1.0), (0.1, 0.8), (0.15, 0.85))
    is_wood = u[9] < 0.6
    primary_colour = jnp.where(fabric, cloth, jnp.where(is_wood, wood, painted))
    primary_pattern = jnp.where(fabric, Pattern.FABRIC, jnp.where(is_wood, Pattern.WOOD, Pattern.PAINT))
    secondary_colour = jnp.where(fabric, wood, jnp.where(u[10] < 0.5, 0.6 * primary_colour, painted))
    secondary_pattern = jnp.where(fabric, Pattern.WOOD, Pattern.PAINT)
    shade = _between(u[11:13], 0.6, 0.9)
    return (
        Material(primary_pattern.astype(jnp.int32), primary_colour, shade[0] * primary_colour, jnp.array(0.3)),
        Material(secondary_pattern.astype(jnp.int32), secondary_colour, shade[1] * secondary_colour, jnp.array(0.3)),
    )


def _piece_boxes(kind, size, centre, rotation, floor_height, primary: Material, secondary: Material):
    """The boxes of one piece of furniture (PARTS_PER_PIECE of them, with a mask)."""
    parts = jnp.asarray(_TEMPLATES["parts"])[kind]
    low, high = parts[:, 0::2] * size, parts[:, 1::2] * size
    local = (low + high) / 2 - jnp.array([size[0] / 2, size[1] / 2, 0.0])
    xy = centre + local[:, :1] * rotation + local[:, 1:2] * _perpendicular(rotation)
    secondary_part = jnp.asarray(_TEMPLATES["secondary"])[kind]
    material = jax.tree.map(
        lambda a, b: jnp.where(secondary_part.reshape((-1,) + (1,) * a.ndim), b, a), primary, secondary
    )
    return Boxes(
        centre=jnp.concatenate([xy, floor_height + local[:, 2:]], -1),
        half_size=(high - low) / 2,
        rotation=jnp.broadcast_to(rotation, (PARTS_PER_PIECE, 2)),
        material=material,
        emission=jnp.zeros((PARTS_PER_PIECE, 3)),
        mask=jnp.asarray(_TEMPLATES["part_mask"])[kind],
    )


def _nothing() -> _Footprints:
    return _Footprints(jnp.zeros((1, 2)), jnp.ones((1, 2)), jnp.array([[1.0, 0.0]]), jnp.zeros(1, bool))


def _opening_candidate(key, room: Room, config: SceneConfig):
    """One door or window: its fields, its footprint on the wall and (doors) the
    keep-out area in front of it."""
    u = jax.random.uniform(key, (10,))
    is_window = u[0] >= config.door_probability
    door = jnp.stack([_between(u[1], 0.75, 1.0), 0.0, _between(u[2], 1.95, 2.15)])
    window = jnp.stack([_between(u[1], 0.6, 2.2), _between(u[2], 0.5, 1.1), _between(u[3], 0.8, 1.6)])
    width, bottom, height = jnp.where(is_window, window, door)
    height = jnp.minimum(height, room.ceiling_height - room.floor_height - 0.15 - bottom)
    wall, along, fits, start, direction, normal = _wall_position(u[4:6], room, width, 0.15)
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
    footprint = _Footprints(centre, jnp.stack([width / 2 + 0.1, 0.05]), direction, fits & (height > 0.5))
    keep_out = _Footprints(centre + 0.45 * normal, jnp.stack([width / 2, 0.45]), direction, ~is_window)
    return fields, footprint, keep_out


def _openings(key, room: Room, config: SceneConfig):
    """Doors and windows on the walls, apart; and the keep-out footprints in front of the doors."""
    key_candidates, key_count = jax.random.split(key)
    n = config.opening_slots * config.candidates_per_slot
    fields, footprints, keep_out = jax.vmap(lambda k: _opening_candidate(k, room, config))(
        jax.random.split(key_candidates, n)
    )
    chosen, filled = _pack(footprints, config.opening_slots, _nothing(), 0.3)
    wanted = 1 + jnp.floor(jax.random.uniform(key_count) * config.opening_slots)
    filled = filled & (jnp.arange(config.opening_slots) < wanted)
    openings = Openings(**{name: value[chosen] for name, value in fields.items()}, mask=filled)
    keep_out = jax.tree.map(lambda x: x[chosen], keep_out)
    return openings, eqx.tree_at(lambda f: f.mask, keep_out, keep_out.mask & filled)


def _lamps(key, room: Room, config: SceneConfig):
    """Ceiling lamps (boxes) and their point lights, away from walls and apart."""
    n = config.lamp_slots * config.candidates_per_slot * 2
    slots = config.lamp_slots
    u = jax.random.uniform(key, (n, 3))
    v = jax.random.uniform(jax.random.fold_in(key, 1), (slots, 2 + 3 + 1))
    _, room_direction, _, _, low_xy, high_xy = _room_frame(room)
    centre = _between(u[:, :2], low_xy, high_xy)
    half = _between(u[:, 2:3], 0.12, 0.3) * jnp.ones((1, 2))
    rotation = jnp.broadcast_to(room_direction[0], (n, 2))
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(centre, room.corners, room.mask)
    away = jax.vmap(distance_to_walls, in_axes=(0, None, None))(centre, room.corners, room.mask) > 0.6 + 1.5 * half[:, 0]
    chosen, filled = _pack(_Footprints(centre, half, rotation, inside & away), slots, _nothing(), 0.8)
    filled = filled & (jnp.arange(slots) <= jnp.floor(v[0, 5] * slots))
    thickness = _between(v[:, 0], 0.04, 0.12)
    power = _between(v[:, 1:2], 1.5, 5.0)
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


# Range of the pattern period (metres) per Pattern, indexed by its value.
_SCALE_RANGE = np.array(
    [[1.0, 1.0], [0.6, 2.0], [0.12, 0.22], [0.3, 0.7], [0.6, 1.0], [0.1, 0.4], [0.15, 0.35], [0.3, 0.3], [0.3, 0.3]],
    np.float32,
)


def _surface_material(uniform: Float[Array, "9"], pool: list[tuple[float, Pattern]], colour_a, colour_b) -> Material:
    """A material from a weighted pool of patterns, with its period drawn in the pattern's range.

    ``colour_a`` and ``colour_b`` map (pattern, uniforms (3,)) to a colour."""
    pattern = jnp.array([int(p) for _, p in pool], jnp.int32)[_categorical(uniform[0], jnp.array([w for w, _ in pool]))]
    low, high = jnp.asarray(_SCALE_RANGE)[pattern]
    a = colour_a(pattern, uniform[2:5])
    return Material(pattern, a, jnp.clip(colour_b(pattern, a, uniform[5:9]), 0.0, 1.0), _between(uniform[1], low, high))


def _surface_materials(key):
    """Floor, ceiling and wall materials drawn from pools (paper Section 5.1)."""
    u = jax.random.uniform(key, (3, 9))
    floor = _surface_material(
        u[0],
        [(0.45, Pattern.PLANKS), (0.25, Pattern.TILES), (0.15, Pattern.CARPET), (0.15, Pattern.PAINT)],
        lambda pattern, w: jnp.where(
            pattern == Pattern.PLANKS,
            colour_in_hsv_box(w, (0.04, 0.11), (0.3, 0.8), (0.2, 0.8)),
            colour_in_hsv_box(w, (0.0, 1.0), (0.0, 0.5), (0.15, 0.9)),
        ),
        lambda pattern, a, w: a * _between(w[0], 0.45, 1.4),
    )
    walls = _surface_material(
        u[1],
        [(0.35, Pattern.PAINT), (0.25, Pattern.PLASTER), (0.2, Pattern.STRIPES), (0.2, Pattern.DIAMONDS)],
        lambda pattern, w: colour_in_hsv_box(w, (0.0, 1.0), (0.05, 0.55), (0.45, 0.9)),
        lambda pattern, a, w: jnp.where(
            w[0] < 0.5, a * _between(w[1], 0.6, 0.9), colour_in_hsv_box(w[1:4], (0.0, 1.0), (0.0, 0.6), (0.3, 0.95))
        ),
    )
    ceiling = _surface_material(
        u[2],
        [(0.5, Pattern.PAINT), (0.3, Pattern.PLASTER), (0.2, Pattern.TILES)],
        lambda pattern, w: colour_in_hsv_box(w, (0.0, 1.0), (0.0, 0.1), (0.8, 0.98)),
        lambda pattern, a, w: 0.85 * a,
    )
    return floor, ceiling, walls


def random_scene(key: PRNGKeyArray, room: Room, config: SceneConfig = SceneConfig()) -> Scene:
    """Furnish and light ``room`` at random (paper Section 5.1), a pure function of ``key``.

    Args:
        key: a ``jax.random`` key.
        room: the room, e.g. from :func:`~ncjax.random_room` (camera frame).
        config: static settings (see :class:`SceneConfig`).

    Returns:
        A :class:`Scene`. Jit with ``config`` static, vmap over keys and rooms.
    """
    keys = jax.random.split(key, 6)
    openings, keep_out = _openings(keys[0], room, config)
    n = config.furniture_slots * config.candidates_per_slot
    kind, size, centre, rotation, valid = jax.vmap(lambda k: _furniture_candidate(k, room, config))(
        jax.random.split(keys[1], n)
    )
    chosen, filled = _pack(_Footprints(centre, size[:, :2] / 2, rotation, valid), config.furniture_slots, keep_out, 0.1)
    u = jax.random.uniform(keys[2], (config.furniture_slots + 9,))
    filled = filled & (u[: config.furniture_slots] < config.furniture_probability)
    fabric = jnp.asarray(_TEMPLATES["fabric"])[kind[chosen]]
    primary, secondary = jax.vmap(_piece_materials)(jax.random.split(keys[3], config.furniture_slots), fabric)
    pieces = jax.vmap(_piece_boxes, in_axes=(0, 0, 0, 0, None, 0, 0))(
        kind[chosen], size[chosen], centre[chosen], rotation[chosen], room.floor_height, primary, secondary
    )
    pieces = eqx.tree_at(lambda b: b.mask, pieces, pieces.mask & filled[:, None])
    pieces = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), pieces)
    lamps, lights = _lamps(keys[4], room, config)
    floor, ceiling, walls = _surface_materials(keys[5])
    extra = u[config.furniture_slots :]
    return Scene(
        room=room,
        boxes=jax.tree.map(lambda a, b: jnp.concatenate([a, b]), pieces, lamps),
        openings=openings,
        lights=lights,
        floor=floor,
        ceiling=ceiling,
        walls=walls,
        skirting_height=jnp.where(extra[0] < 0.75, _between(extra[1], 0.05, 0.14), 0.0),
        skirting_colour=jnp.where(extra[2] < 0.5, jnp.full(3, 0.92), 0.8 * floor.colour_a),
        ambient=colour_in_hsv_box(extra[3:6], (0.05, 0.6), (0.0, 0.15), (0.2, 0.5)),
        ambient_direction=jnp.array([jnp.cos(2 * math.pi * extra[7]), jnp.sin(2 * math.pi * extra[7]), 0.3]) / 1.044,
        seed=jnp.floor(extra[6] * 2**24).astype(jnp.int32),
    )
