"""Details the renderer adds over the room's surfaces without touching its layout:
doors and windows, decals on walls, light panels in the ceiling, sunlight, and
the rooms seen through open doors (:mod:`ncjax.synth.render` calls these per
column and per row).

The layout stays exact because all of these are decided where the ray meets
the room's own surfaces: a decal or a door is drawn on the wall plane, a panel
on the ceiling plane, and a ray through an open door only goes on past the
wall once it has met the wall plane inside the doorway (between the ceiling and
floor boundaries of its column).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .elements import FRAME_WIDTH, DecalKind, Panels, SunPatches
from .materials import hash_uniform, value_noise


def in_span(
    walls: Int[Array, " N"], span: Float[Array, "N 2"], mask: Bool[Array, " N"], wall: Int[Array, " W"], along
) -> tuple[Bool[Array, " W"], Int[Array, " W"]]:
    """Per column: whether a wall rectangle (door, window, decal) covers the point
    ``along`` its wall ``wall`` horizontally, and the first such rectangle."""
    covers = (
        (walls[None, :] == wall[:, None])
        & (span[None, :, 0] <= along[:, None])
        & (along[:, None] <= span[None, :, 1])
        & mask[None, :]
    )
    return jnp.any(covers, axis=1), jnp.argmax(covers, axis=1)


def opening_appearance(opening: dict, along, height):
    """Albedo and emission of a door or window (fields of ``opening`` per column)
    at coordinates inside it: a frame, inset door panels with a handle, or glass
    panes split by mullions that glow with daylight."""
    x, y = along - opening["start"], height - opening["bottom"]
    width, tall, window = opening["width"], opening["tall"], opening["is_window"]
    frame = FRAME_WIDTH
    on_frame = (x < frame) | (x > width - frame) | (y > tall - frame) | (window & (y < frame))
    mullion = window & ((jnp.abs(x - width / 2) < 0.025) | (jnp.abs(y - 0.6 * tall) < 0.025))
    in_panel = (
        (x > 0.14) & (x < width - 0.14) & (((y > 0.12) & (y < 0.45 * tall)) | ((y > 0.5 * tall) & (y < tall - 0.14)))
    )
    panel_edge = in_panel & (
        (x < 0.16)
        | (x > width - 0.16)
        | (jnp.abs(y - 0.12) < 0.02)
        | (jnp.abs(y - 0.45 * tall) < 0.02)
        | (jnp.abs(y - 0.5 * tall) < 0.02)
        | (jnp.abs(y - tall + 0.14) < 0.02)
    )
    handle = ~window & ((x - (width - 0.1)) ** 2 + (y - 1.0) ** 2 < 0.035**2)
    leaf = opening["colour"] * (jnp.where(panel_edge, 0.55, 1.0) * jnp.where(handle, 0.2, 1.0))[..., None]
    sky = opening["colour"] * (0.75 + 0.35 * y / tall)[..., None]
    framed = (on_frame | mullion)[..., None]
    albedo = jnp.where(framed, opening["frame_colour"], jnp.where(window[..., None], 0.0, leaf))
    emission = jnp.where(framed | ~window[..., None], 0.0, 1.6 * sky)
    return albedo, emission


def decal_appearance(decal: dict, along, height, seed) -> Float[Array, "W 3"]:
    """Albedo of a poster, picture or whiteboard (fields of ``decal`` per column)
    at coordinates inside it: a frame around blocks of two colours (poster), a
    white mat around a two-colour landscape (picture), or white with faint
    smudges (whiteboard)."""
    x, y = along - decal["start"], height - decal["bottom"]
    width, tall, frame = decal["width"], decal["tall"], decal["frame_width"]
    kind = decal["kind"]
    noise = value_noise(seed, x / 0.15, y / 0.15)

    def within(margin):
        return (x > margin) & (x < width - margin) & (y > margin) & (y < tall - margin)

    blocks = hash_uniform(seed, jnp.floor(3 * x / width).astype(jnp.int32), jnp.floor(4 * y / tall).astype(jnp.int32))
    poster = jnp.where((blocks > 0.5)[:, None], decal["colour_a"], decal["colour_b"]) * (0.85 + 0.15 * noise)[:, None]
    sky = y / tall > 0.45 + 0.2 * noise
    picture = jnp.where(sky[:, None], decal["colour_a"], decal["colour_b"]) * (0.7 + 0.3 * noise)[:, None]
    board = decal["colour_a"] * (1.0 - 0.08 * noise)[:, None]
    content = jnp.where(
        (kind == DecalKind.WHITEBOARD)[:, None], board, jnp.where((kind == DecalKind.PICTURE)[:, None], picture, poster)
    )
    mat = (kind == DecalKind.PICTURE) & ~within(2 * frame)
    content = jnp.where(mat[:, None], 0.92, content)
    return jnp.where(within(frame)[:, None], content, decal["frame_colour"])


def ceiling_panels(panels: Panels, x, y):
    """Per pixel (ceiling points ``x, y``): inside a light panel, on its 2 cm
    non-emissive rim, and the panel's emission."""
    inside = jnp.zeros(x.shape, bool)
    rim = jnp.zeros(x.shape, bool)
    emission = jnp.zeros(x.shape + (3,))
    for p in range(panels.mask.shape[0]):
        dx, dy = x - panels.centre[p, 0], y - panels.centre[p, 1]
        cos, sin = panels.rotation[p, 0], panels.rotation[p, 1]
        local_x, local_y = jnp.abs(dx * cos + dy * sin), jnp.abs(dy * cos - dx * sin)
        half_x, half_y = panels.half_size[p, 0], panels.half_size[p, 1]
        here = panels.mask[p] & (local_x < half_x) & (local_y < half_y)
        edge = here & ((local_x > half_x - 0.02) | (local_y > half_y - 0.02))
        emission = jnp.where((here & ~edge)[:, None], panels.emission[p], emission)
        inside, rim = inside | here, rim | edge
    return inside, rim, emission


