"""Placement in the floor plan: rotated rectangles, packing without overlap and the random draws
that turn uniforms into positions (used by the furniture and the decor)."""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.polygon import perpendicular, point_in_polygon, polygon_edges, segments_cross
from .rooms import Room, room_walls, wall_distances

# ----------------------------------------------------------------- 2D rectangles


def rectangle_corners(
    centre: Float[Array, 2], half_size: Float[Array, 2], rotation: Float[Array, 2]
) -> Float[Array, "4 2"]:
    """Corners of a rotated rectangle (counter-clockwise)."""
    signs = jnp.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
    local = signs * half_size
    return centre + local[:, :1] * rotation + local[:, 1:] * perpendicular(rotation)


class Rectangle(NamedTuple):
    """A rotated rectangle in the plan (or a batch of them, along a leading axis).

    Attributes:
        centre: (2,) its centre.
        half_size: (2,) its half extents along ``rotation`` and perpendicular to it.
        rotation: (2,) the unit direction of its first axis.
    """

    centre: Float[Array, "*n 2"]
    half_size: Float[Array, "*n 2"]
    rotation: Float[Array, "*n 2"]


def rectangles_overlap(a: Rectangle, b: Rectangle, gap: Float[ArrayLike, ""] = 0.0) -> Bool[Array, ""]:
    """Whether two rotated rectangles come closer than ``gap`` along some axis
    (separating-axis theorem on the four edge normals)."""
    axes = jnp.stack([a.rotation, perpendicular(a.rotation), b.rotation, perpendicular(b.rotation)])

    def radius(half, rotation):
        return jnp.abs(half[0] * axes @ rotation) + jnp.abs(half[1] * axes @ perpendicular(rotation))

    separation = jnp.abs(axes @ (b.centre - a.centre))
    return ~jnp.any(separation > radius(a.half_size, a.rotation) + radius(b.half_size, b.rotation) + gap)


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


class Footprints(eqx.Module):
    """Rotated rectangles (one, or a leading batch axis) and which are valid."""

    centre: Float[Array, "*n 2"]
    half_size: Float[Array, "*n 2"]
    rotation: Float[Array, "*n 2"]
    mask: Bool[Array, "*n"]

    @property
    def rectangles(self) -> Rectangle:
        return Rectangle(self.centre, self.half_size, self.rotation)


def pack_footprints(candidates: Footprints, capacity: int, obstacles: Footprints, gap: float):
    """Greedy rejection sampling: accept the valid candidates in order while they
    overlap neither an accepted one nor an obstacle, up to ``capacity``.

    Returns ``(chosen, chosen_mask)``: candidate indices (capacity,) and which
    slots were filled.
    """

    def overlaps_any(footprints, rectangle):
        hits = jax.vmap(rectangles_overlap, in_axes=(0, None, None))(footprints.rectangles, rectangle, gap)
        return jnp.any(hits & footprints.mask)

    blocked = jax.vmap(lambda rectangle: overlaps_any(obstacles, rectangle))(candidates.rectangles)

    def step(carry, inputs):
        accepted, chosen, count = carry
        index, centre, half, rotation, valid, is_blocked = inputs
        take = valid & ~is_blocked & (count < capacity) & ~overlaps_any(accepted, Rectangle(centre, half, rotation))
        slot = jnp.minimum(count, capacity - 1)
        accepted = jax.tree.map(
            lambda field, value: field.at[slot].set(jnp.where(take, value, field[slot])),
            accepted,
            Footprints(centre, half, rotation, jnp.array(True)),
        )
        chosen = chosen.at[slot].set(jnp.where(take, index, chosen[slot]))
        return (accepted, chosen, count + take), None

    empty = Footprints(
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


def between(uniform: Array, low, high) -> Array:
    return low + uniform * (jnp.asarray(high) - low)


def categorical(uniform: Float[Array, ""], weights: Float[Array, " n"]) -> Int[Array, ""]:
    """Index drawn with probability proportional to ``weights`` (inverse CDF)."""
    cumulative = jnp.cumsum(weights)
    return jnp.minimum(jnp.sum(uniform * cumulative[-1] >= cumulative), weights.shape[0] - 1)


def room_frame(room: Room):
    """Wall starts, unit directions, inward normals and lengths (K each), and the
    room's bounding box."""
    direction, _, _, _ = room_walls(room)
    edges = polygon_edges(room.corners, room.mask)
    length = jnp.where(room.mask, jnp.linalg.norm(edges[:, 1] - edges[:, 0], axis=-1), 0.0)
    # Counter-clockwise polygon: the interior is to the left of each wall.
    normal = perpendicular(direction)
    valid = jnp.where(room.mask[:, None], room.corners, room.corners[:1])
    return edges[:, 0], direction, normal, length, jnp.min(valid, 0), jnp.max(valid, 0)


def wall_position(uniform: Float[Array, 2], room: Room, width: Float[Array, ""], margin: float):
    """A wall (chosen with probability proportional to its length) and a start
    position along it that fits ``width`` with ``margin`` at both ends.

    Returns ``(wall, along, fits, wall_start, wall_direction, inward_normal)``.
    """
    start, direction, normal, length, _, _ = room_frame(room)
    wall = categorical(uniform[0], length)
    room_left = length[wall] - width - 2 * margin
    along = margin + uniform[1] * jnp.maximum(room_left, 0.0)
    return wall, along, room_left >= 0, start[wall], direction[wall], normal[wall]


def wall_position_at_camera(room: Room, width: Float[Array, ""], margin: float):
    """The wall nearest the camera and a start along it that centres ``width`` on the camera's foot, shifted to
    keep ``margin`` at both ends, with ``width`` cut to what the wall holds.

    Returns ``(wall, along, width, wall_start, wall_direction, inward_normal)``.
    """
    start, direction, normal, length, _, _ = room_frame(room)
    wall = jnp.argmin(wall_distances(jnp.zeros(2), room.corners, room.mask))
    width = jnp.minimum(width, length[wall] - 2 * margin)
    foot = -jnp.dot(start[wall], direction[wall])  # the camera (the origin) along the wall from its start
    along = jnp.clip(foot - width / 2, margin, length[wall] - margin - width)
    return wall, along, width, start[wall], direction[wall], normal[wall]


def no_footprints() -> Footprints:
    return Footprints(jnp.zeros((1, 2)), jnp.ones((1, 2)), jnp.array([[1.0, 0.0]]), jnp.zeros(1, bool))
