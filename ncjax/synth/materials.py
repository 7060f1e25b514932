"""Procedural materials: colours as pure functions of surface coordinates.

A material is a pattern kind, two colours and a scale (:class:`Material`);
:func:`material_albedo` turns 2D surface coordinates (metres, e.g. along a wall
and up it) into an albedo. Patterns are built from a 32-bit integer hash, so they
are identical on every run and every backend that implements uint32 arithmetic.
Variety matters more than photorealism here: the point is to keep a layout
network from learning the texture of a handful of rooms: :func:`surface_materials`
draws a scene's floor, wall and ceiling materials from pools, as paper Section 5.1 does.
"""

from __future__ import annotations

import enum

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .placement import between, categorical


class Pattern(enum.IntEnum):
    """Pattern kinds of :func:`material_albedo`."""

    PAINT = 0  # flat colour with a faint mottle
    PLASTER = 1  # low-frequency blotches
    PLANKS = 2  # wooden floor boards in staggered rows, with grain
    TILES = 3  # square tiles with grout lines, alternating shades
    CARPET = 4  # fine fibre noise
    STRIPES = 5  # wallpaper stripes
    DIAMONDS = 6  # wallpaper lattice
    WOOD = 7  # furniture wood grain
    FABRIC = 8  # woven fabric
    GRID = 9  # suspended ceiling: square fissured tiles in a grid of thin T-bars
    STIPPLE = 10  # popcorn ceiling: dense bright bumps with dark specks


class Material(eqx.Module):
    """A procedural material (all fields traced; any leading batch shape, e.g. per box).

    Attributes:
        pattern: a :class:`Pattern` value.
        colour_a, colour_b: the two linear RGB colours the pattern mixes, in [0, 1].
        scale: the pattern's period in metres (plank width, tile side, stripe period...).
    """

    pattern: Int[Array, "*batch"]
    colour_a: Float[Array, "*batch 3"]
    colour_b: Float[Array, "*batch 3"]
    scale: Float[Array, "*batch"]


def hash_uniform(
    seed: Int[ArrayLike, "*#batch"], i: Int[ArrayLike, "*#batch"], j: Int[ArrayLike, "*#batch"]
) -> Float[Array, "*batch"]:
    """A uniform number in [0, 1) from three integers: the inputs multiplied by
    odd constants and xor-ed, then one xorshift-multiply avalanche round (cheap:
    the renderer evaluates several per pixel)."""

    def as_uint(x):
        return jnp.asarray(x).astype(jnp.uint32)

    h = (
        as_uint(seed) * jnp.uint32(0x9E3779B1)
        ^ as_uint(i) * jnp.uint32(0x85EBCA6B)
        ^ as_uint(j) * jnp.uint32(0xC2B2AE35)
    )
    h = h ^ (h >> 15)
    h = h * jnp.uint32(0x2C1B3C6D)
    h = h ^ (h >> 12)
    return (h >> 8).astype(jnp.float32) / jnp.float32(1 << 24)


def value_noise(
    seed: Int[ArrayLike, "*#batch"], a: Float[Array, "*#batch"], b: Float[Array, "*#batch"]
) -> Float[Array, "*batch"]:
    """Smooth noise in [0, 1]: hashed values at integer lattice points, interpolated."""
    ia, ib = jnp.floor(a), jnp.floor(b)
    fa, fb = a - ia, b - ib
    fa, fb = fa * fa * (3 - 2 * fa), fb * fb * (3 - 2 * fb)
    ia, ib = ia.astype(jnp.int32), ib.astype(jnp.int32)
    v00, v10 = hash_uniform(seed, ia, ib), hash_uniform(seed, ia + 1, ib)
    v01, v11 = hash_uniform(seed, ia, ib + 1), hash_uniform(seed, ia + 1, ib + 1)
    return (v00 * (1 - fa) + v10 * fa) * (1 - fb) + (v01 * (1 - fa) + v11 * fa) * fb


def _wave(x: Float[Array, "*batch"]) -> Float[Array, "*batch"]:
    """A smooth periodic wave in [0, 1] of period 1 (a cheap stand-in for a sine)."""
    triangle = jnp.abs(2 * (x - jnp.floor(x)) - 1)
    return triangle * triangle * (3 - 2 * triangle)


def _seam(fraction: Float[Array, "*batch"], width: float | Float[Array, "*#batch"]) -> Float[Array, "*batch"]:
    """1 on a thin line at the integer boundaries of a coordinate's fractional part."""
    return ((fraction < width) | (fraction > 1 - width)).astype(fraction.dtype)