def sunlight(sun: SunPatches, point, normal) -> Float[Array, "W 3"]:
    """Irradiance of the sun at points ``(x, y, z)`` with unit normals ``(normal_x, normal_y, normal_z)`` (each
    a tuple of coordinate arrays): where the line back towards the sun crosses a window's glass (inside its
    frame, off its mullions), so that patches carry the window's shape."""
    x, y, z = point
    normal_x, normal_y, normal_z = normal
    irradiance = jnp.zeros(x.shape + (3,))
    for s in range(sun.mask.shape[0]):
        dx, dy, dz = sun.direction[s, 0], sun.direction[s, 1], sun.direction[s, 2]
        ox, oy = x - sun.origin[s, 0], y - sun.origin[s, 1]
        into = ox * sun.normal[s, 0] + oy * sun.normal[s, 1]
        back = into / (dx * sun.normal[s, 0] + dy * sun.normal[s, 1])
        along = (ox - back * dx) * sun.axis[s, 0] + (oy - back * dy) * sun.axis[s, 1] - sun.span[s, 0]
        up = z - back * dz - sun.z_range[s, 0]
        width, tall = sun.span[s, 1] - sun.span[s, 0], sun.z_range[s, 1] - sun.z_range[s, 0]
        glass = (
            (along > FRAME_WIDTH)
            & (along < width - FRAME_WIDTH)
            & (up > FRAME_WIDTH)
            & (up < tall - FRAME_WIDTH)
            & (jnp.abs(along - width / 2) > 0.025)
            & (jnp.abs(up - 0.6 * tall) > 0.025)
        )
        cosine = jnp.maximum(-(normal_x * dx + normal_y * dy + normal_z * dz), 0.0)
        lit = sun.mask[s] & (back > 0.02) & glass
        irradiance = irradiance + (jnp.where(lit, cosine, 0.0))[:, None] * sun.colour[s]
    return irradiance


