"""Ray-scene intersection and surface appearance for the path tracer (:mod:`ncjax.synth.pathtrace`).

Unlike the ray caster (:mod:`ncjax.synth.raycast`), whose rays all leave a column's optical centre in its
vertical plane, a path's rays go anywhere, so each ray is intersected in 3D with the whole scene: the room's
prism (the wall polygon from :func:`~ncjax.synth.rooms.ray_hits`, the floor and ceiling planes) and the boxes
(the footprint slab test :func:`~ncjax.synth.raycast.box_interval_2d` with a vertical slab). Everything is
written for ONE ray and batched with ``jax.vmap``.

Doors and windows stay rectangles on the wall planes, as in the ray caster, so a hit's albedo matches its
colours there. Where the ray caster shows the sky through a window's glass the wall has a hole: the ray leaves
the room (:attr:`SurfaceKind.ESCAPE`) and reads the environment. With decor, a ray through an open door or
passage goes on, as in the ray caster, through the door's lining (the wall's thickness) into the box-shaped
room behind it (:class:`~ncjax.synth.elements.Doorways`), whose floor, walls and ceiling it meets
(:attr:`SurfaceKind.NEXT_ROOM`): that room is seen, lit as the ray caster lights it (evenly, darker towards
its edges; its skirting boards drawn), but paths do not go on in it.
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ..geometry.polygon import perpendicular
from .elements import FRAME_WIDTH
from .materials import Material, material_albedo
from .raycast import box_interval_2d
from .render_details import (
    ambient_facing,
    ceiling_panels,
    decal_appearance,
    edge_darkening,
    in_span,
    opening_appearance,
    with_skirting,
)
from .rooms import ray_hits, room_walls
from .scene import Scene

# Far distance given to rays that meet nothing (only in rooms whose polygon is invalid): finite, so that no
# NaN comes out of the arithmetic on their (discarded) hit points.
_FAR = 1e3


class SurfaceKind(enum.IntEnum):
    """What a ray meets (:attr:`Hit.kind`)."""

    ESCAPE = 0  # left the room through a window's glass (or met nothing): the environment
    FLOOR = 1
    CEILING = 2
    WALL = 3
    BOX = 4  # furniture, lamps, door leaves
    NEXT_ROOM = 5  # through an open door: the room behind it, or the door's lining


class Hit(eqx.Module):
    """Where one ray first meets the scene (all fields traced).

    Attributes:
        distance: along the (unit) ray, metres; for an escape through a window, to the wall plane.
        point: (3,) the hit point, camera frame.
        normal: (3,) unit normal of the surface, on the ray's side.
        kind: a :class:`SurfaceKind`.
        index: the wall's slot (walls, and the wall a ray left through) or the box's slot (boxes), else 0.
        along: where the ray crosses that wall's plane, from its first corner (walls, and the window or door
            a ray left through).
    """

    distance: Float[Array, ""]
    point: Float[Array, 3]
    normal: Float[Array, 3]
    kind: Int[Array, ""]
    index: Int[Array, ""]
    along: Float[Array, ""]


def box_interval_3d(
    origin: Float[Array, 3],
    direction: Float[Array, 3],
    centre: Float[Array, 3],
    half_size: Float[Array, 3],
    rotation: Float[Array, 2],
) -> tuple[Float[Array, ""], Float[Array, ""], Float[Array, 3]]:
    """Slab test of a 3D ray against a box rotated about z: the footprint's interval
    (:func:`~ncjax.synth.raycast.box_interval_2d`, which holds for the horizontal part of any ray) cut by the
    vertical slab.

    Returns:
        ``(t_in, t_out, normal)``: the ray parameters where it enters and leaves the box (empty when
        ``t_in >= t_out``) and the outward normal of the entry face.
    """
    t_in, t_out, normal_2d = box_interval_2d(origin[:2], direction[:2], centre[:2], half_size[:2], rotation)
    dz = jnp.where(jnp.abs(direction[2]) > 1e-12, direction[2], 1e-12)
    t_a, t_b = (centre[2] - half_size[2] - origin[2]) / dz, (centre[2] + half_size[2] - origin[2]) / dz
    near, far = jnp.minimum(t_a, t_b), jnp.maximum(t_a, t_b)
    normal = jnp.where(near > t_in, jnp.stack([0.0, 0.0, -jnp.sign(dz)]), jnp.append(normal_2d, 0.0))
    return jnp.maximum(t_in, near), jnp.minimum(t_out, far), normal


def _opening_slot(
    scene: Scene, wall: Int[Array, ""], along: Float[Array, ""]
) -> tuple[Bool[Array, ""], Int[Array, ""]]:
    """Whether a point ``along`` a wall is in a door's or window's span, and its slot (for a hit: the point where
    its ray crossed the wall, ``hit.index`` and ``hit.along``)."""
    openings = scene.openings
    present, slot = in_span(openings.wall, openings.span, openings.mask, wall[None], along[None])
    return present[0], slot[0]


def _opening_at(scene: Scene, wall: Int[Array, ""], along: Float[Array, ""], z: Float[Array, ""]):
    """The door or window at a point of a wall: whether the point is inside one's rectangle, whether it is on
    a window's glass, whether it is in an open door's aperture (with decor), the ray caster's albedo of the
    rectangle, and the opening's slot."""
    openings = scene.openings
    present, slot = _opening_slot(scene, wall, along)
    fields = dict(
        start=openings.span[slot, 0],
        width=openings.span[slot, 1] - openings.span[slot, 0],
        bottom=openings.z_range[slot, 0],
        tall=openings.z_range[slot, 1] - openings.z_range[slot, 0],
        is_window=openings.is_window[slot],
        colour=openings.colour[slot],
        frame_colour=openings.frame_colour[slot],
    )
    inside = present & (z >= fields["bottom"]) & (z <= fields["bottom"] + fields["tall"])
    albedo, emission = opening_appearance(fields, along, z)
    # The ray caster draws the sky where a window's glass is (it glows there): that is where light comes in.
    glass = inside & fields["is_window"] & jnp.any(emission > 0)
    aperture = jnp.zeros((), bool)
    if scene.decor is not None:
        x = along - fields["start"]
        aperture = (
            inside
            & scene.decor.doorways.is_open[slot]
            & (x > FRAME_WIDTH)
            & (x < fields["width"] - FRAME_WIDTH)
            & (z < fields["bottom"] + fields["tall"] - FRAME_WIDTH)
        )
    return inside, glass, aperture, albedo, slot


