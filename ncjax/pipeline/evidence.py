"""Steps 1-3 of the pipeline, shared by both worlds: corners, one RANSAC wall per pair, occlusion tests."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from ..geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles, pixel_to_ray
from ..geometry.polygon import previous_in_loop
from ..geometry.reprojection import column_directions
from ..solvers.layout import solve_atlanta_layout
from ..solvers.ransac import WallColumns, boundary_errors, ransac_wall, wall_columns
from ..solvers.settings import scaled
from .adjust import boundary_weights
from .config import PipelineConfig
from .corners import (
    SideWindow,
    column_walls,
    configured_corners,
    distance_to_corners,
    full_window_spread,
    side_extrapolation,
    straight_wall_value,
)
from .types import Rows, WallEvidence
from .walls import boundary_gap


def gather_evidence(
    rows: Rows,
    cam: NonCentralPanorama,
    key: PRNGKeyArray,
    config: PipelineConfig,
    heights: tuple[Float[Array, ""], Float[Array, ""]] | None = None,
) -> WallEvidence:
    """Steps 1-3: corners (``config.corners``), one RANSAC wall between each pair (``config.ransac``), and the
    boundary jump at each corner (``config.occlusion``).

    ``heights``: a height prior's known ``(h_c, h_f)``, which RANSAC's walls then keep (:func:`ransac_wall`).
    """
    width, capacity = cam.width, config.capacity
    ransac, occlusion = config.ransac, config.occlusion
    ceiling_v, floor_v = rows.ceiling, rows.floor
    finite = jnp.isfinite(ceiling_v) & jnp.isfinite(floor_v)
    ceiling_v = jnp.where(finite, ceiling_v, cam.height / 4)
    floor_v = jnp.where(finite, floor_v, 3 * cam.height / 4)
    columns = jnp.arange(width, dtype=ceiling_v.dtype)
    azimuth = column_directions(cam, columns)
    ceiling_rays = pixel_to_ray(cam, columns, ceiling_v)
    floor_rays = pixel_to_ray(cam, columns, floor_v)

    corner_columns, corner_mask, corner_exact, overflow = configured_corners(rows.corner_prob, config)
    column_wall = column_walls(corner_columns, corner_mask, width)
    away = distance_to_corners(corner_columns, corner_mask, width) >= scaled(ransac.corner_margin, width, 1024)
    wall_of = jnp.where(column_wall >= 0, column_wall, capacity)  # segment ids, capacity: none
    seen_away = jax.ops.segment_sum((finite & away).astype(jnp.int32), wall_of, capacity + 1)
    # narrow walls (seen almost edge-on) keep the columns next to their corners
    few = seen_away < 2 * ransac.sample_size
    usable = finite & (column_wall >= 0) & (away | few[wall_of])

    pixels = scaled(1.0, cam.height, 512)
    threshold = ransac.inlier_threshold * pixels
    sampled, sampled_valid = wall_columns(column_wall, usable, corner_columns, ransac.columns)
    columns_of_walls = WallColumns(azimuth[sampled], ceiling_rays[sampled], floor_rays[sampled], sampled_valid)
    walls = jax.vmap(lambda k, c: ransac_wall(k, cam, c, ransac, heights))(
        jax.random.split(key, capacity), columns_of_walls
    )

    previous = previous_in_loop(corner_mask)
    following = (jnp.arange(capacity) + 1) % jnp.maximum(jnp.sum(corner_mask), 1)
    wall = jnp.maximum(column_wall, 0)

    def errors_of(index):
        """Row errors of wall ``index[column]`` at each column (one wall per column, not K x W)."""
        return boundary_errors(cam, jax.tree.map(lambda x: x[index], walls), azimuth, ceiling_v, floor_v)

    ceiling_error, floor_error = errors_of(wall)
    ceiling_in, floor_in = usable & (ceiling_error < threshold), usable & (floor_error < threshold)
    inliers = ceiling_in | floor_in
    counts = jax.ops.segment_sum(ceiling_in.astype(jnp.int32) + floor_in, wall_of, capacity + 1)[:capacity]
    weights = jnp.where(walls.ok & corner_mask, counts, 0)

    def explained_fraction(neighbour):
        """Per wall, the fraction of its inlier columns whose rows wall ``neighbour[wall]`` explains too."""
        neighbour_ceiling, neighbour_floor = errors_of(neighbour[wall])
        explained = inliers & (neighbour_ceiling < threshold) & (neighbour_floor < threshold)
        total = jax.ops.segment_sum(jnp.stack([explained, inliers], -1).astype(jnp.int32), wall_of, capacity + 1)
        return total[:capacity, 0] / jnp.maximum(total[:capacity, 1], 1)

    fitted = walls.ok & corner_mask
    on_fitted = fitted[wall]
    ceiling_trusted = ceiling_in | (usable & ~on_fitted)
    floor_trusted = floor_in | (usable & ~on_fitted)
    row_weights = boundary_weights(
        ceiling_error, floor_error, ceiling_in & on_fitted, floor_in & on_fitted, config.adjustment.min_noise(cam)
    )
    # one wall's rows fix its own metric scale poorly: the heights come from all the fitted walls at once
    heights = solve_atlanta_layout(
        ceiling_rays,
        floor_rays,
        jnp.where(ceiling_trusted & floor_trusted, column_wall, -1),
        fitted,
        walls.direction,
        boundary_weights=row_weights,
    )

    # the boundary jump at each corner, from the walls' boundaries on either side extrapolated to it
    margin = scaled(ransac.corner_margin, width, 1024)
    window = max(3, round(scaled(8.0, width, 1024)))
    column_angle = cam.fov_horizontal / width

    def height_over_range(rows, height):
        """Per column, a boundary's ``h / R`` at height ``h``.

        A pixel's ray leaves the circle at ``rc`` and rises at elevation ``phi``: it
        meets height ``h`` at radial distance ``R = rc + h / tan(phi)``, so
        ``h / R = tan(phi) / (1 + (rc / h) tan(phi))``, which
        :func:`~ncjax.pipeline.corners.side_extrapolation` extrapolates.
        """
        tan_elevation = jnp.tan(pixel_to_angles(cam, columns, rows)[1])
        return tan_elevation / (1 + rc_over(height) * tan_elevation)

    def rc_over(height):
        return jnp.where(heights.ok & (height != 0), cam.rc / height, 0.0)

    def rows_of(value, height):
        """The rows of ``h / R`` values at height ``h`` (the inverse of :func:`height_over_range`)."""
        tan_elevation = value / jnp.maximum(1 - rc_over(height) * value, jnp.finfo(value.dtype).tiny)
        return angles_to_pixel(cam, 0.0, jnp.arctan(tan_elevation))[1]

    def extrapolate(value, wall, side):
        """``h / R`` of the walls ``wall`` at their corners ``corner_columns`` from the given side, and its spread."""
        own = finite[None, :] & (column_wall[None, :] == wall[:, None])
        side_window = SideWindow(window, margin, column_angle)
        return jax.vmap(lambda usable, corner: side_extrapolation(value, usable, corner, side, side_window))(
            own, corner_columns
        )

    ceiling_value = height_over_range(ceiling_v, heights.ceiling_height)
    floor_value = height_over_range(floor_v, heights.floor_height)
    ceiling_value_here, seen_here, spread_here = extrapolate(ceiling_value, jnp.arange(capacity), 1)
    floor_value_here, _, _ = extrapolate(floor_value, jnp.arange(capacity), 1)
    ceiling_value_before, seen_before, spread_before = extrapolate(ceiling_value, previous, -1)
    floor_value_before, _, _ = extrapolate(floor_value, previous, -1)
    ceiling_here, floor_here = (
        rows_of(ceiling_value_here, heights.ceiling_height),
        rows_of(floor_value_here, heights.floor_height),
    )
    ceiling_before = rows_of(ceiling_value_before, heights.ceiling_height)
    floor_before = rows_of(floor_value_before, heights.floor_height)
    jump = jnp.maximum(jnp.abs(ceiling_here - ceiling_before), jnp.abs(floor_here - floor_before))
    both_fitted = fitted & fitted[previous]

    def ransac_wall_at(index):
        return walls.direction[index], walls.distance[index], walls.ceiling_height[index], walls.floor_height[index]

    # two fitted walls that meet at the corner reproject to one point there, which
    # the extrapolations of their few noisy rows near the corner may miss
    wall_jump, both_seen = boundary_gap(
        cam, ransac_wall_at(jnp.arange(capacity)), ransac_wall_at(previous), corner_columns
    )
    jump = jnp.where(both_fitted & both_seen, jnp.minimum(jump, wall_jump), jump)
    # each of walls j - 1 and j explains most inliers of the other
    same_plane = (explained_fraction(previous) >= occlusion.merge_fraction) & (
        explained_fraction(following)[previous] >= occlusion.merge_fraction
    )
    # noisy rows make the jump noisy too: it must also stand out of the noise, whose scale is
    # robustly 1.4826 x the median row error of the usable columns about their RANSAC walls,
    # as much more as the two extrapolations spread more than those of two full windows
    residuals = jnp.concatenate([ceiling_error, floor_error])
    residuals = jnp.where(jnp.tile(usable, 2) & jnp.isfinite(residuals), residuals, jnp.nan)
    noise = 1.4826 * jnp.nanmedian(residuals)
    noise = jnp.where(jnp.isfinite(noise), noise, 0.0)
    full_window = full_window_spread(window, margin)

    def relative_spread(first, second):
        """How much less surely two extrapolations give a jump than two full windows (at least 1)."""
        return jnp.maximum(jnp.hypot(first, second) / (math.sqrt(2) * full_window), 1.0)

    jump_seen = corner_mask & seen_here & seen_before
    jump_stands_out = jump_seen & (jump > occlusion.noise_factor * noise * relative_spread(spread_here, spread_before))
    occluded = jump_stands_out & (jump > occlusion.threshold * pixels)
    previous_nearer = (floor_before - ceiling_before) > (floor_here - ceiling_here)

    # A wall too narrow to extrapolate (its corners closer than the window) between two that extrapolate: along a
    # straight wall from the previous wall's boundary at its first corner to the next wall's at its second
    # (``h / R`` is ``a cos + b sin`` of the azimuth), its own rows lie on it unless an occlusion hides a wall at
    # one of its corners: the one where the nearer of the two neighbours ends.
    narrow = corner_mask & ~seen_here & seen_before & seen_here[following]
    span = column_angle * ((corner_columns[following] - corner_columns) % width)
    offset = column_angle * ((columns - corner_columns[wall]) % width)

    def chord_deviation(rows, value_before, value_here, height):
        chord = straight_wall_value(value_before[wall], value_here[following][wall], span[wall], offset)
        return jnp.abs(rows_of(chord, height) - rows)

    deviation = jnp.maximum(
        chord_deviation(ceiling_v, ceiling_value_before, ceiling_value_here, heights.ceiling_height),
        chord_deviation(floor_v, floor_value_before, floor_value_here, heights.floor_height),
    )
    on_narrow = finite & (column_wall >= 0) & narrow[wall] & jnp.isfinite(deviation)
    deviation = jax.ops.segment_max(jnp.where(on_narrow, deviation, 0.0), wall_of, capacity + 1)[:capacity]
    hidden = narrow & (
        deviation
        > jnp.maximum(
            occlusion.threshold * pixels,
            occlusion.noise_factor * noise * relative_spread(spread_before, spread_here[following]),
        )
    )
    span_before = floor_before - ceiling_before
    before_nearer = span_before > (floor_here - ceiling_here)[following]
    at_start = hidden & before_nearer
    at_end = (
        jnp.zeros(capacity, bool).at[jnp.where(hidden & ~before_nearer, following, capacity)].set(True, mode="drop")
    )
    occluded = occluded | at_start | at_end
    previous_nearer = jnp.where(at_start, True, jnp.where(at_end, False, previous_nearer))
    # where the fitted walls part at the corner, an occlusion the jump missed may hide a wall there
    walls_part = both_fitted & both_seen & (wall_jump > occlusion.noise_factor * noise)
    return WallEvidence(
        cam=cam,
        rows=rows,
        ceiling_rays=ceiling_rays,
        floor_rays=floor_rays,
        finite=finite,
        corner_columns=corner_columns,
        corner_mask=corner_mask,
        corner_exact=corner_exact,
        corner_overflow=overflow,
        column_wall=column_wall,
        walls=walls,
        usable=usable,
        ceiling_trusted=ceiling_trusted,
        floor_trusted=floor_trusted,
        floor_measured=jnp.ones_like(usable),
        input_floor=rows.floor,
        weights=weights.astype(ceiling_v.dtype),
        row_weights=row_weights,
        fitted=fitted,
        both_fitted=both_fitted,
        same_plane=both_fitted & same_plane,
        occluded=occluded,
        walls_part=walls_part,
        jump_seen=jump_seen,
        jump_stands_out=jump_stands_out,
        previous_nearer=previous_nearer,
        heights=heights,
        row_noise=noise,
    )


def previous_of(evidence: WallEvidence) -> Int[Array, " K"]:
    return previous_in_loop(evidence.corner_mask)