def doorway_columns(opening: dict, direction, t_wall, along, wall_direction, wall_normal) -> dict:
    """Per column, the horizontal path of a ray through an open door: whether it
    passes inside the door frame, where it leaves the wall's thickness (the
    jamb's end) and which upright surface it meets behind the wall (a jamb, a
    side wall or the back wall of the room behind), with that surface's normal
    and horizontal texture coordinate."""
    # The ray in the wall's frame: along the wall, and out through it (> 0).
    out = -jnp.sum(direction * wall_normal, -1)
    sideways = jnp.sum(direction * wall_direction, -1)
    out = jnp.maximum(out, 1e-6)
    sideways = jnp.where(jnp.abs(sideways) > 1e-9, sideways, 1e-9)
    forward = sideways > 0
    low, high = opening["start"] + FRAME_WIDTH, opening["start"] + opening["width"] - FRAME_WIDTH
    aperture = opening["present"] & opening["is_open"] & (along > low) & (along < high)
    t_tunnel = t_wall + opening["wall_thickness"] / out
    t_jamb = t_wall + (jnp.where(forward, high, low) - along) / sideways
    side = jnp.where(
        forward, high + FRAME_WIDTH + opening["room_sides"][:, 1], low - FRAME_WIDTH - opening["room_sides"][:, 0]
    )
    t_side = t_wall + (side - along) / sideways
    t_back = t_wall + (opening["wall_thickness"] + opening["room_depth"]) / out
    on_jamb = t_jamb < t_tunnel
    on_back = ~on_jamb & (t_back <= t_side)
    t_upright = jnp.where(on_jamb, t_jamb, jnp.minimum(t_side, t_back))
    facing = jnp.where(forward, -1.0, 1.0)[:, None] * wall_direction
    normal = jnp.where(on_back[:, None], wall_normal, facing)
    beyond = t_upright - t_wall
    return dict(
        aperture=aperture,
        lintel=opening["bottom"] + opening["tall"] - FRAME_WIDTH,
        ceiling=opening["room_ceiling"],
        light=opening["room_light"],
        t_tunnel=t_tunnel,
        t_upright=t_upright,
        normal_x=normal[:, 0],
        normal_y=normal[:, 1],
        texture_a=jnp.where(on_back, along + sideways * beyond, out * beyond),
    )


def edge_darkening(to_edge) -> Array:
    """The factor of the ambient light at ``to_edge`` metres from the nearest edge of a room (where a wall
    meets the floor, the ceiling or another wall): 0.65 on the edge, within 5% of 1 beyond 0.6 m; the soft
    darkening into corners that light bouncing between surfaces gives, which the ray caster does not trace."""
    return 1.0 - 0.35 * jnp.exp(-jnp.maximum(to_edge, 0.0) / 0.3)


def with_skirting(albedo, on_wall, height_above_floor, skirting_height, skirting_colour) -> Array:
    """``albedo`` (``(..., 3)``) with the skirting boards drawn where ``on_wall`` (``(...)``) points lie below
    ``skirting_height``: ``skirting_colour``, darker on the board's top lip."""
    skirting = on_wall & (height_above_floor < skirting_height)
    lip = height_above_floor > skirting_height - 0.012
    return jnp.where(skirting[..., None], skirting_colour * jnp.where(lip, 0.7, 1.0)[..., None], albedo)


def ambient_facing(normal, direction) -> Array:
    """The factor of the hemispherical ambient light on surfaces of unit ``normal`` (a tuple of coordinate
    arrays): brighter facing ``direction``, where it comes from most (as daylight from a window), so that walls
    of different orientations are shaded differently, as in real rooms."""
    normal_x, normal_y, normal_z = normal
    return 0.7 + 0.3 * (normal_x * direction[0] + normal_y * direction[1] + normal_z * direction[2])


def through_doorway(doorway: dict, slope, cotangent, floor_height):
    """Per pixel of a row, for rays through an open door: the distance to what
    they meet behind the wall, whether it is upright (a jamb or a wall), and
    whether it is in the wall's thickness (the door's lining: jambs, lintel, sill)."""
    to_lintel = doorway["lintel"] * cotangent
    to_ceiling = jnp.where(to_lintel < doorway["t_tunnel"], to_lintel, doorway["ceiling"] * cotangent)
    t_flat = jnp.where(slope > 0, to_ceiling, floor_height * cotangent)
    t_flat = jnp.where(t_flat > 0, t_flat, jnp.inf)
    upright = doorway["t_upright"] < t_flat
    t = jnp.where(upright, doorway["t_upright"], t_flat)
    return t, upright, t < doorway["t_tunnel"]