def _box_exit(
    start: Float[Array, 3], velocity: Float[Array, 3], low: Float[Array, 3], high: Float[Array, 3]
) -> tuple[Float[Array, ""], Int[Array, ""]]:
    """Where a ray inside an axis-aligned box leaves it: the parameter and the axis of the face it leaves by."""
    safe = jnp.where(jnp.abs(velocity) > 1e-12, velocity, 1e-12)
    exits = (jnp.where(safe > 0, high, low) - start) / safe
    axis = jnp.argmin(exits)
    return exits[axis], axis


def next_room_hit(
    scene: Scene,
    slot: Int[Array, ""],
    along: Float[Array, ""],
    z: Float[Array, ""],
    direction: Float[Array, 3],
    wall_direction: Float[Array, 2],
) -> tuple[Float[Array, ""], Float[Array, 3]]:
    """What a ray that crosses a wall's plane inside an open door's aperture meets behind it, as the ray caster
    draws it (:func:`~ncjax.synth.render_details.doorway_columns`): first the door's lining, a box as deep as
    the wall is thick, between the frame's inner edges, from the floor to the lintel; through its far side the
    room behind, a box ``room_depth`` deep reaching ``room_sides`` beyond the frame, up to ``room_ceiling``.

    Args:
        scene: the scene (with decor); slot: the door's slot in ``scene.openings``.
        along, z: where the ray crosses the wall's plane (along the wall from its first corner, and height).
        direction: (3,) the ray's unit direction; wall_direction: (2,) the wall's.

    Returns:
        ``(beyond, normal)``: the distance from the crossing to the surface met, and its unit normal facing
        the ray.
    """
    openings, doorways, room = scene.openings, scene.decor.doorways, scene.room
    # The wall's frame: along it, out of the room through it, up.
    outward = -perpendicular(wall_direction)
    outward = jnp.where(jnp.dot(direction[:2], outward) < 0, -outward, outward)
    velocity = jnp.stack([jnp.dot(direction[:2], wall_direction), jnp.dot(direction[:2], outward), direction[2]])
    low_side, high_side = openings.span[slot, 0] + FRAME_WIDTH, openings.span[slot, 1] - FRAME_WIDTH
    thickness = doorways.wall_thickness[slot]
    lintel = openings.z_range[slot, 1] - FRAME_WIDTH
    start = jnp.stack([along, 0.0, z])
    in_lining, lining_axis = _box_exit(
        start,
        velocity,
        jnp.stack([low_side, 0.0, room.floor_height]),
        jnp.stack([high_side, thickness, lintel]),
    )
    in_room, room_axis = _box_exit(
        start + in_lining * velocity,
        velocity,
        jnp.stack([low_side - FRAME_WIDTH - doorways.room_sides[slot, 0], thickness, room.floor_height]),
        jnp.stack(
            [
                high_side + FRAME_WIDTH + doorways.room_sides[slot, 1],
                thickness + doorways.room_depth[slot],
                doorways.room_ceiling[slot],
            ]
        ),
    )
    through = lining_axis == 1  # left the lining by its far side, into the room
    beyond = in_lining + jnp.where(through, in_room, 0.0)
    axis = jnp.where(through, room_axis, lining_axis)
    local = -jnp.sign(velocity[axis]) * jax.nn.one_hot(axis, 3)  # the face's normal, towards the ray
    normal = jnp.append(local[0] * wall_direction + local[1] * outward, local[2])
    return beyond, normal


