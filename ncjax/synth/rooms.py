"""Synthetic rooms (the geometry of the paper's dataset, Section 5.1); their exact labels: :mod:`.labels`.

Rooms are generated as the paper describes: a random Manhattan layout of 4-14
walls (here a rectangle whose corners are cut by rectilinear staircases, each
step adding two walls), optionally turned into an Atlanta layout by clipping
convex corners with oblique walls, at any yaw. A camera (a circle of optical
centres of radius ``rc``) is placed anywhere inside with a margin.

Everything is a pure function of a ``jax.random`` key with fixed-capacity
arrays, so it runs under ``jax.jit(jax.vmap(...))``: same key, same room. Failure
modes are returned in ``Room.status`` (see :class:`RoomStatus`), never hidden.

Polygons are counter-clockwise seen from +z; wall ``i`` runs from corner ``i``
to corner ``i + 1`` (cyclically over the valid corners, which come first).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama
from ..geometry.plucker import cross_2d as _cross2
from ..geometry.plucker import horizontal_wall_line, rotation_z
from ..geometry.polygon import (
    is_simple,
    next_index,
    point_in_polygon,
    polygon_area,
    polygon_edges,
    previous_index,
    segments_cross,
)


class RoomStatus(enum.IntEnum):
    """Why a room generation failed (``Room.status``); 0 is success."""

    OK = 0
    CAMERA_NOT_PLACED = 1
    DEGENERATE_POLYGON = 2
    OCCLUSION_REQUIREMENT_NOT_MET = 3
    NO_CORNER_TO_CLIP = 4


@dataclasses.dataclass(frozen=True)
class RoomConfig:
    """Static configuration of :func:`random_room` (hashable: a jit static argument).

    Attributes:
        world: "manhattan", "atlanta" or "mix" (half and half).
        min_walls, max_walls: range of the Manhattan wall count (even numbers).
        size_range: side lengths of the bounding rectangle, metres.
        width_range: with a range, the rectangle's shorter side is drawn from it instead, and the
            longer from ``size_range`` (a corridor: ``(0.9, 1.5)`` wide, ``size_range`` long); None: both
            sides from ``size_range``.
        height_range: floor-to-ceiling height, metres.
        camera_height_range: camera height above the floor, metres.
        rc_range: radius of the circle of optical centres, metres.
        occlusion: "any", "none" (no wall hidden, even partly) or "required"
            (at least one occlusion corner in view).
        camera_margin: extra clearance between the circle of optical centres
            and every wall, metres.
        doorway_distance: with a range, the circle of optical centres stands this far (metres) from
            its nearest wall, as a photographer in a doorway (the scene can open a passage there:
            :attr:`~ncjax.synth.SceneConfig.passage_at_camera`), and ``camera_margin`` from the others;
            None: ``camera_margin`` from every wall.
        min_step: smallest staircase step, metres.
        clip_probability: probability of clipping each convex corner (Atlanta).
        capacity: K, the fixed number of wall slots.
        camera_tries: candidate camera positions tried per room (no loops).
        room_tries: whole rooms generated per call; the first that succeeds is
            returned (fixed work, no loops), the failure of the last otherwise.
    """

    world: str = "manhattan"
    min_walls: int = 4
    max_walls: int = 14
    size_range: tuple[float, float] = (3.5, 10.0)
    width_range: tuple[float, float] | None = None
    height_range: tuple[float, float] = (2.4, 3.5)
    camera_height_range: tuple[float, float] = (1.0, 1.8)
    rc_range: tuple[float, float] = (0.3, 1.0)
    occlusion: str = "any"
    camera_margin: float = 0.3
    doorway_distance: tuple[float, float] | None = None
    min_step: float = 0.25
    clip_probability: float = 0.5
    capacity: int = 32
    camera_tries: int = 256
    room_tries: int = 4

    def __post_init__(self):
        if self.world not in ("manhattan", "atlanta", "mix"):
            raise ValueError(f"world must be 'manhattan', 'atlanta' or 'mix', got {self.world!r}")
        if self.occlusion not in ("any", "none", "required"):
            raise ValueError(f"occlusion must be 'any', 'none' or 'required', got {self.occlusion!r}")
        if self.min_walls % 2 or self.max_walls % 2 or not 4 <= self.min_walls <= self.max_walls <= 14:
            raise ValueError("Manhattan wall counts must be even with 4 <= min_walls <= max_walls <= 14")
        for name in ("size_range", "height_range", "camera_height_range", "rc_range", "doorway_distance"):
            if getattr(self, name) is None:
                continue
            low, high = getattr(self, name)
            if not 0 <= low <= high:
                raise ValueError(f"{name} must be (low, high) with 0 <= low <= high, got {(low, high)}")
        if self.width_range is not None and not 0 < self.width_range[0] <= self.width_range[1] <= self.size_range[0]:
            raise ValueError(
                f"width_range must be (low, high) with 0 < low <= high <= size_range's low {self.size_range[0]}, "
                f"got {self.width_range}"
            )
        if self.camera_height_range[1] >= self.height_range[0]:
            raise ValueError("the camera must stay below the ceiling: camera_height_range[1] < height_range[0]")
        if self.capacity < self.max_walls + self.max_walls // 2 + 3:
            raise ValueError(f"capacity {self.capacity} is too small for {self.max_walls} walls plus clips")


class Room(eqx.Module):
    """A room seen from a camera at the origin (camera frame, metres).

    All fields are traced arrays (batchable). ``corners`` (K, 2) is the
    counter-clockwise floor plan with the valid corners first (``mask``).
    ``camera_position`` (3,) is the camera in a world frame of the same
    orientation whose floor is z = 0 (the dataset's ``cam_pose``).
    """

    corners: Float[Array, "K 2"]
    mask: Bool[Array, " K"]
    ceiling_height: Float[Array, ""]
    floor_height: Float[Array, ""]
    rc: Float[Array, ""]
    camera_position: Float[Array, 3]
    is_atlanta: Bool[Array, ""]
    status: Int[Array, ""]

    @property
    def num_walls(self) -> Int[Array, "*batch"]:
        return jnp.sum(self.mask, -1)

    @property
    def ok(self) -> Bool[Array, "*batch"]:
        return self.status == RoomStatus.OK

    def camera(self, width: int = 1024, height: int = 512) -> NonCentralPanorama:
        """The panorama camera of this room (its ``rc``)."""
        return NonCentralPanorama(width=width, height=height, rc=self.rc)


# --------------------------------------------------------------------------- polygons


def _compact(points: Float[Array, "N 2"], valid: Bool[Array, " N"], capacity: int):
    """Move the valid points to the front (keeping their order), pad to ``capacity``."""
    order = jnp.argsort(~valid, stable=True)[:capacity]
    return points[order], valid[order]


def wall_distances(point: Float[Array, 2], corners: Float[Array, "K 2"], mask: Bool[Array, " K"]) -> Float[Array, " K"]:
    """Distance from a point to each wall segment (inf in masked slots)."""
    edges = polygon_edges(corners, mask)
    a, b = edges[:, 0], edges[:, 1]
    ab = b - a
    t = jnp.clip(jnp.sum((point - a) * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), 1e-12), 0.0, 1.0)
    return jnp.where(mask, jnp.linalg.norm(point - (a + t[:, None] * ab), axis=-1), jnp.inf)


def distance_to_walls(
    point: Float[Array, 2], corners: Float[Array, "K 2"], mask: Bool[Array, " K"]
) -> Float[Array, ""]:
    """Distance from a point to the nearest wall segment."""
    return jnp.min(wall_distances(point, corners, mask))


def ray_hits(
    origin: Float[Array, 2], direction: Float[Array, 2], corners: Float[Array, "K 2"], mask: Bool[Array, " K"]
) -> Float[Array, " K"]:
    """Distance along a horizontal ray to each wall segment (inf where missed)."""
    edges = polygon_edges(corners, mask)
    a, e = edges[:, 0], edges[:, 1] - edges[:, 0]
    denominator = _cross2(direction, e)
    hit = jnp.abs(denominator) > 1e-12
    safe = jnp.where(hit, denominator, 1.0)
    t = _cross2(a - origin, e) / safe
    s = _cross2(a - origin, direction) / safe
    # a ray through a corner meets both of its walls at s = 1 and s = 0, which rounding can put just outside [0, 1]:
    # a few ulps of slack, so that it never misses both (a column that sees no wall)
    tolerance = 64 * jnp.finfo(s.dtype).eps
    hit = hit & mask & (t > 0) & (s >= -tolerance) & (s <= 1 + tolerance)
    return jnp.where(hit, t, jnp.inf)


# ---------------------------------------------------------------------- generation


class _RectangleCorner(NamedTuple):
    """A corner of the rectangle that a staircase replaces, and its two walls."""

    point: Float[Array, 2]
    incoming: Float[Array, 2]  # unit direction of the wall that ends at the corner
    outgoing: Float[Array, 2]  # unit direction of the wall that starts there
    length_in: Float[Array, ""]  # the walls' lengths
    length_out: Float[Array, ""]


def _staircase(key, corner: _RectangleCorner, steps, clearance, config: RoomConfig):
    """Vertices replacing one rectangle corner by a staircase of ``steps`` steps.

    With breakpoints ``a_0 > ... > a_{s-1} > a_s = 0`` along the incoming wall and
    ``0 = b_0 < b_1 < ... < b_s`` along the outgoing one, the vertices are
    ``C - a_k e_in + b_k e_out`` (k = 0..s) interleaved with
    ``C - a_k e_in + b_{k+1} e_out`` (k = 0..s-1): 2 s + 1 vertices, s = 0 keeps
    the corner. Each staircase stays within 45% of both walls, so the four never meet,
    and (when the steps fit) ``clearance`` away from the rectangle's centre, so
    that a camera always fits there.
    """
    max_steps = config.max_walls // 2 - 2
    key_a, key_b, key_ga, key_gb = jax.random.split(key, 4)
    active = jnp.arange(max_steps) < steps

    def breakpoints(key_total, key_gaps, length):
        low = steps * config.min_step
        high = jnp.maximum(low, jnp.minimum(0.45 * length, 0.5 * length - clearance))
        total = jnp.where(steps > 0, jax.random.uniform(key_total, minval=low, maxval=high), 0.0)
        weights = jnp.where(active, jax.random.exponential(key_gaps, (max_steps,)), 0.0)
        weights = weights / jnp.maximum(jnp.sum(weights), 1e-12)
        gaps = jnp.where(active, config.min_step + (total - low) * weights, 0.0)
        return jnp.concatenate([jnp.zeros(1), jnp.cumsum(gaps)])  # (max_steps + 1,)

    a = breakpoints(key_a, key_ga, corner.length_in)
    a = a[steps] - a  # a_0 = total ... a_s = 0
    b = breakpoints(key_b, key_gb, corner.length_out)
    b_next = jnp.concatenate([b[1:], b[-1:]])
    even = corner.point - a[:, None] * corner.incoming + b[:, None] * corner.outgoing
    odd = corner.point - a[:, None] * corner.incoming + b_next[:, None] * corner.outgoing
    vertices = jnp.stack([even, odd], 1).reshape(-1, 2)[: 2 * max_steps + 1]
    valid = jnp.arange(2 * max_steps + 1) <= 2 * steps
    return vertices, valid


def _manhattan_polygon(key, clearance, config: RoomConfig):
    """A rectilinear CCW polygon with an even number of walls in [min_walls, max_walls],
    centred on the origin, sides at least ``2 clearance + 1`` metres (a corridor's width at least
    ``2 clearance``, and ``2 min_step`` more where staircases may be)."""
    key_n, key_size, key_slots, key_corners = jax.random.split(key, 4)
    max_steps = config.max_walls // 2 - 2
    total_steps = jax.random.randint(key_n, (), config.min_walls // 2 - 2, config.max_walls // 2 - 1)
    smallest = jnp.maximum(config.size_range[0], 2 * clearance + 1.0)
    size = jax.random.uniform(key_size, (2,), minval=smallest, maxval=jnp.maximum(smallest, config.size_range[1]))
    if config.width_range is not None:
        # A corridor (along x; the room is turned to any yaw later): the camera needs its clearance to both long
        # walls, and a staircase's step room beside it.
        steps_room = 2 * config.min_step if config.max_walls > 4 else 0.0
        narrowest = jnp.maximum(config.width_range[0], 2 * clearance + steps_room)
        width = jax.random.uniform(
            jax.random.fold_in(key_size, 1), minval=narrowest, maxval=jnp.maximum(narrowest, config.width_range[1])
        )
        size = jnp.stack([size[0], width])
    half_x, half_y = size[0] / 2, size[1] / 2
    rectangle = jnp.array([[1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]]) * jnp.stack([half_x, half_y])
    incoming = jnp.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    outgoing = jnp.roll(incoming, -1, axis=0)
    length_in = jnp.stack([size[0], size[1], size[0], size[1]])
    length_out = jnp.roll(length_in, -1)
    slot_corner = jax.random.randint(key_slots, (max(max_steps, 1),), 0, 4)
    slot_active = jnp.arange(max(max_steps, 1)) < total_steps
    steps = jnp.sum((slot_corner[None, :] == jnp.arange(4)[:, None]) & slot_active[None, :], 1)
    corners = _RectangleCorner(rectangle, incoming, outgoing, length_in, length_out)
    vertices, valid = jax.vmap(lambda k, corner, s: _staircase(k, corner, s, clearance, config))(
        jax.random.split(key_corners, 4), corners, steps
    )
    return _compact(vertices.reshape(-1, 2), valid.reshape(-1), config.capacity)


def _clip_corners(key, corners, mask, force: Bool[Array, ""], config: RoomConfig):
    """Atlanta layout: clip convex corners with oblique walls (paper Section 5.1).

    A clipped corner V becomes ``V - c1 e_in / |e_in|`` and ``V + c2 e_out / |e_out|``
    with c in [min_step, 0.4 |e|], only where both walls are at least 2.5
    min_step long, so clips on one wall never overlap and leave no wall shorter
    than min_step / 2; a clip whose new wall would cross another wall is skipped. With ``force`` at least one
    corner is clipped. Returns the new polygon and whether a clip was possible.
    """
    key_pick, key_fraction, key_priority = jax.random.split(key, 3)
    capacity = corners.shape[0]
    previous = corners[previous_index(mask)]
    following = corners[next_index(mask)]
    edge_in, edge_out = corners - previous, following - corners
    convex = _cross2(edge_in, edge_out) > 0
    lengths = jnp.stack([jnp.linalg.norm(edge_in, axis=-1), jnp.linalg.norm(edge_out, axis=-1)], -1)
    long_enough = jnp.all(lengths >= 2.5 * config.min_step, axis=-1)
    cut = jax.random.uniform(
        key_fraction, (capacity, 2), minval=config.min_step, maxval=jnp.maximum(config.min_step, 0.4 * lengths)
    )
    fractions = cut / jnp.maximum(lengths, 1e-12)
    start = corners - fractions[:, :1] * edge_in
    end = corners + fractions[:, 1:] * edge_out
    edges = polygon_edges(corners, mask)
    index = jnp.arange(capacity)
    adjacent = (index[None, :] == index[:, None]) | (index[None, :] == previous_index(mask)[:, None])
    crossing = segments_cross(start[:, None], end[:, None], edges[None, :, 0], edges[None, :, 1])
    eligible = mask & convex & long_enough & ~jnp.any(crossing & ~adjacent & mask[None, :], axis=1)
    picked = eligible & jax.random.bernoulli(key_pick, config.clip_probability, (capacity,))
    priority = jnp.where(eligible, jax.random.uniform(key_priority, (capacity,)), -1.0)
    fallback = (index == jnp.argmax(priority)) & eligible
    picked = picked & force | jnp.where(force & ~jnp.any(picked), fallback, False)
    pairs = jnp.stack([jnp.where(picked[:, None], start, corners), end], 1).reshape(-1, 2)
    valid = jnp.stack([mask, picked & mask], 1).reshape(-1)
    new_corners, new_mask = _compact(pairs, valid, capacity)
    return new_corners, new_mask, jnp.any(eligible)


def vertex_visibility(corners: Float[Array, "K 2"], mask: Bool[Array, " K"], rc: Float[Array, ""]):
    """Which room corners the panorama sees, and which of them occlude.

    A corner P is seen in the column of azimuth ``atan2(P)`` from the optical
    centre ``rc (cos, sin)`` of that azimuth (wall-wall edges image as vertical
    lines whatever rc). It is visible if no other wall is hit before it; it is
    an occluding (silhouette) corner if both its walls lie on the same side of
    that ray, in which case the ray goes on to a farther wall.

    Returns:
        ``(visible, occluding, far_distance, neighbours_left)``, each (K,):
        ``far_distance`` is the distance along the ray (from the optical centre)
        to the wall behind an occluding corner; ``neighbours_left`` says the
        corner's own walls lie at larger azimuth (to its left in the image).
    """
    azimuth = jnp.arctan2(corners[:, 1], corners[:, 0])
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    origin = rc * direction
    own = jnp.sum(corners * direction, -1) - rc
    hits = jax.vmap(ray_hits, in_axes=(0, 0, None, None))(origin, direction, corners, mask)
    index = jnp.arange(corners.shape[0])
    adjacent = (index[None, :] == index[:, None]) | (index[None, :] == previous_index(mask)[:, None])
    other = jnp.min(jnp.where(adjacent, jnp.inf, hits), axis=1)
    visible = mask & (other > own + 1e-6)
    side_previous = _cross2(direction, corners[previous_index(mask)] - corners)
    side_next = _cross2(direction, corners[next_index(mask)] - corners)
    occluding = visible & (side_previous * side_next > 0)
    return visible, occluding, other, side_previous > 0


def _place_camera(key, corners, mask, rc, config: RoomConfig):
    """First of ``camera_tries`` uniform candidates that is inside with margin (or, with
    ``config.doorway_distance``, in a doorway) and meets the occlusion requirement; the origin (the
    rectangle's centre, kept clear by construction) is the last resort. Returns (position, status)."""
    valid_corners = jnp.where(mask[:, None], corners, corners[:1])
    low, high = jnp.min(valid_corners, 0), jnp.max(valid_corners, 0)
    candidates = jax.random.uniform(key, (config.camera_tries, 2), minval=low, maxval=high)
    candidates = candidates.at[-1].set(0.0)

    def assess(candidate):
        local = corners - candidate
        inside = point_in_polygon(candidate, corners, mask)
        distances = wall_distances(candidate, corners, mask)
        nearest = jnp.min(distances)
        if config.doorway_distance is None:
            clear = nearest > rc + config.camera_margin
        else:
            low, high = config.doorway_distance
            others = jnp.where(jnp.arange(distances.shape[0]) == jnp.argmin(distances), jnp.inf, distances)
            in_doorway = (nearest >= rc + low) & (nearest <= rc + high)
            clear = in_doorway & (jnp.min(others) > rc + config.camera_margin)
        _, occluding, _, _ = vertex_visibility(local, mask, rc)
        occluded = jnp.any(occluding)
        return inside & clear, occluded

    placeable, occluded = jax.vmap(assess)(candidates)
    wanted = {"any": placeable, "none": placeable & ~occluded, "required": placeable & occluded}[config.occlusion]
    choice = jnp.argmax(wanted)
    status = jnp.where(
        jnp.any(wanted),
        RoomStatus.OK,
        jnp.where(jnp.any(placeable), RoomStatus.OCCLUSION_REQUIREMENT_NOT_MET, RoomStatus.CAMERA_NOT_PLACED),
    )
    return candidates[choice], status


def random_room(key: PRNGKeyArray, config: RoomConfig = RoomConfig()) -> Room:
    """A random room and camera (paper Section 5.1), as a pure function of ``key``.

    ``config.room_tries`` candidate rooms are generated (vmapped) and the first
    that succeeds is returned, so rare failures (e.g. no camera position that
    sees an occlusion) almost never surface; when all fail, the returned room
    carries the failure in ``status``.

    Args:
        key: a ``jax.random`` key.
        config: static generation settings (see :class:`RoomConfig`).

    Returns:
        A :class:`Room` in the camera frame. Jit with ``config`` static, vmap over keys.
    """
    candidates = jax.vmap(lambda k: _random_room_once(k, config))(jax.random.split(key, config.room_tries))
    choice = jnp.argmax(candidates.ok)
    choice = jnp.where(jnp.any(candidates.ok), choice, config.room_tries - 1)
    return jax.tree.map(lambda leaf: leaf[choice], candidates)


def _random_room_once(key: PRNGKeyArray, config: RoomConfig) -> Room:
    """One attempt of :func:`random_room`."""
    keys = jax.random.split(key, 8)
    if config.occlusion == "required":
        # A convex room cannot occlude: at least one staircase step is needed.
        config = dataclasses.replace(config, min_walls=max(config.min_walls, 6))
    rc = jax.random.uniform(keys[4], (), minval=config.rc_range[0], maxval=config.rc_range[1])
    corners, mask = _manhattan_polygon(keys[0], rc + config.camera_margin, config)
    is_atlanta = {
        "manhattan": jnp.array(False),
        "atlanta": jnp.array(True),
        "mix": jax.random.bernoulli(keys[1], 0.5),
    }[config.world]
    clipped, clipped_mask, clippable = _clip_corners(keys[2], corners, mask, is_atlanta, config)
    corners = jnp.where(is_atlanta, clipped, corners)
    mask = jnp.where(is_atlanta, clipped_mask, mask)
    yaw = jax.random.uniform(keys[3], (), minval=0.0, maxval=2 * math.pi)
    corners = corners @ rotation_z(yaw)[:2, :2].T
    room_height = jax.random.uniform(keys[5], (), minval=config.height_range[0], maxval=config.height_range[1])
    camera_height = jax.random.uniform(
        keys[6], (), minval=config.camera_height_range[0], maxval=config.camera_height_range[1]
    )
    camera_xy, camera_status = _place_camera(keys[7], corners, mask, rc, config)
    edge_lengths = jnp.linalg.norm(corners[next_index(mask)] - corners, axis=-1)
    well_formed = (
        is_simple(corners, mask)
        & (polygon_area(corners, mask) > 0)
        & jnp.all(jnp.where(mask, edge_lengths, jnp.inf) > 0.5 * config.min_step)
    )
    status = jnp.where(
        is_atlanta & ~clippable,
        RoomStatus.NO_CORNER_TO_CLIP,
        jnp.where(well_formed, camera_status, RoomStatus.DEGENERATE_POLYGON),
    )
    local = jnp.where(mask[:, None], corners - camera_xy, 0.0)
    return Room(
        corners=local,
        mask=mask,
        ceiling_height=room_height - camera_height,
        floor_height=-camera_height,
        rc=rc,
        camera_position=jnp.concatenate([camera_xy, camera_height[None]]),
        is_atlanta=is_atlanta,
        status=status.astype(jnp.int32),
    )


# ------------------------------------------------------------------- walls and corners


def room_walls(room: Room):
    """The room's walls: unit directions (K, 2), signed distances (K,) along
    ``e2 = (-uy, ux)`` and the ceiling and floor Plücker lines (K, 6) each
    (docs/design.md section 3). For a counter-clockwise room around the camera the
    distances are negative. Masked slots hold a harmless unit wall."""
    start = room.corners
    end = room.corners[next_index(room.mask)]
    delta = end - start
    length = jnp.linalg.norm(delta, axis=-1, keepdims=True)
    direction = jnp.where(
        room.mask[:, None] & (length > 0), delta / jnp.where(length > 0, length, 1.0), jnp.array([1.0, 0.0])
    )
    normal = jnp.stack([-direction[:, 1], direction[:, 0]], -1)
    distance = jnp.sum(start * normal, -1)
    return (
        direction,
        distance,
        horizontal_wall_line(direction, distance, room.ceiling_height),
        horizontal_wall_line(direction, distance, room.floor_height),
    )


def room_corners_3d(room: Room) -> tuple[Float[Array, "K 3"], Float[Array, "K 3"]]:
    """The full room's ceiling and floor corners (K, 3), camera frame."""
    heights = jnp.stack([room.ceiling_height, room.floor_height])
    points = jnp.concatenate(
        [
            jnp.broadcast_to(room.corners, (2,) + room.corners.shape),
            jnp.broadcast_to(heights[:, None, None], (2, room.corners.shape[0], 1)),
        ],
        -1,
    )
    return points[0], points[1]
