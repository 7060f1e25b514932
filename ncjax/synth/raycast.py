"""The renderer's ray casting (:mod:`.render`): per column, and per pixel of a row.

Every ray of a column lies in the column's vertical half-plane and shares its
horizontal path, so the walls, the doors and windows, the decals and the box
footprints are intersected once per column (:func:`cast_columns`); a pixel then
only compares heights against the column's nearest boxes (:func:`nearest_box`).
Shadow rays test segments against the boxes in 3D (:func:`box_segment_blocked`).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ..geometry.camera import NonCentralPanorama, pixel_to_angles
from ..geometry.polygon import perpendicular
from .elements import Boxes
from .render_details import doorway_columns, in_span
from .rooms import ray_hits, room_walls
from .scene import Scene


def box_interval_2d(
    origin: Float[Array, 2],
    direction: Float[Array, 2],
    centre: Float[Array, 2],
    half_size: Float[Array, 2],
    rotation: Float[Array, 2],
) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, 2]]:
    """Slab test of a horizontal ray against a rotated rectangle.

    Returns:
        ``(t_in, t_out, normal)``: the ray parameters where it enters and leaves
        the rectangle (empty when ``t_in >= t_out``), and the outward normal of
        the entry side.
    """
    axes = jnp.stack([rotation, perpendicular(rotation)])
    o, d = axes @ (origin - centre), axes @ direction
    safe_d = jnp.where(jnp.abs(d) > 1e-12, d, 1e-12)
    t_a, t_b = (-half_size - o) / safe_d, (half_size - o) / safe_d
    near, far = jnp.minimum(t_a, t_b), jnp.maximum(t_a, t_b)
    entry_axis = jnp.argmax(near)
    normal = -jnp.sign(safe_d[entry_axis]) * axes[entry_axis]
    return jnp.max(near), jnp.min(far), normal


def box_segment_blocked(
    start: Float[Array, 3], end: Float[Array, 3], boxes: Boxes, casts_shadow: Bool[Array, " B"]
) -> Bool[Array, ""]:
    """Whether the segment from ``start`` to ``end`` passes through a box (3D slab test)."""
    axes = jnp.stack([boxes.rotation, perpendicular(boxes.rotation)], -2)  # (B, 2, 2)
    offset = start[None] - boxes.centre
    delta = end - start
    o = jnp.concatenate([jnp.einsum("bij,bj->bi", axes, offset[:, :2]), offset[:, 2:]], -1)
    d = jnp.concatenate([jnp.einsum("bij,j->bi", axes, delta[:2]), jnp.broadcast_to(delta[2:], (o.shape[0], 1))], -1)
    safe_d = jnp.where(jnp.abs(d) > 1e-12, d, 1e-12)
    t_a, t_b = (-boxes.half_size - o) / safe_d, (boxes.half_size - o) / safe_d
    t_in = jnp.max(jnp.minimum(t_a, t_b), -1)
    t_out = jnp.min(jnp.maximum(t_a, t_b), -1)
    return jnp.any((t_in < t_out) & (t_out > 1e-4) & (t_in < 1.0 - 1e-4) & casts_shadow)


def cast_columns(scene: Scene, cam: NonCentralPanorama, boxes_per_column: int):
    """Everything that depends on the column only: the horizontal ray, the wall
    it meets and where, the door or window there (with decor, the decal there
    and the path through an open door), and the boxes whose footprints it
    crosses with all their attributes (so that the per-pixel code gathers nothing)."""
    room, boxes = scene.room, scene.boxes
    azimuth, _ = pixel_to_angles(cam, jnp.arange(cam.width, dtype=room.corners.dtype), 0.0)
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    origin = cam.rc * direction
    hits = jax.vmap(ray_hits, in_axes=(0, 0, None, None))(origin, direction, room.corners, room.mask)
    wall = jnp.argmin(hits, axis=1)
    t_wall = jnp.min(hits, axis=1)
    t_wall = jnp.where(jnp.isfinite(t_wall), t_wall, 1e3)  # only for invalid rooms
    wall_direction, _, _, _ = room_walls(room)
    wall_point = origin + t_wall[:, None] * direction
    along = jnp.sum((wall_point - room.corners[wall]) * wall_direction[wall], -1)
    wall_normal = perpendicular(wall_direction[wall])

    def rectangles_on_walls(fields, names):
        present, index = in_span(fields.wall, fields.span, fields.mask, wall, along)
        gathered = dict(
            present=present,
            index=index,
            start=fields.span[index, 0],
            width=fields.span[index, 1] - fields.span[index, 0],
            bottom=fields.z_range[index, 0],
            tall=fields.z_range[index, 1] - fields.z_range[index, 0],
        )
        return gathered | {name: getattr(fields, name)[index] for name in names}

    opening = rectangles_on_walls(scene.openings, ("is_window", "colour", "frame_colour"))
    details = {}
    if scene.decor is not None:
        doorways = scene.decor.doorways
        opening |= {f.name: getattr(doorways, f.name)[opening["index"]] for f in dataclasses.fields(doorways)}
        details = dict(
            decal=rectangles_on_walls(
                scene.decor.decals, ("kind", "colour_a", "colour_b", "frame_colour", "frame_width")
            ),
            doorway=doorway_columns(opening, direction, t_wall, along, wall_direction[wall], wall_normal),
        )
    t_in, t_out, box_normal = jax.vmap(
        jax.vmap(box_interval_2d, in_axes=(None, None, 0, 0, 0)), in_axes=(0, 0, None, None, None)
    )(origin, direction, boxes.centre[:, :2], boxes.half_size[:, :2], boxes.rotation)
    # Keep, per column, the nearest boxes whose footprint the column's ray crosses
    # in front of the wall: pixels then test only those (box axis first, so that
    # the per-pixel work vectorises along the row).
    crossed = boxes.mask[None, :] & (t_in < t_out) & (t_out > 0) & (t_in < t_wall[:, None])
    _, nearest = jax.lax.top_k(jnp.where(crossed, -t_in, -jnp.inf), boxes_per_column)
    nearest = nearest.T  # (M, W)
    column = jnp.arange(cam.width)[None, :]
    candidates = dict(
        box=nearest,
        t_in=jnp.where(crossed.T[nearest, column], t_in.T[nearest, column], jnp.inf),
        t_out=t_out.T[nearest, column],
        normal_x=box_normal[..., 0].T[nearest, column],
        normal_y=box_normal[..., 1].T[nearest, column],
        bottom=boxes.centre[nearest, 2] - boxes.half_size[nearest, 2],
        top=boxes.centre[nearest, 2] + boxes.half_size[nearest, 2],
        centre_x=boxes.centre[nearest, 0],
        centre_y=boxes.centre[nearest, 1],
        cos=boxes.rotation[nearest, 0],
        sin=boxes.rotation[nearest, 1],
        emission=boxes.emission[nearest],
        material=jax.tree.map(lambda x: x[nearest], boxes.material),
    )
    return dict(
        origin=origin,
        direction=direction,
        t_wall=t_wall,
        along=along,
        wall_normal=wall_normal,
        opening=opening,
        candidates=candidates,
        overflow=jnp.sum(crossed, 1) > boxes_per_column,
        **details,
    )


def nearest_box(candidates: dict, cotangent: Float[Array, ""]):
    """Per pixel of a row: the distance to the nearest candidate box (inf if
    none) and that box's attributes: a running minimum over the M candidates,
    each a slab test of the column's footprint interval against the row's
    height interval."""
    best = jnp.full(candidates["t_in"].shape[1:], jnp.inf)
    index = jnp.zeros(best.shape, jnp.int32)
    for m in range(candidates["t_in"].shape[0]):
        low, high = candidates["bottom"][m] * cotangent, candidates["top"][m] * cotangent
        enter = jnp.maximum(candidates["t_in"][m], jnp.minimum(low, high))
        leave = jnp.minimum(candidates["t_out"][m], jnp.maximum(low, high))
        t = jnp.where((enter < leave) & (leave > 0), enter, jnp.inf)
        closer = t < best
        best = jnp.where(closer, t, best)
        index = jnp.where(closer, m, index)
    chosen = jax.tree.map(
        lambda x: jnp.take_along_axis(x, index.reshape((1,) + index.shape + (1,) * (x.ndim - 2)), 0)[0], candidates
    )
    return best, chosen