def intersect(scene: Scene, origin: Float[Array, 3], direction: Float[Array, 3]) -> Hit:
    """The first surface a ray meets (ONE ray; batch with ``jax.vmap``).

    Args:
        scene: the scene (camera frame); the ray starts inside its room, outside its boxes.
        origin: (3,) the ray's start, metres.
        direction: (3,) its unit direction.

    Returns:
        The :class:`Hit`. Surfaces at parameter ``t <= 0`` are ignored, so a ray that leaves a surface
        should start a little off it (e.g. 1e-4 m along the normal).
    """
    room, boxes = scene.room, scene.boxes
    # The prism: the wall polygon seen along the horizontal part of the ray (its parameter is the 3D one),
    # capped by the floor and ceiling planes.
    wall_hits = ray_hits(origin[:2], direction[:2], room.corners, room.mask)
    wall = jnp.argmin(wall_hits)
    t_wall = wall_hits[wall]
    dz = jnp.where(jnp.abs(direction[2]) > 1e-12, direction[2], 1e-12)
    height = jnp.where(direction[2] < 0, room.floor_height, room.ceiling_height)
    t_flat = jnp.where(direction[2] != 0, (height - origin[2]) / dz, jnp.inf)
    t_flat = jnp.where(t_flat > 0, t_flat, jnp.inf)
    t_in, t_out, box_normals = jax.vmap(box_interval_3d, in_axes=(None, None, 0, 0, 0))(
        origin, direction, boxes.centre, boxes.half_size, boxes.rotation
    )
    t_box = jnp.where(boxes.mask & (t_in < t_out) & (t_in > 0), t_in, jnp.inf)
    box = jnp.argmin(t_box)
    t_box = t_box[box]

    on_box = t_box < jnp.minimum(t_wall, t_flat)
    on_wall = ~on_box & (t_wall <= t_flat) & jnp.isfinite(t_wall)
    on_flat = ~on_box & ~on_wall & jnp.isfinite(t_flat)
    distance = jnp.minimum(jnp.minimum(t_box, t_wall), t_flat)
    distance = jnp.where(jnp.isfinite(distance), distance, _FAR)
    wall_direction, _, _, _ = room_walls(room)
    crossing = origin + jnp.where(jnp.isfinite(t_wall), t_wall, distance) * direction
    along = jnp.sum((crossing[:2] - room.corners[wall]) * wall_direction[wall])
    _, glass, aperture, _, slot = _opening_at(scene, wall, along, crossing[2])
    flat_kind = jnp.where(direction[2] < 0, SurfaceKind.FLOOR, SurfaceKind.CEILING)
    kind = jnp.where(
        on_box,
        SurfaceKind.BOX,
        jnp.where(on_wall & ~glass, SurfaceKind.WALL, jnp.where(on_flat, flat_kind, SurfaceKind.ESCAPE)),
    )
    normal = jnp.where(
        on_box,
        box_normals[box],
        jnp.where(on_wall, jnp.append(perpendicular(wall_direction[wall]), 0.0), jnp.stack([0.0, 0.0, -jnp.sign(dz)])),
    )
    if scene.decor is not None:
        into_next_room = on_wall & aperture
        beyond, next_normal = next_room_hit(scene, slot, along, crossing[2], direction, wall_direction[wall])
        distance = jnp.where(into_next_room, distance + beyond, distance)
        kind = jnp.where(into_next_room, SurfaceKind.NEXT_ROOM, kind)
        normal = jnp.where(into_next_room, next_normal, normal)
    # Facing the ray, whatever side it came from (a ray that started inside a box sees its faces from within).
    normal = jnp.where(jnp.dot(normal, direction) > 0, -normal, normal)
    return Hit(
        distance=distance,
        point=origin + distance * direction,
        normal=normal,
        kind=kind.astype(jnp.int32),
        index=jnp.where(on_box, box, jnp.where(on_wall, wall, 0)).astype(jnp.int32),
        along=along,
    )


