"""Exact per-column labels of a synthetic room seen by a panorama (HorizonNet's encoding, paper Section 5.1).

The boundary rows, the corners (occlusions twice, near and far point) and the
corner target ``CORNER_LABEL_BASE**d`` of :func:`room_labels`, which the dataset
writes and the network learns.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ..geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles
from ..pipeline.corners import CORNER_LABEL_BASE
from .rooms import Room, ray_hits, vertex_visibility


class RoomLabels(eqx.Module):
    """Exact per-column labels of a room seen by a camera (HorizonNet encoding).

    Attributes:
        ceiling_v, floor_v: (W,) sub-pixel rows of the ceiling-wall and floor-wall
            boundaries.
        ceiling_points, floor_points: (W, 3) the 3D boundary points they image.
        wall_index: (W,) index of the wall seen in each column (-1: none).
        corner_u: (C,) sub-pixel columns of the layout corners in image order
            (left to right, i.e. decreasing azimuth); occlusion corners appear
            twice (near and far point), as in HorizonNet's ``label_cor``.
        corner_mask: (C,) valid corners; corner_is_occlusion: (C,) the corner is
            one of the two points of an occlusion.
        ceiling_corners, floor_corners: (C, 3) the corners of the visible layout.
        corner_target: (W,) ``0.96 ** d``, d the (wrap-around) distance in
            columns from the column centre to the nearest corner column.
        ok: labels are valid (the room is ok, every column sees a wall and the
            corner capacity C was enough).
    """

    ceiling_v: Float[Array, " W"]
    floor_v: Float[Array, " W"]
    ceiling_points: Float[Array, "W 3"]
    floor_points: Float[Array, "W 3"]
    wall_index: Int[Array, " W"]
    corner_u: Float[Array, " C"]
    corner_mask: Bool[Array, " C"]
    corner_is_occlusion: Bool[Array, " C"]
    ceiling_corners: Float[Array, "C 3"]
    floor_corners: Float[Array, "C 3"]
    corner_target: Float[Array, " W"]
    ok: Bool[Array, ""]


def corner_target(
    corner_u: Float[ArrayLike, " C"], corner_mask: Bool[ArrayLike, " C"], width: int
) -> Float[Array, " {width}"]:
    """HorizonNet's corner target ``0.96**d`` per column, d the wrap-around column distance to the nearest corner.

    Zero everywhere when no corner is given. A network may be trained on a
    sharper encoding ``b**d`` of the same distance: :func:`reencode_corner_prob`.
    """
    corner_u = jnp.asarray(corner_u)
    columns = jnp.arange(width, dtype=corner_u.dtype)
    distance = jnp.abs(columns[:, None] - corner_u[None, :]) % width
    distance = jnp.minimum(distance, width - distance)
    nearest = jnp.min(jnp.where(jnp.asarray(corner_mask)[None, :], distance, jnp.inf), axis=1)
    return jnp.where(jnp.isfinite(nearest), CORNER_LABEL_BASE**nearest, 0.0)


def reencode_corner_prob(
    corner_prob: Float[ArrayLike, "*shape"], from_base: float, to_base: float
) -> Float[Array, "*shape"]:
    """The same distance-to-corner estimate in another encoding: ``from_base**d -> to_base**d``.

    ``d = log p / log from_base``, so ``to_base**d = p**(log to_base / log from_base)``:
    a monotone map, which keeps every peak and dip of ``corner_prob`` in place.
    """
    exponent = math.log(to_base) / math.log(from_base)
    return jnp.asarray(corner_prob) ** exponent


def room_labels(room: Room, cam: NonCentralPanorama, corner_capacity: int | None = None) -> RoomLabels:
    """Exact per-column labels of ``room`` seen by ``cam`` (``cam.rc`` is used).

    Each column's rays lie in the vertical half-plane of its azimuth, leaving the
    optical centre ``rc (cos, sin, 0)``; the first wall hit at horizontal
    distance t gives the boundary elevations ``atan2(h_c, t)`` and ``atan2(h_f, t)``
    (paper eq. forward). Corners are the visible room corners plus, for each
    occluding corner, the point of the farther wall behind it.

    Args:
        room: the room, camera frame.
        cam: the camera (static width W and height H).
        corner_capacity: C, slots for layout corners (default: the room's K).

    Returns:
        :class:`RoomLabels`.
    """
    capacity = room.corners.shape[0] if corner_capacity is None else corner_capacity
    columns = jnp.arange(cam.width, dtype=room.corners.dtype)
    azimuth, _ = pixel_to_angles(cam, columns, 0.0)
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    hits = jax.vmap(ray_hits, in_axes=(0, 0, None, None))(cam.rc * direction, direction, room.corners, room.mask)
    wall_index = jnp.argmin(hits, axis=1)
    distance = jnp.min(hits, axis=1)
    seen = jnp.isfinite(distance)
    safe_distance = jnp.where(seen, distance, 1.0)
    _, ceiling_v = angles_to_pixel(cam, azimuth, jnp.arctan2(room.ceiling_height, safe_distance))
    _, floor_v = angles_to_pixel(cam, azimuth, jnp.arctan2(room.floor_height, safe_distance))
    ground = (cam.rc + safe_distance)[:, None] * direction

    def at_height(points_2d, height):
        return jnp.concatenate([points_2d, jnp.broadcast_to(height, points_2d.shape[:-1])[..., None]], -1)

    visible, occluding, far_distance, neighbours_left = vertex_visibility(room.corners, room.mask, cam.rc)
    corner_azimuth = jnp.arctan2(room.corners[:, 1], room.corners[:, 0])
    corner_u, _ = angles_to_pixel(cam, corner_azimuth, 0.0)
    corner_direction = jnp.stack([jnp.cos(corner_azimuth), jnp.sin(corner_azimuth)], -1)
    far_points = (cam.rc + jnp.where(occluding, far_distance, 0.0))[:, None] * corner_direction
    # Within one occlusion column the near corner comes first when its own walls
    # are to its left in the image.
    order_offset = 1e-3
    near_key = corner_u + jnp.where(occluding & ~neighbours_left, order_offset, 0.0)
    far_key = corner_u + jnp.where(neighbours_left, order_offset, 0.0)
    points_2d = jnp.concatenate([room.corners, far_points])
    valid = jnp.concatenate([visible, occluding])
    sort_key = jnp.where(valid, jnp.concatenate([near_key, far_key]), jnp.inf)
    order = jnp.argsort(sort_key, stable=True)[:capacity]
    columns_of = jnp.concatenate([corner_u, corner_u])[order]
    corner_mask = valid[order]
    ok = room.ok & jnp.all(seen) & (jnp.sum(valid) <= capacity) & jnp.any(corner_mask)
    return RoomLabels(
        ceiling_v=ceiling_v,
        floor_v=floor_v,
        ceiling_points=at_height(ground, room.ceiling_height),
        floor_points=at_height(ground, room.floor_height),
        wall_index=jnp.where(seen, wall_index, -1).astype(jnp.int32),
        corner_u=jnp.where(corner_mask, columns_of, 0.0),
        corner_mask=corner_mask,
        corner_is_occlusion=jnp.concatenate([occluding, occluding])[order] & corner_mask,
        ceiling_corners=jnp.where(corner_mask[:, None], at_height(points_2d[order], room.ceiling_height), 0.0),
        floor_corners=jnp.where(corner_mask[:, None], at_height(points_2d[order], room.floor_height), 0.0),
        corner_target=corner_target(columns_of, corner_mask, cam.width),
        ok=ok,
    )
