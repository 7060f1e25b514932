"""Boundary rows snapped to the panorama's own edges (between the network and the geometry).

The metric scale of a non-central layout lives in sub-pixel differences of the
boundary rows (paper Section 3), while the network sees the panorama shrunk to
its input size and places the ceiling-wall and floor-wall boundaries to about
2 pixels of the full image. Where a boundary is a visible edge (two surfaces
of different colour or shading meet), the full-resolution image locates it
better: each column's row moves to the strongest vertical colour change within
``radius`` rows of the network's estimate, to a fraction of a row by a parabola
through the logarithms of the edge strengths around that maximum.

Where the boundary is hidden (furniture in front of the floor-wall line) the
snap lands on the occluder's edge, within ``radius`` rows of the estimate;
RANSAC and the robust steps of the pipeline treat those columns as outliers.

Rows follow docs/design.md: pixel centres at integer rows, so the change between
pixel rows ``r`` and ``r + 1`` sits at row ``r + 0.5``. Columns wrap around.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Shaped


@dataclasses.dataclass(frozen=True)
class EdgeSnap:
    """How boundary rows are snapped to image edges (hashable: a jit static argument).

    Attributes:
        radius: rows searched on each side of the network's row, in pixels of a
            512-row panorama (scaled with the image height).
        sigma: standard deviation of the Gaussian blur applied to the image
            before differencing, in pixels of a 512-row panorama.
        min_strength: the weakest edge (colour distance between adjacent rows
            of the blurred image, colours in [0, 1]) a row moves to; where
            nothing in reach is stronger, the network's row stays.

    The defaults were chosen on 96 validation renders (``ncjax synth --seed 11``,
    valid split; never the test renders) with the shipped network's rows: the
    share of columns within 1 px of the truth went from 50% to 92% (ceiling)
    and from 30% to 58% (floor, often hidden by furniture).
    """

    radius: float = 3.0
    sigma: float = 1.0
    min_strength: float = 0.005

    def __post_init__(self):
        if not self.radius >= 1:
            raise ValueError(f"radius must be at least 1 row, got {self.radius}")
        if not self.sigma >= 0:
            raise ValueError(f"sigma must be >= 0, got {self.sigma}")
        if not self.min_strength >= 0:
            raise ValueError(f"min_strength must be >= 0, got {self.min_strength}")


REFERENCE_HEIGHT = 512


def blur(image: Float[Array, "H W C"], sigma: float) -> Float[Array, "H W C"]:
    """Separable Gaussian blur, columns wrapping around and rows clamped at the poles."""
    if sigma == 0:
        return image
    reach = max(1, math.ceil(3 * sigma))
    offsets = jnp.arange(-reach, reach + 1)
    weights = jnp.exp(-0.5 * (offsets / sigma) ** 2)
    weights = (weights / jnp.sum(weights)).astype(image.dtype)
    height, width = image.shape[:2]
    padded = jnp.pad(image, ((reach, reach), (0, 0), (0, 0)), mode="edge")
    image = sum(w * padded[k : k + height] for k, w in enumerate(weights))
    padded = jnp.pad(image, ((0, 0), (reach, reach), (0, 0)), mode="wrap")
    return sum(w * padded[:, k : k + width] for k, w in enumerate(weights))


def vertical_edge_strength(image: Float[Array, "H W C"]) -> Float[Array, "H-1 W"]:
    """Colour distance between vertically adjacent pixels: row ``r`` of the result sits at ``r + 0.5``."""
    return jnp.linalg.norm(image[1:] - image[:-1], axis=-1)


def snap_row(strength: Float[Array, " R"], row: Float[Array, ""], radius: int, min_strength: float) -> Float[Array, ""]:
    """One column: the sub-row position of the strongest edge within ``radius`` rows of ``row``.

    Args:
        strength: the column of :func:`vertical_edge_strength` (``R = H - 1``).
        row: the network's boundary row (returned as it is when not finite).
        radius: static number of candidate edges on each side.
        min_strength: ``row`` is kept unless the strongest edge exceeds this.
    """
    last = strength.shape[0] - 2
    nearest = jnp.round(jnp.where(jnp.isfinite(row), row, 0.0) - 0.5).astype(jnp.int32)
    candidates = jnp.clip(nearest + jnp.arange(-radius, radius + 1), 1, last)
    peak = candidates[jnp.argmax(strength[candidates])]
    # A blurred step's differences are close to a Gaussian, whose logarithm a parabola fits exactly.
    tiny = jnp.finfo(strength.dtype).tiny
    previous, centre, following = jnp.log(jnp.maximum(strength[peak + jnp.arange(-1, 2)], tiny))
    curvature = previous - 2 * centre + following
    offset = 0.5 * (previous - following) / jnp.where(curvature < 0, curvature, -1.0)
    snapped = peak + 0.5 + jnp.clip(jnp.where(curvature < 0, offset, 0.0), -0.5, 0.5)
    strong = strength[peak] > min_strength
    return jnp.where(jnp.isfinite(row) & strong, snapped.astype(row.dtype), row)


def snap_to_edges(
    image: Shaped[ArrayLike, "H W 3"],
    ceiling_v: Float[ArrayLike, " W"],
    floor_v: Float[ArrayLike, " W"],
    snap: EdgeSnap = EdgeSnap(),
) -> tuple[Float[Array, " W"], Float[Array, " W"]]:
    """The ceiling and floor rows of one panorama moved onto its nearest strong edges.

    Args:
        image: the panorama at full size, RGB (uint8, or float in [0, 1]).
        ceiling_v, floor_v: boundary rows in that image's pixels (docs/design.md).
        snap: static search radius and blur.

    Returns:
        ``(ceiling_v, floor_v)`` snapped, each within ``radius + 1`` rows of its input
        (scaled ``radius``; rows next to the poles may move further).
    """
    image, ceiling_v, floor_v = jnp.asarray(image), jnp.asarray(ceiling_v), jnp.asarray(floor_v)
    height = image.shape[0]
    scale = height / REFERENCE_HEIGHT
    pixels = image.astype(jnp.float32) / (255.0 if jnp.issubdtype(image.dtype, jnp.integer) else 1.0)
    strength = vertical_edge_strength(blur(pixels, snap.sigma * scale))
    radius = max(1, round(snap.radius * scale))
    along_columns = jax.vmap(snap_row, in_axes=(1, 0, None, None))
    return (
        along_columns(strength, ceiling_v, radius, snap.min_strength),
        along_columns(strength, floor_v, radius, snap.min_strength),
    )