def leaves_through_a_window(scene: Scene, hit: Hit) -> Bool[Array, ""]:
    """Whether a ray that met ``hit`` left the room through a window's glass (not through an open door, which
    leads to another room)."""
    present, slot = _opening_slot(scene, hit.index, hit.along)
    return (hit.kind == SurfaceKind.ESCAPE) & present & scene.openings.is_window[slot]


def next_room_radiance(
    scene: Scene, hit: Hit, direction: Float[Array, 3], irradiance: Float[Array, 3], textured: bool = True
) -> Float[Array, 3]:
    """The radiance of a surface of a room behind an open door (:attr:`SurfaceKind.NEXT_ROOM`; 0 elsewhere),
    met by a ray of unit ``direction``.

    That room is lit as the ray caster lights it: ``irradiance`` times the door's ``room_light``, shaded by
    the way the surface faces (brighter towards ``scene.ambient_direction``) and darkened towards the room's
    edges (:func:`~ncjax.synth.render_details.edge_darkening`), on a Lambertian surface of
    :func:`surface_appearance`'s albedo, or with ``textured`` False (static) of its material's mean colour
    (cheaper, for the light it sheds through the door).
    """
    if scene.decor is None:
        return jnp.zeros(3)
    if textured:
        albedo, _ = surface_appearance(scene, hit)
    else:
        material, _, _, _, in_lining, lining_colour = _next_room_surface(scene, hit)
        albedo = jnp.where(in_lining, lining_colour, (material.colour_a + material.colour_b) / 2)
    _, slot = _opening_slot(scene, hit.index, hit.along)
    facing = ambient_facing(tuple(hit.normal), scene.ambient_direction)
    darkening = edge_darkening(_next_room_edge_distance(scene, hit, direction, slot))
    light = scene.decor.doorways.room_light[slot] * facing * darkening * irradiance / jnp.pi
    return jnp.where(hit.kind == SurfaceKind.NEXT_ROOM, albedo * light, 0.0)


def _next_room_edge_distance(scene: Scene, hit: Hit, direction: Float[Array, 3], slot: Int[Array, ""]):
    """How far a hit in the room behind a door lies from that room's edges, as the ray caster measures it: on
    an upright surface, from the floor or the room's ceiling; on the floor or a ceiling, horizontally along
    the ray to the first upright surface it would meet (a jamb, a side or the back wall)."""
    along_wall, _, behind_wall = _behind_door_wall(scene, hit)
    level = jnp.append(direction[:2], 0.0) / jnp.maximum(jnp.linalg.norm(direction[:2]), 1e-9)
    to_upright, _ = next_room_hit(scene, slot, hit.along, scene.room.floor_height, level, along_wall)
    travelled = behind_wall / jnp.maximum(jnp.abs(jnp.dot(level[:2], perpendicular(along_wall))), 1e-9)
    height = hit.point[2] - scene.room.floor_height
    upright = jnp.minimum(height, scene.decor.doorways.room_ceiling[slot] - hit.point[2])
    return jnp.where(jnp.abs(hit.normal[2]) > 0.5, to_upright - travelled, upright)


