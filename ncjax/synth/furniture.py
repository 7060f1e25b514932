"""Furniture types and their placement without overlap (rectangles in the plan)."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.polygon import perpendicular, polygon_edges, segments_cross
from .rooms import Room, point_in_polygon, room_walls


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


_TEMPLATES = _template_arrays()


# ----------------------------------------------------------------- 2D rectangles


def rectangle_corners(
    centre: Float[Array, 2], half_size: Float[Array, 2], rotation: Float[Array, 2]
) -> Float[Array, "4 2"]:
    """Corners of a rotated rectangle (counter-clockwise)."""
    signs = jnp.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = signs * half_size
    return centre + local[:, :1] * rotation + local[:, 1:] * perpendicular(rotation)


def rectangles_overlap(
    centre_a: Float[Array, 2],
    half_a: Float[Array, 2],
    rotation_a: Float[Array, 2],
    centre_b: Float[Array, 2],
    half_b: Float[Array, 2],
    rotation_b: Float[Array, 2],
    gap: Float[ArrayLike, ""] = 0.0,
) -> Bool[Array, ""]:
    """Whether two rotated rectangles come closer than ``gap`` along some axis
    (separating-axis theorem on the four edge normals)."""
    axes = jnp.stack([rotation_a, perpendicular(rotation_a), rotation_b, perpendicular(rotation_b)])

    def radius(half, rotation):
        return jnp.abs(half[0] * axes @ rotation) + jnp.abs(half[1] * axes @ perpendicular(rotation))

    separation = jnp.abs(axes @ (centre_b - centre_a))
    return ~jnp.any(separation > radius(half_a, rotation_a) + radius(half_b, rotation_b) + gap)


def rectangle_distance_to_point(
    point: Float[Array, 2], centre: Float[Array, 2], half_size: Float[Array, 2], rotation: Float[Array, 2]
) -> Float[Array, ""]:
    """Distance from a point to a rotated rectangle (0 inside)."""
    offset = point - centre
    local = jnp.stack([offset @ rotation, offset @ perpendicular(rotation)])
    outside = jnp.maximum(jnp.abs(local) - half_size, 0.0)
    return jnp.sqrt(jnp.sum(outside**2))


def rectangle_in_room(
    centre: Float[Array, 2], half_size: Float[Array, 2], rotation: Float[Array, 2], room: Room
) -> Bool[Array, ""]:
    """The rectangle lies inside the room's floor plan: its corners are inside and
    no wall crosses its edges (a reflex corner of the room cannot poke in)."""
    corners = rectangle_corners(centre, half_size, rotation)
    inside = jax.vmap(point_in_polygon, in_axes=(0, None, None))(corners, room.corners, room.mask)
    walls = polygon_edges(room.corners, room.mask)
    sides = jnp.stack([corners, jnp.roll(corners, -1, axis=0)], 1)
    crossing = segments_cross(sides[:, None, 0], sides[:, None, 1], walls[None, :, 0], walls[None, :, 1])
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
        jnp.zeros((capacity, 2)),
        jnp.zeros((capacity, 2)),
        jnp.tile(jnp.array([1.0, 0.0]), (capacity, 1)),
        jnp.zeros(capacity, bool),
    )
    n = candidates.mask.shape[0]
    inputs = (jnp.arange(n), candidates.centre, candidates.half_size, candidates.rotation, candidates.mask, blocked)
    (accepted, chosen, _), _ = jax.lax.scan(step, (empty, jnp.zeros(capacity, jnp.int32), jnp.array(0)), inputs)
    return chosen, accepted.mask


# ------------------------------------------------------------- random placement
# Generators draw ONE array of uniforms and read their numbers from it (see
# :mod:`ncjax.synth.scene`); these helpers turn such numbers into placements.


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
    normal = perpendicular(direction)
    valid = jnp.where(room.mask[:, None], room.corners, room.corners[:1])
    return edges[:, 0], direction, normal, length, jnp.min(valid, 0), jnp.max(valid, 0)


def _wall_position(uniform: Float[Array, 2], room: Room, width: Float[Array, ""], margin: float):
    """A wall (chosen with probability proportional to its length) and a start
    position along it that fits ``width`` with ``margin`` at both ends.

    Returns ``(wall, along, fits, wall_start, wall_direction, inward_normal)``.
    """
    start, direction, normal, length, _, _ = _room_frame(room)
    wall = _categorical(uniform[0], length)
    room_left = length[wall] - width - 2 * margin
    along = margin + uniform[1] * jnp.maximum(room_left, 0.0)
    return wall, along, room_left >= 0, start[wall], direction[wall], normal[wall]


def _nothing() -> _Footprints:
    return _Footprints(jnp.zeros((1, 2)), jnp.ones((1, 2)), jnp.array([[1.0, 0.0]]), jnp.zeros(1, bool))