def material_albedo(
    material: Material,
    seed: Int[Array, "*#batch"],
    a: Float[Array, "*#batch"],
    b: Float[Array, "*#batch"],
    decor: bool = False,
) -> Float[Array, "*batch 3"]:
    """Albedo of ``material`` at surface coordinates ``(a, b)`` metres.

    Every pattern is evaluated and the material's one is selected: under ``vmap``
    over scenes the kind is a traced value, so the branches would be evaluated
    anyway; they share their noise to stay cheap (this is most of a pixel's cost).

    Args:
        material: the material, one or one per point (fields of shape batch or batch + (3,)).
        seed: integers that decorrelate the patterns of different surfaces.
        a, b: surface coordinates.
        decor: also the patterns only realistic scenes use (``GRID``, ``STIPPLE``);
            static: without them a pixel costs less.

    Returns:
        Linear RGB albedo of the broadcast shape + (3,).
    """
    u, v = a / material.scale, b / material.scale
    fine = hash_uniform(seed, jnp.floor(37.0 * u).astype(jnp.int32), jnp.floor(37.0 * v).astype(jnp.int32))
    coarse = value_noise(seed + 1, 1.7 * u, 1.7 * v)
    # Planks: rows of width `scale` along b, boards of 4-7 widths along a, staggered per row.
    row = jnp.floor(v)
    row_random = hash_uniform(seed + 2, row.astype(jnp.int32), 0)
    along = u / (4.0 + 3.0 * row_random) + 7.13 * row_random
    board = jnp.floor(along)
    board_shade = hash_uniform(seed + 3, row.astype(jnp.int32), board.astype(jnp.int32))
    grain = _wave(6.0 * v + coarse + 1.4 * board_shade)
    seams = jnp.maximum(_seam(v - row, 0.025), _seam(along - board, 0.004))
    planks = (0.55 * board_shade + 0.3 * grain + 0.15 * fine) * (1 - 0.6 * seams)
    # Tiles: unit squares, grout lines, checker of two shades with a small jitter.
    cell_u, cell_v = jnp.floor(u), jnp.floor(v)
    checker = jnp.mod(cell_u + cell_v, 2.0)
    tile_jitter = hash_uniform(seed + 4, cell_u.astype(jnp.int32), cell_v.astype(jnp.int32))
    grout = jnp.maximum(_seam(u - cell_u, 0.03), _seam(v - cell_v, 0.03))
    tiles = (0.8 * checker + 0.1 * tile_jitter + 0.1 * fine) * (1 - grout) + 0.5 * grout
    # Wallpapers.
    stripes = jnp.where(u - cell_u < 0.5, 0.9, 0.1) + 0.1 * fine
    du, dv = jnp.abs(u - cell_u - 0.5), jnp.abs(0.5 * v - jnp.floor(0.5 * v) - 0.5)
    diamonds = jnp.where(du + dv < 0.3, 0.9, 0.15) + 0.1 * fine
    # Furniture.
    wood = 0.15 + 0.7 * _wave(4.0 * u + 1.3 * coarse) + 0.15 * fine
    weave = _wave(48.0 * a) * _wave(48.0 * b)
    patterns = [
        0.08 * fine,
        0.7 * coarse + 0.1 * fine,
        planks,
        tiles,
        0.25 * coarse + 0.75 * fine,
        stripes,
        diamonds,
        wood,
        0.5 * weave + 0.5 * fine,
    ]
    if decor:
        # Ceilings: a 2 cm T-bar (colour b) around each tile, and a popcorn stipple.
        bar = 0.01 / material.scale
        grid = jnp.maximum(_seam(u - cell_u, bar), _seam(v - cell_v, bar)) + 0.12 * fine + 0.08 * coarse
        patterns += [grid, 0.7 * fine * fine + 0.3 * coarse]
    # A chain of selects, not a gather: XLA's CPU gathers are far slower here.
    mix = patterns[0]
    for kind in range(1, len(patterns)):
        mix = jnp.where(material.pattern == kind, patterns[kind], mix)
    mix = jnp.clip(mix, 0.0, 1.0)[..., None]
    return material.colour_a * (1 - mix) + material.colour_b * mix


def hsv_to_rgb(hsv: Float[Array, "... 3"]) -> Float[Array, "... 3"]:
    """HSV in [0, 1]^3 to RGB in [0, 1]^3."""
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    k = jnp.mod(jnp.array([5.0, 3.0, 1.0]) + 6.0 * h[..., None], 6.0)
    return v[..., None] - v[..., None] * s[..., None] * jnp.clip(jnp.minimum(k, 4.0 - k), 0.0, 1.0)


def colour_in_hsv_box(
    uniform: Float[Array, 3],
    hue: tuple[float, float] = (0.0, 1.0),
    saturation: tuple[float, float] = (0.0, 1.0),
    value: tuple[float, float] = (0.0, 1.0),
) -> Float[Array, 3]:
    """The colour at relative position ``uniform`` in [0, 1]^3 of an HSV box (a
    uniform draw gives a uniform colour in the box)."""
    low = jnp.array([hue[0], saturation[0], value[0]])
    high = jnp.array([hue[1], saturation[1], value[1]])
    return hsv_to_rgb(low + uniform * (high - low))