def _behind_door_wall(scene: Scene, hit: Hit):
    """Where a hit in the room behind a door lies from the wall the door is in: that wall's unit direction,
    the hit's plan offset from the wall's first corner, and its distance behind the wall's plane."""
    wall_direction, _, _, _ = room_walls(scene.room)
    along_wall = wall_direction[hit.index]
    offset = hit.point[:2] - scene.room.corners[hit.index]
    return along_wall, offset, jnp.abs(jnp.dot(offset, perpendicular(along_wall)))


def _box_coordinates(scene: Scene, hit: Hit):
    """The ray caster's texture coordinates on a box: along the face and up it on a side face, the box's own
    axes on its top and bottom."""
    boxes = scene.boxes
    centre, rotation = boxes.centre[hit.index], boxes.rotation[hit.index]
    offset = hit.point[:2] - centre[:2]
    local_x = offset[0] * rotation[0] + offset[1] * rotation[1]
    local_y = offset[1] * rotation[0] - offset[0] * rotation[1]
    side_face = jnp.abs(hit.normal[2]) < 0.5
    facing_x = jnp.abs(hit.normal[0] * rotation[0] + hit.normal[1] * rotation[1]) > 0.5
    return jnp.where(side_face & facing_x, local_y, local_x), jnp.where(side_face, hit.point[2], local_y)


def _select(condition: Bool[Array, ""], first: Material, second: Material) -> Material:
    """``first`` where ``condition`` holds, else ``second``, field by field."""
    return jax.tree.map(lambda p, q: jnp.where(condition, p, q), first, second)


def _next_room_surface(scene: Scene, hit: Hit):
    """The ray caster's surface at a hit in the room behind a door: its material and seed offset, whether it is
    flat (floor or ceiling, textured along the plan), its coordinate along an upright surface (along the wall on
    the back wall, the depth behind the wall on the side walls), whether it is on the door's lining (the wall's
    thickness) and the lining's colour."""
    decor = scene.decor
    along_wall, offset, behind_wall = _behind_door_wall(scene, hit)
    floor, ceiling = hit.normal[2] > 0.5, hit.normal[2] < -0.5
    material = _select(ceiling, scene.ceiling, _select(floor, decor.next_floor, decor.next_walls))
    seed = jnp.where(ceiling, 4, jnp.where(floor, 5, 6))
    back_wall = jnp.abs(jnp.dot(hit.normal[:2], along_wall)) < 0.5
    wall_a = jnp.where(back_wall, jnp.dot(offset, along_wall), behind_wall)
    _, slot = _opening_slot(scene, hit.index, hit.along)
    in_lining = behind_wall < decor.doorways.wall_thickness[slot] + 1e-4
    return material, seed, floor | ceiling, wall_a, in_lining, scene.openings.frame_colour[slot]


