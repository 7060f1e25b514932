"""Corner extraction from the network's corner probability (paper Section 4.4, first step).

The corner target is HorizonNet's ``0.96**d`` (docs/design.md section 5), ``d`` the
distance in columns to the nearest wall-wall corner. Its logarithm is a tent
``d log 0.96`` around each corner, so three samples around a peak locate the
corner to a fraction of a column exactly (:func:`refine_peak`).

Columns wrap around: column ``W - 1`` neighbours column 0. Everything has
fixed capacity ``C`` (corner slots) with a mask (docs/design.md section 4).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from .config import CornerConfig, PipelineConfig

# The labels' corner target is CORNER_LABEL_BASE**d, d the distance in columns to the nearest corner.
CORNER_LABEL_BASE = 0.96


def is_peak(corner_prob: Float[Array, " W"], radius: int, threshold: Float[ArrayLike, ""]) -> Bool[Array, " W"]:
    """Local maxima over a wrap-around window of ``2 radius + 1`` columns (non-maximum suppression).

    A plateau yields its leftmost column only: a peak is strictly greater than
    the ``radius`` columns on its left and not smaller than those on its right.

    Args:
        corner_prob: per-column corner probability.
        radius: static half-width of the suppression window, in columns.
        threshold: minimum probability of a peak.
    """
    prob = jnp.where(jnp.isfinite(corner_prob), corner_prob, -jnp.inf)
    peak = prob >= threshold
    for offset in range(1, radius + 1):
        peak &= prob > jnp.roll(prob, offset)  # the column `offset` to the left
        peak &= prob >= jnp.roll(prob, -offset)
    return peak


def refine_peak(corner_prob: Float[Array, " W"], column: Int[Array, ""]) -> Float[Array, ""]:
    """Sub-column position of a peak from the tent shape of ``log(0.96**d)``.

    With ``l(x) = a - s |x - x0|`` sampled at the peak column and its two
    neighbours, ``x0 = (l(+1) - l(-1)) / (2 (l(0) - min(l(-1), l(+1))))``,
    exact for the target encoding and clipped to half a column for real
    predictions.
    """
    width = corner_prob.shape[0]
    tiny = jnp.finfo(corner_prob.dtype).tiny
    logs = jnp.log(jnp.maximum(corner_prob[(column + jnp.arange(-1, 2)) % width], tiny))
    slope = logs[1] - jnp.minimum(logs[0], logs[2])
    offset = 0.5 * (logs[2] - logs[0]) / jnp.where(slope > 0, slope, 1.0)
    return column + jnp.clip(jnp.where(slope > 0, offset, 0.0), -0.5, 0.5)


def exact_target_corners(
    corner_prob: Float[Array, " W"], column: Int[Array, ""], radius: int, tolerance: Float[ArrayLike, ""]
) -> tuple[Float[Array, ""], Float[Array, ""], Bool[Array, ""]]:
    """The two corners of a peak of the exact label target that holds two (HorizonNet merges them).

    The exact target ``0.96**d`` gives each column its distance ``d = log p / log 0.96``
    (columns) to the nearest corner. Where two neighbouring columns' distances
    differ by one column, both see the same corner on the same side, and the
    farther one's distance places it. Within ``radius + 0.5`` columns of the
    peak, the leftmost and the rightmost corners so placed are the peak's
    corners: two where they are more than ``2 tolerance`` apart and every
    column between them (and one beyond) has the distance those two give,
    however close they are. A network's lobes never follow the encoding this
    exactly, so its peaks are never split.

    Args:
        corner_prob: per-column corner probability.
        column: the peak's column.
        radius: static non-maximum-suppression half-width (columns).
        tolerance: how exactly (columns of distance) the target must follow ``0.96**d``; 0: never split.

    Returns:
        ``(first, second, exact)``: the leftmost and rightmost corners' sub-column
        positions (possibly outside ``[0, W)``; equal for one corner) and whether
        the peak follows the encoding: then it holds those corners and no other.
    """
    width = corner_prob.shape[0]
    reach = radius + 1
    offsets = jnp.arange(-reach - 1, reach + 2)
    tiny = jnp.finfo(corner_prob.dtype).tiny
    distance = jnp.log(jnp.maximum(corner_prob[(column + offsets) % width], tiny)) / jnp.log(CORNER_LABEL_BASE)
    positions = (column + offsets).astype(corner_prob.dtype)
    left, right = distance[:-1], distance[1:]
    # a corner right of both columns (distances falling by one), or left of both (rising by one)
    falling, rising = jnp.abs(left - right - 1) <= tolerance, jnp.abs(right - left - 1) <= tolerance
    placed = jnp.concatenate([positions[:-1] + left, positions[1:] - right])
    # a corner farther than ``radius + 0.5`` from the peak's column is another peak's
    found = jnp.concatenate([falling, rising]) & (jnp.abs(placed - column) < radius + 0.5)
    first = jnp.min(jnp.where(found, placed, jnp.inf))
    second = jnp.max(jnp.where(found, placed, -jnp.inf))
    between = (positions >= first - 1) & (positions <= second + 1)
    expected = jnp.minimum(jnp.abs(positions - first), jnp.abs(positions - second))
    follows = jnp.all(~between | (jnp.abs(distance - expected) <= tolerance))
    return first, second, (tolerance > 0) & jnp.any(found) & follows


def find_corners(
    corner_prob: Float[Array, " W"],
    capacity: int,
    radius: int,
    config: CornerConfig,
) -> tuple[Float[Array, " C"], Bool[Array, " C"], Bool[Array, " C"], Bool[Array, ""]]:
    """Corner columns: the ``capacity`` strongest peaks, refined, sorted left to right.

    A room has at least ``config.min_corners`` corners. When fewer peaks reach
    ``config.threshold`` (a network unsure of a panorama unlike its training images
    gives flat lobes), the threshold drops to the ``min_corners``-th strongest
    peak, but not below ``fallback_threshold``; otherwise nothing changes.
    A peak of the exact label target that holds two corners closer than the
    suppression window gives both, more than ``2 exact_tolerance`` apart
    (:func:`exact_target_corners`).

    Args:
        corner_prob: per-column corner probability.
        capacity: static number of corner slots ``C``.
        radius: static non-maximum-suppression half-width (columns).
        config: the threshold, the fallback for ``min_corners`` (static; 0 keeps ``threshold`` whatever the
            count) and :func:`exact_target_corners`' tolerance (0: peaks are never split); its ``nms_radius``
            is the caller's, as ``radius``.

    Returns:
        ``(columns, mask, exact, overflow)``: sub-column positions in ``[-0.5, W - 0.5)``
        (masked slots hold ``W``, after every real column), which slots are
        corners, which corners' peaks follow the exact target (no corner hides
        in them), and whether more corners than ``capacity`` were found.
    """
    width = corner_prob.shape[0]
    threshold, min_corners, exact_tolerance = config.threshold, config.min_corners, config.exact_target_tolerance
    fallback_threshold = config.fallback_threshold
    candidate = is_peak(corner_prob, radius, jnp.minimum(threshold, fallback_threshold) if min_corners else threshold)
    strength = jnp.where(candidate, corner_prob, -jnp.inf)
    values, strongest = jax.lax.top_k(strength, capacity)
    if min_corners:
        threshold = jnp.minimum(threshold, values[min(min_corners, capacity) - 1])
    peak = candidate & (corner_prob >= threshold)
    mask = peak[strongest]
    refined = jax.vmap(refine_peak, in_axes=(None, 0))(corner_prob, strongest)
    first, second, exact = jax.vmap(exact_target_corners, in_axes=(None, 0, None, None))(
        corner_prob, strongest, radius, exact_tolerance
    )
    two = mask & exact & (second - first > 2 * exact_tolerance)
    found = jnp.concatenate([jnp.where(two, first, refined), second])
    found = jnp.where(found < -0.5, found + width, found)
    found = jnp.where(found >= width - 0.5, found - width, found)
    order = jnp.argsort(jnp.where(jnp.concatenate([mask, two]), found, float(width)))[:capacity]
    count = jnp.sum(peak) + jnp.sum(two)
    valid = jnp.arange(capacity) < count
    columns = jnp.where(valid, found[order], float(width))
    return columns, valid, valid & jnp.tile(exact, 2)[order], count > capacity


def configured_corners(
    corner_prob: Float[Array, " W"], config: PipelineConfig
) -> tuple[Float[Array, " C"], Bool[Array, " C"], Bool[Array, " C"], Bool[Array, ""]]:
    """The corners the pipeline takes: :func:`find_corners` with ``config.corners`` (``C`` =
    ``config.capacity``), non-finite probabilities read as 0."""
    corner_prob = jnp.where(jnp.isfinite(corner_prob), corner_prob, 0.0)
    return find_corners(corner_prob, config.capacity, config.corners.radius(corner_prob.shape[0]), config.corners)


def column_walls(corner_columns: Float[Array, " C"], corner_mask: Bool[Array, " C"], width: int) -> Int[Array, " W"]:
    """The wall each column belongs to: wall ``j`` runs from corner ``j`` to corner ``j + 1``.

    Corners are sorted left to right; the columns left of the first corner
    belong to the last wall (the image wraps around). -1 when there is no corner.
    """
    columns = jnp.arange(width, dtype=corner_columns.dtype)
    count = jnp.sum(corner_mask)
    passed = jnp.sum(corner_mask[None, :] & (corner_columns[None, :] <= columns[:, None]), axis=1)
    wall = jnp.where(passed == 0, count, passed) - 1
    return jnp.where(count > 0, wall, -1).astype(jnp.int32)


def distance_to_corners(
    corner_columns: Float[Array, " C"], corner_mask: Bool[Array, " C"], width: int
) -> Float[Array, " W"]:
    """Wrap-around distance in columns from each column to the nearest corner (inf if none)."""
    columns = jnp.arange(width, dtype=corner_columns.dtype)
    gap = jnp.abs(columns[:, None] - corner_columns[None, :]) % width
    gap = jnp.minimum(gap, width - gap)
    return jnp.min(jnp.where(corner_mask[None, :], gap, jnp.inf), axis=1)


class SideWindow(NamedTuple):
    """The columns :func:`side_extrapolation` fits beside a corner.

    Attributes:
        columns: static number of columns fitted.
        margin: columns skipped next to the corner.
        column_angle: azimuth step between columns (radians).
    """

    columns: int
    margin: Float[ArrayLike, ""]
    column_angle: Float[ArrayLike, ""]


def side_extrapolation(
    height_over_range: Float[Array, " W"],
    usable: Bool[Array, " W"],
    corner: Float[Array, ""],
    side: int,
    window: SideWindow,
) -> tuple[Float[Array, ""], Bool[Array, ""], Float[Array, ""]]:
    """A boundary's ``h / R`` at a corner column, extrapolated from the wall on one side of it.

    A boundary at height ``h`` on a wall at plan distance ``d`` from the camera's
    axis (normal at azimuth ``theta_n``) meets the half-plane of azimuth ``theta``
    at radial distance ``R = d / cos(theta - theta_n)``: ``h / R`` is
    ``a cos(delta) + b sin(delta)`` at ``delta`` radians from the corner, so
    ``(h / R) / cos(delta)`` is a line in ``tan(delta)`` whose value at the corner
    is ``a``. Unlike a line through the rows, it follows the curve of a near
    wall's boundary.

    Args:
        height_over_range: per column, the boundary's ``h / R``.
        usable: columns that may be used (finite, on the right wall).
        corner: the corner's (sub-)column.
        side: static, -1 for the columns left of the corner, +1 for the right.
        window: the columns fitted.

    Returns:
        ``(h / R, ok, spread)`` at the corner: ``ok`` is False with fewer than 3 usable
        columns; ``spread`` is the extrapolation's standard deviation for rows of unit
        noise, ``sqrt(1 / n + mean(x)**2 / sum((x - mean(x))**2))`` (a narrow wall's few
        columns near the corner extrapolate far less surely than a full window).
    """
    width = height_over_range.shape[0]
    window_columns, margin, column_angle = window
    offsets = side * window_offsets(window_columns, margin).astype(height_over_range.dtype)
    columns = jnp.round(corner) + offsets
    index = (columns.astype(jnp.int32)) % width
    weight = usable[index].astype(height_over_range.dtype)
    delta = column_angle * (columns - corner)
    x, y = jnp.tan(delta), height_over_range[index] / jnp.cos(delta)
    count = jnp.sum(weight)
    mean_x = jnp.sum(weight * x) / jnp.maximum(count, 1)
    mean_y = jnp.sum(weight * y) / jnp.maximum(count, 1)
    spread = jnp.sum(weight * (x - mean_x) ** 2)
    slope = jnp.sum(weight * (x - mean_x) * (y - mean_y)) / jnp.where(spread > 0, spread, 1.0)
    return mean_y - slope * mean_x, count >= 3, _intercept_spread(count, mean_x, spread)


def straight_wall_value(
    start: Float[ArrayLike, "*#n"],
    end: Float[ArrayLike, "*#n"],
    span: Float[ArrayLike, "*#n"],
    offset: Float[ArrayLike, "*#n"],
) -> Float[Array, "*n"]:
    """A boundary's ``h / R`` ``offset`` radians along a straight wall on which it is ``start`` at offset 0 and
    ``end`` at ``span`` (``a cos + b sin`` of the offset, :func:`side_extrapolation`)."""
    sin_span = jnp.sin(span)
    slope = (end - start * jnp.cos(span)) / jnp.where(sin_span != 0, sin_span, 1.0)
    return start * jnp.cos(offset) + slope * jnp.sin(offset)


def window_offsets(window: int, margin: Float[ArrayLike, ""]) -> Float[Array, " window"]:
    """Distances (columns) from a corner of the columns :func:`side_extrapolation` fits on one side."""
    return jnp.ceil(margin) + 1 + jnp.arange(window)


def _intercept_spread(count, mean_x, spread) -> Float[Array, ""]:
    """A fitted line's value at ``x = 0`` has ``sqrt(1 / n + mean(x)**2 / sum((x - mean(x))**2))`` times
    the noise of its points as standard deviation (inf when the line is not fixed)."""
    fixed = (count >= 3) & (spread > 0)
    uncertainty = jnp.sqrt(1 / jnp.maximum(count, 1) + mean_x**2 / jnp.where(fixed, spread, 1.0))
    return jnp.where(fixed, uncertainty, jnp.inf)


def full_window_spread(window: int, margin: Float[ArrayLike, ""]) -> Float[Array, ""]:
    """:func:`side_extrapolation`'s ``spread`` with every column of its window usable (small angles)."""
    offsets = window_offsets(window, margin)
    return _intercept_spread(window, jnp.mean(offsets), jnp.sum((offsets - jnp.mean(offsets)) ** 2))
