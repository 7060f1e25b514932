"""Furniture: its types (parts, sizes and where they stand) and random pieces of them, with their
materials and boxes (placed in a scene by :mod:`ncjax.synth.scene` with :mod:`ncjax.synth.placement`)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool

from ..geometry.polygon import perpendicular
from .elements import Boxes
from .materials import Material, Pattern, colour_in_hsv_box
from .placement import between, categorical, rectangle_distance_to_point, rectangle_in_room, room_frame, wall_position
from .rooms import Room


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
    decor: bool = False  # only in realistic scenes (``SceneConfig.decor``)


_LEGS = tuple((x0, x0 + 0.08, y0, y0 + 0.08, 0.0, 0.94, True) for x0 in (0.02, 0.9) for y0 in (0.02, 0.9))

FURNITURE_TYPES: tuple[_FurnitureType, ...] = (
    _FurnitureType(
        "bed",
        True,
        (1.0, 1.9, 0.9),
        (1.9, 2.15, 1.2),
        (
            (0.0, 1.0, 0.03, 1.0, 0.0, 0.4, True),
            (0.03, 0.97, 0.05, 0.98, 0.4, 0.55, False),
            (0.0, 1.0, 0.0, 0.04, 0.0, 1.0, True),
            (0.12, 0.88, 0.06, 0.2, 0.55, 0.65, False),
        ),
        fabric=True,
        weight=1.0,
    ),
    _FurnitureType(
        "wardrobe",
        True,
        (0.8, 0.5, 1.8),
        (2.0, 0.65, 2.3),
        (
            (0.0, 1.0, 0.0, 0.96, 0.0, 1.0, False),
            (0.01, 0.495, 0.96, 1.0, 0.04, 0.98, True),
            (0.505, 0.99, 0.96, 1.0, 0.04, 0.98, True),
        ),
        weight=1.0,
    ),
    _FurnitureType(
        "desk",
        True,
        (1.0, 0.55, 0.72),
        (1.6, 0.8, 0.78),
        (
            (0.0, 1.0, 0.0, 1.0, 0.95, 1.0, False),
            (0.0, 0.04, 0.0, 1.0, 0.0, 0.95, True),
            (0.96, 1.0, 0.0, 1.0, 0.0, 0.95, True),
            (0.04, 0.96, 0.0, 0.05, 0.45, 0.95, True),
        ),
        weight=1.0,
    ),
    _FurnitureType(
        "tv unit",
        True,
        (1.2, 0.35, 1.1),
        (2.0, 0.5, 1.4),
        (
            (0.0, 1.0, 0.0, 1.0, 0.0, 0.4, False),
            (0.15, 0.85, 0.25, 0.35, 0.5, 1.0, True),
            (0.45, 0.55, 0.25, 0.35, 0.4, 0.5, True),
        ),
        weight=0.7,
    ),
    _FurnitureType(
        "shelves",
        True,
        (0.6, 0.3, 1.5),
        (1.2, 0.4, 2.2),
        (
            (0.0, 0.05, 0.0, 1.0, 0.0, 1.0, False),
            (0.95, 1.0, 0.0, 1.0, 0.0, 1.0, False),
            (0.05, 0.95, 0.0, 0.05, 0.0, 1.0, True),
            (0.05, 0.95, 0.0, 1.0, 0.0, 0.04, False),
            (0.05, 0.95, 0.0, 1.0, 0.48, 0.52, False),
            (0.05, 0.95, 0.0, 1.0, 0.96, 1.0, False),
        ),
        weight=0.7,
    ),
    _FurnitureType(
        "sofa",
        False,
        (1.6, 0.8, 0.75),
        (2.4, 1.0, 0.9),
        (
            (0.0, 1.0, 0.2, 1.0, 0.0, 0.5, False),
            (0.0, 1.0, 0.0, 0.25, 0.0, 1.0, False),
            (0.0, 0.1, 0.2, 1.0, 0.0, 0.7, True),
            (0.9, 1.0, 0.2, 1.0, 0.0, 0.7, True),
        ),
        fabric=True,
        weight=1.0,
    ),
    _FurnitureType(
        "table",
        False,
        (0.8, 0.7, 0.72),
        (1.8, 1.0, 0.78),
        ((0.0, 1.0, 0.0, 1.0, 0.94, 1.0, False),) + _LEGS,
        weight=1.0,
    ),
    _FurnitureType(
        "chair",
        False,
        (0.42, 0.42, 0.85),
        (0.5, 0.5, 1.0),
        ((0.0, 1.0, 0.0, 1.0, 0.45, 0.5, False), (0.0, 1.0, 0.0, 0.08, 0.5, 1.0, False))
        + tuple((x0, x0 + 0.1, y0, y0 + 0.1, 0.0, 0.45, True) for x0 in (0.0, 0.9) for y0 in (0.0, 0.9)),
        weight=1.5,
    ),
    _FurnitureType(
        "carpet",
        False,
        (1.2, 0.8, 0.01),
        (3.0, 2.0, 0.02),
        ((0.0, 1.0, 0.0, 1.0, 0.0, 1.0, False),),
        fabric=True,
        weight=0.8,
        may_cover_camera=True,
    ),
    _FurnitureType(
        "cabinet",
        False,
        (0.4, 0.4, 0.45),
        (0.9, 0.6, 1.0),
        ((0.0, 1.0, 0.0, 0.97, 0.0, 1.0, False), (0.03, 0.97, 0.97, 1.0, 0.05, 0.95, True)),
        weight=0.8,
    ),
    _FurnitureType(
        "counter",
        True,
        (1.2, 0.58, 0.88),
        (3.0, 0.65, 0.95),
        (
            (0.0, 1.0, 0.0, 0.95, 0.1, 0.95, False),
            (0.0, 1.0, 0.0, 0.9, 0.0, 0.1, True),
            (0.0, 1.0, 0.0, 1.0, 0.95, 1.0, True),
            (0.01, 0.49, 0.95, 0.97, 0.15, 0.9, True),
            (0.51, 0.99, 0.95, 0.97, 0.15, 0.9, True),
        ),
        weight=0.6,
        decor=True,
    ),
    _FurnitureType(
        "desk with monitor",
        True,
        (1.1, 0.6, 0.72),
        (1.6, 0.8, 0.78),
        (
            (0.0, 1.0, 0.0, 1.0, 0.95, 1.0, False),
            (0.0, 0.04, 0.0, 1.0, 0.0, 0.95, False),
            (0.96, 1.0, 0.0, 1.0, 0.0, 0.95, False),
            (0.3, 0.7, 0.15, 0.19, 1.2, 1.65, True),
            (0.47, 0.53, 0.1, 0.16, 1.0, 1.2, True),
            (0.42, 0.58, 0.05, 0.3, 1.0, 1.02, True),
        ),
        weight=0.7,
        decor=True,
    ),
    # Walk-in closets' wall shelving (drawn only where a scene's furniture_weights ask for it): a shelf
    # at head height over a hanging rail, brackets at the ends, a shoe shelf; empty, as in homes for sale,
    # or with clothes hanging from the rail.
    _FurnitureType(
        "closet shelving",
        True,
        (0.6, 0.3, 1.6),
        (2.4, 0.45, 2.0),
        (
            (0.0, 1.0, 0.0, 1.0, 0.97, 1.0, False),
            (0.0, 1.0, 0.45, 0.52, 0.9, 0.92, False),
            (0.0, 0.02, 0.0, 0.9, 0.1, 0.97, True),
            (0.98, 1.0, 0.0, 0.9, 0.1, 0.97, True),
            (0.0, 1.0, 0.0, 0.9, 0.1, 0.12, False),
        ),
        weight=0.0,
        decor=True,
    ),
    _FurnitureType(
        "closet shelving with clothes",
        True,
        (0.6, 0.4, 1.6),
        (2.4, 0.6, 2.0),
        (
            (0.0, 1.0, 0.0, 0.75, 0.97, 1.0, True),
            (0.0, 1.0, 0.35, 0.4, 0.9, 0.92, True),
            (0.02, 0.98, 0.05, 0.95, 0.45, 0.9, False),
            (0.0, 0.02, 0.0, 0.75, 0.1, 0.97, True),
            (0.98, 1.0, 0.0, 0.75, 0.1, 0.97, True),
        ),
        fabric=True,
        weight=0.0,
        decor=True,
    ),
)
PARTS_PER_PIECE = max(len(t.parts) for t in FURNITURE_TYPES)
# The basic scenes' types: the head of the pool (the decor's types come after them).
BASIC_TYPES = sum(not t.decor for t in FURNITURE_TYPES)
assert all(t.decor for t in FURNITURE_TYPES[BASIC_TYPES:])


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


TEMPLATES = _template_arrays()


# ---------------------------------------------------------------- random pieces


def furniture_weights(config) -> np.ndarray:
    """The relative frequency of each furniture type in a scene of configuration ``config`` (a
    :class:`~ncjax.synth.scene.SceneConfig`): the templates' weights, with ``config.furniture_weights``
    in place of those it names; the basic scenes draw from the head of the pool only."""
    weight = TEMPLATES["weight"].copy()
    names = [t.name for t in FURNITURE_TYPES]
    for name, value in config.furniture_weights:
        weight[names.index(name)] = value
    return weight if config.decor else weight[:BASIC_TYPES]


def furniture_candidate(key, room: Room, config):
    """One random piece for a scene of configuration ``config`` (a :class:`~ncjax.synth.scene.SceneConfig`):
    (type, size (3,), centre (2,), rotation (2,), valid)."""
    u = jax.random.uniform(key, (11,))
    # The types of the realistic scenes come last in the pool: the basic pool is its head.
    weight = furniture_weights(config)
    kind = categorical(u[0], jnp.asarray(weight))
    size = between(u[1:4], jnp.asarray(TEMPLATES["size_low"])[kind], jnp.asarray(TEMPLATES["size_high"])[kind])
    size = size.at[2].min(room.ceiling_height - room.floor_height - 0.25)
    # Against a wall: the back 1 cm off the wall, the piece's x axis along it.
    wall, along, fits, start, direction, normal = wall_position(u[4:6], room, size[0], 0.05)
    wall_centre = start + (along + size[0] / 2) * direction + (size[1] / 2 + 0.01) * normal
    # Free-standing: anywhere, aligned with the room (wall 0) more often than not.
    _, room_direction, _, _, low_xy, high_xy = room_frame(room)
    free_centre = between(u[6:8], low_xy, high_xy)
    aligned = jnp.arctan2(room_direction[0, 1], room_direction[0, 0]) + jnp.floor(4 * u[8]) * (math.pi / 2)
    angle = jnp.where(u[9] < 0.6, aligned, 2 * math.pi * u[10])
    free_rotation = jnp.stack([jnp.cos(angle), jnp.sin(angle)])
    against_wall = jnp.asarray(TEMPLATES["against_wall"])[kind]
    centre = jnp.where(against_wall, wall_centre, free_centre)
    rotation = jnp.where(against_wall, direction, free_rotation)
    half = size[:2] / 2
    clear_of_camera = (
        rectangle_distance_to_point(jnp.zeros(2), centre, half, rotation) > room.rc + config.camera_clearance
    )
    valid = (
        rectangle_in_room(centre, half, rotation, room)
        & (clear_of_camera | jnp.asarray(TEMPLATES["may_cover_camera"])[kind])
        & jnp.where(against_wall, fits, True)
    )
    return kind, size, centre, rotation, valid


def piece_materials(key, fabric: Bool[Array, ""]) -> tuple[Material, Material]:
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
    shade = between(u[11:13], 0.6, 0.9)
    return (
        Material(primary_pattern.astype(jnp.int32), primary_colour, shade[0] * primary_colour, jnp.array(0.3)),
        Material(secondary_pattern.astype(jnp.int32), secondary_colour, shade[1] * secondary_colour, jnp.array(0.3)),
    )


def piece_boxes(kind, size, centre, rotation, floor_height, materials: tuple[Material, Material]) -> Boxes:
    """The boxes of one piece of furniture (PARTS_PER_PIECE of them, with a mask), in its primary and
    secondary ``materials`` (:func:`piece_materials`)."""
    primary, secondary = materials
    parts = jnp.asarray(TEMPLATES["parts"])[kind]
    low, high = parts[:, 0::2] * size, parts[:, 1::2] * size
    local = (low + high) / 2 - jnp.array([size[0] / 2, size[1] / 2, 0.0])
    xy = centre + local[:, :1] * rotation + local[:, 1:2] * perpendicular(rotation)
    secondary_part = jnp.asarray(TEMPLATES["secondary"])[kind]
    material = jax.tree.map(
        lambda a, b: jnp.where(secondary_part.reshape((-1,) + (1,) * a.ndim), b, a), primary, secondary
    )
    return Boxes(
        centre=jnp.concatenate([xy, floor_height + local[:, 2:]], -1),
        half_size=(high - low) / 2,
        rotation=jnp.broadcast_to(rotation, (PARTS_PER_PIECE, 2)),
        material=material,
        emission=jnp.zeros((PARTS_PER_PIECE, 3)),
        mask=jnp.asarray(TEMPLATES["part_mask"])[kind],
    )