def surface_appearance(scene: Scene, hit: Hit) -> tuple[Float[Array, 3], Bool[Array, ""]]:
    """The albedo at a hit, as the ray caster colours it (the same materials, seeds and texture coordinates;
    skirting boards, doors and window frames; with decor, posters and pictures, the light panels' diffusers and
    the rooms behind open doors with their doors' linings), and whether it is the room's floor (glossy).

    Sunlight, which the ray caster paints on as a detail, is not drawn: here the windows' light is traced.
    """
    room, boxes, kind = scene.room, scene.boxes, hit.kind
    x, y, z = hit.point[0] + room.camera_position[0], hit.point[1] + room.camera_position[1], hit.point[2]
    plan_a, plan_b = x, y
    if scene.decor is not None:
        # Floors and ceilings are textured along the room's main axis, as boards and tiles are laid.
        axis = scene.decor.plan_axis
        plan_a, plan_b = x * axis[0] + y * axis[1], y * axis[0] - x * axis[1]
    box_a, box_b = _box_coordinates(scene, hit)
    is_box, is_floor, is_ceiling = kind == SurfaceKind.BOX, kind == SurfaceKind.FLOOR, kind == SurfaceKind.CEILING
    height_above_floor = z - room.floor_height
    a = jnp.where(is_box, box_a, jnp.where(is_floor | is_ceiling, plan_a, hit.along))
    b = jnp.where(is_box, box_b, jnp.where(is_floor | is_ceiling, plan_b, height_above_floor))

    box_material = jax.tree.map(lambda field: field[hit.index], boxes.material)
    material = _select(
        is_box, box_material, _select(is_floor, scene.floor, _select(is_ceiling, scene.ceiling, scene.walls))
    )
    seed = jnp.where(is_box, 100 + 13 * hit.index, jnp.where(is_ceiling, 1, jnp.where(is_floor, 2, 3)))
    in_opening, _, _, opening_albedo, _ = _opening_at(scene, hit.index, hit.along, z)
    if scene.decor is not None:
        next_room = kind == SurfaceKind.NEXT_ROOM
        next_material, next_seed, next_flat, next_wall_a, in_lining, lining_colour = _next_room_surface(scene, hit)
        a = jnp.where(next_room, jnp.where(next_flat, plan_a, next_wall_a), a)
        b = jnp.where(next_room, jnp.where(next_flat, plan_b, height_above_floor), b)
        material = _select(next_room, next_material, material)
        seed = jnp.where(next_room, next_seed, seed)
    albedo = material_albedo(material, scene.seed + seed, a, b, decor=scene.decor is not None)

    on_wall = kind == SurfaceKind.WALL
    skirted = on_wall & ~in_opening
    if scene.decor is not None:
        # The room behind a door has skirting boards too (not in the door's lining), as the ray caster draws it.
        skirted = skirted | (next_room & (jnp.abs(hit.normal[2]) < 0.5) & ~in_lining)
    albedo = with_skirting(albedo, skirted, height_above_floor, scene.skirting_height, scene.skirting_colour)
    if scene.decor is not None:
        in_decal, decal_albedo = _decal_at(scene, hit.index, hit.along, z)
        albedo = jnp.where(on_wall & ~in_opening & in_decal, decal_albedo, albedo)
        # The panels are placed in the camera frame, as the ray caster reads them.
        in_panel, rim, _ = ceiling_panels(scene.decor.panels, hit.point[0][None], hit.point[1][None])
        albedo = jnp.where(is_ceiling & in_panel[0], jnp.where(rim[0], 0.7, 0.95), albedo)
        albedo = jnp.where(next_room & in_lining, lining_colour, albedo)
    return jnp.where(on_wall & in_opening, opening_albedo, albedo), is_floor


def _decal_at(scene: Scene, wall: Int[Array, ""], along: Float[Array, ""], z: Float[Array, ""]):
    """Whether a point of a wall is on a poster, picture or whiteboard, and the ray caster's albedo there."""
    decals = scene.decor.decals
    present, slot = in_span(decals.wall, decals.span, decals.mask, wall[None], along[None])
    bottom, top = decals.z_range[slot[0], 0], decals.z_range[slot[0], 1]
    fields = dict(
        start=decals.span[slot, 0],
        width=decals.span[slot, 1] - decals.span[slot, 0],
        bottom=decals.z_range[slot, 0],
        tall=decals.z_range[slot, 1] - decals.z_range[slot, 0],
        kind=decals.kind[slot],
        colour_a=decals.colour_a[slot],
        colour_b=decals.colour_b[slot],
        frame_colour=decals.frame_colour[slot],
        frame_width=decals.frame_width[slot],
    )
    albedo = decal_appearance(fields, along[None], z[None], scene.seed + 200 + 7 * slot)[0]
    return present[0] & (z > bottom) & (z < top), albedo


def surface_emission(scene: Scene, hit: Hit) -> Float[Array, 3]:
    """The radiance a hit surface emits itself: an emissive box's (lamp shades), or with decor a light panel's
    in the ceiling (inside its rim)."""
    emission = jnp.where(hit.kind == SurfaceKind.BOX, scene.boxes.emission[hit.index], 0.0)
    if scene.decor is None:
        return emission
    _, _, panel = ceiling_panels(scene.decor.panels, hit.point[0][None], hit.point[1][None])
    return jnp.where(hit.kind == SurfaceKind.CEILING, panel[0], emission)
