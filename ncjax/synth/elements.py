"""The fixed-capacity containers a :class:`~ncjax.synth.scene.Scene` is made of.

Each is an ``equinox.Module`` of traced arrays with a leading slot axis and a
``mask`` saying which slots hold something, so that scenes of different
contents share one compiled program.
"""

from __future__ import annotations

import enum

import equinox as eqx
from jaxtyping import Array, Bool, Float, Int

from .materials import Material

FRAME_WIDTH = 0.06  # width of door and window frames, metres


class Boxes(eqx.Module):
    """Boxes that rotate about z (all fields traced, leading axis B).

    Attributes:
        centre: (B, 3) camera frame, metres.
        half_size: (B, 3) half extents along the box's own axes.
        rotation: (B, 2) ``(cos, sin)`` of the yaw: the box's x axis in the camera frame.
        material: a :class:`~ncjax.synth.materials.Material` with leading axis B.
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


class Doorways(eqx.Module):
    """Which doors stand open, and the rooms seen through them (leading axis D,
    the slots of :class:`Openings`).

    An open door is an aperture: rays through it go on into a box-shaped room
    behind the wall (a wall ``wall_thickness`` thick, then a room
    ``room_depth`` deep that reaches ``room_sides`` beyond the door on either
    side, with its ceiling at ``room_ceiling``), lit ``room_light`` times the
    ambient light.

    Attributes:
        is_open: (D,) an open door (never a window).
        is_passage: (D,) a wide passage (open, with no leaf; see
            :attr:`~ncjax.synth.SceneConfig.passage_probability`).
        wall_thickness, room_depth, room_ceiling, room_light: (D,) the room behind an open door.
        room_sides: (D, 2) how far the room behind reaches beyond the door's start and end.
    """

    is_open: Bool[Array, " D"]
    is_passage: Bool[Array, " D"]
    wall_thickness: Float[Array, " D"]
    room_depth: Float[Array, " D"]
    room_sides: Float[Array, "D 2"]
    room_ceiling: Float[Array, " D"]
    room_light: Float[Array, " D"]


class Lights(eqx.Module):
    """Point lights (leading axis L): position (L, 3), radiant colour (L, 3), mask (L,)."""

    position: Float[Array, "L 3"]
    colour: Float[Array, "L 3"]
    mask: Bool[Array, " L"]


class DecalKind(enum.IntEnum):
    """What a :class:`Decals` slot shows."""

    POSTER = 0  # blocks of two colours, a thin white margin
    PICTURE = 1  # a framed, matted landscape-like gradient
    WHITEBOARD = 2  # white with faint smudges and a thin aluminium frame


class Decals(eqx.Module):
    """Posters, pictures and whiteboards: flat rectangles on walls (leading axis E),
    drawn like doors and windows, so they never touch the layout's edges.

    Attributes:
        wall: (E,) index of the wall they are on.
        span: (E, 2) start and end along the wall from its first corner, metres.
        z_range: (E, 2) bottom and top, camera frame.
        kind: (E,) a :class:`DecalKind`.
        colour_a, colour_b: (E, 3) the two colours of the picture.
        frame_colour: (E, 3); frame_width: (E,) metres.
        mask: (E,) which slots hold a decal.
    """

    wall: Int[Array, " E"]
    span: Float[Array, "E 2"]
    z_range: Float[Array, "E 2"]
    kind: Int[Array, " E"]
    colour_a: Float[Array, "E 3"]
    colour_b: Float[Array, "E 3"]
    frame_colour: Float[Array, "E 3"]
    frame_width: Float[Array, " E"]
    mask: Bool[Array, " E"]


class Panels(eqx.Module):
    """Emissive light panels flush in the ceiling: rotated rectangles (leading axis P).

    Attributes:
        centre: (P, 2) camera frame; half_size: (P, 2); rotation: (P, 2) ``(cos, sin)``.
        emission: (P, 3) emitted radiance (bright enough to saturate).
        mask: (P,) which slots hold a panel.
    """

    centre: Float[Array, "P 2"]
    half_size: Float[Array, "P 2"]
    rotation: Float[Array, "P 2"]
    emission: Float[Array, "P 3"]
    mask: Bool[Array, " P"]


class SunPatches(eqx.Module):
    """Sunlight through windows (leading axis S): a point is lit when the line
    back towards the sun crosses the window's rectangle, which makes bright
    parallelograms on the floor, walls and furniture.

    Attributes:
        origin: (S, 2) first corner of the window's wall; axis: (S, 2) the wall's
            unit direction; normal: (S, 2) its inward normal.
        span: (S, 2) the window along the wall from ``origin``; z_range: (S, 2) bottom and top.
        direction: (S, 3) unit direction the sunlight travels (into the room, down).
        colour: (S, 3) irradiance added where lit.
        mask: (S,) which slots hold a patch.
    """

    origin: Float[Array, "S 2"]
    axis: Float[Array, "S 2"]
    normal: Float[Array, "S 2"]
    span: Float[Array, "S 2"]
    z_range: Float[Array, "S 2"]
    direction: Float[Array, "S 3"]
    colour: Float[Array, "S 3"]
    mask: Bool[Array, " S"]


class Decor(eqx.Module):
    """What a realistic scene (``SceneConfig(decor=True)``) adds over a furnished
    room's walls, floor and ceiling; its extra boxes (ceiling fittings, door
    leaves) are in the scene's :class:`Boxes`.

    Attributes:
        doorways: the open doors and the rooms behind them, :class:`Doorways`.
        decals: posters, pictures and whiteboards, :class:`Decals`.
        panels: light panels flush in the ceiling, :class:`Panels`.
        sun: sunlight through windows, :class:`SunPatches`.
        next_floor, next_walls: materials of the rooms seen through open doors.
        plan_axis: (2,) unit direction the floor and ceiling patterns follow (the longest wall).
    """

    doorways: Doorways
    decals: Decals
    panels: Panels
    sun: SunPatches
    next_floor: Material
    next_walls: Material
    plan_axis: Float[Array, 2]