# ---------------------------------------------------------------- surfaces

# fold_in data of the neutral-paint draw: its own stream, so the other draws stay those of earlier scenes.
_NEUTRAL_PAINT_STREAM = 0x9A17

# Range of the pattern period (metres) per Pattern, indexed by its value.
_SCALE_RANGE = np.array(
    [
        [1.0, 1.0],
        [0.6, 2.0],
        [0.12, 0.22],
        [0.3, 0.7],
        [0.6, 1.0],
        [0.1, 0.4],
        [0.15, 0.35],
        [0.3, 0.3],
        [0.3, 0.3],
        [0.59, 0.62],  # suspended-ceiling tiles: 60 cm (2 ft)
        [0.12, 0.25],
    ],
    np.float32,
)


def _surface_material(uniform: Float[Array, 9], pool: list[tuple[float, Pattern]], colour_a, colour_b) -> Material:
    """A material from a weighted pool of patterns, with its period drawn in the pattern's range.

    ``colour_a`` and ``colour_b`` map (pattern, uniforms (3,)) to a colour."""
    pattern = jnp.array([int(p) for _, p in pool], jnp.int32)[categorical(uniform[0], jnp.array([w for w, _ in pool]))]
    low, high = jnp.asarray(_SCALE_RANGE)[pattern]
    a = colour_a(pattern, uniform[2:5])
    return Material(pattern, a, jnp.clip(colour_b(pattern, a, uniform[5:9]), 0.0, 1.0), between(uniform[1], low, high))


def surface_materials(key, config) -> tuple[Material, Material, Material]:
    """Floor, ceiling and wall materials drawn from pools (paper Section 5.1) for a scene of configuration
    ``config`` (a :class:`~ncjax.synth.scene.SceneConfig`)."""
    u = jax.random.uniform(key, (3, 9))
    floor = _surface_material(
        u[0],
        [(0.45, Pattern.PLANKS), (0.25, Pattern.TILES), (0.15, Pattern.CARPET), (0.15, Pattern.PAINT)],
        lambda pattern, w: jnp.where(
            pattern == Pattern.PLANKS,
            colour_in_hsv_box(w, (0.04, 0.11), (0.3, 0.8), (0.2, 0.8)),
            colour_in_hsv_box(w, (0.0, 1.0), (0.0, 0.5), (0.15, 0.9)),
        ),
        lambda pattern, a, w: a * between(w[0], 0.45, 1.4),
    )
    walls = _surface_material(
        u[1],
        [(0.35, Pattern.PAINT), (0.25, Pattern.PLASTER), (0.2, Pattern.STRIPES), (0.2, Pattern.DIAMONDS)],
        lambda pattern, w: colour_in_hsv_box(w, (0.0, 1.0), (0.05, 0.55), (0.45, 0.9)),
        lambda pattern, a, w: jnp.where(
            w[0] < 0.5, a * between(w[1], 0.6, 0.9), colour_in_hsv_box(w[1:4], (0.0, 1.0), (0.0, 0.6), (0.3, 0.95))
        ),
    )
    if config.neutral_paint_probability > 0.0:
        draw = jax.random.uniform(jax.random.fold_in(key, _NEUTRAL_PAINT_STREAM), (10,))
        neutral = _surface_material(
            draw[1:],
            [(0.6, Pattern.PAINT), (0.4, Pattern.PLASTER)],
            lambda pattern, w: colour_in_hsv_box(w, (0.05, 0.15), (0.0, 0.12), (0.75, 0.97)),
            lambda pattern, a, w: a * between(w[0], 0.88, 0.97),
        )
        painted = draw[0] < config.neutral_paint_probability
        walls = jax.tree.map(lambda a, b: jnp.where(painted, a, b), neutral, walls)
    if config.decor:
        plain = 1.0 - config.suspended_ceiling_probability - config.stipple_ceiling_probability
        ceiling_pool = [
            (0.5 * plain, Pattern.PAINT),
            (0.3 * plain, Pattern.PLASTER),
            (0.2 * plain, Pattern.TILES),
            (config.suspended_ceiling_probability, Pattern.GRID),
            (config.stipple_ceiling_probability, Pattern.STIPPLE),
        ]
    else:
        ceiling_pool = [(0.5, Pattern.PAINT), (0.3, Pattern.PLASTER), (0.2, Pattern.TILES)]
    ceiling = _surface_material(
        u[2],
        ceiling_pool,
        lambda pattern, w: colour_in_hsv_box(w, (0.0, 1.0), (0.0, 0.1), (0.8, 0.98)),
        # A suspended ceiling's grid is a grey or white metal T-bar.
        lambda pattern, a, w: (
            jnp.where(pattern == Pattern.GRID, a * between(w[0], 0.55, 1.0), 0.85 * a) if config.decor else 0.85 * a
        ),
    )
    return floor, ceiling, walls
