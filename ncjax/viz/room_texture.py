"""The panorama textured onto the recovered room: each wall, the floor and the ceiling get the part of the
panorama that sees them, resampled through the camera model.

Every surface has a rectangle (a chart) of one square texture: a wall its length by the room height, the
floor and the ceiling their plan's bounding box. A texel is the surface point at its centre; its colour is
the panorama's at :func:`~ncjax.geometry.camera.project` of that point, bilinear, so a non-central panorama's
texture is placed by its own rays. A point that no ray of the panorama sees gets :data:`UNSEEN_COLOUR`
instead of a colour smeared from elsewhere: a point inside the circle of optical centres, a point whose ray
from its optical centre crosses another wall of the layout first (hidden by an occlusion), every
point of a wall inserted for an occlusion (the panorama shows what stands in front of it), and a point whose
pixel the photograph does not hold (a photo sphere's padding).
"""

from __future__ import annotations

import math

import cv2
import jax
import numpy as np
from jaxtyping import Bool, Float, UInt8

from ..geometry.camera import NonCentralPanorama, project
from ..io.export import signed_area, valid_corners, wall_lengths
from ..io.mesh import SurfaceMesh, TexturedRoom, triangulate_polygon
from ..pipeline.types import Layout

MIN_TEXTURE_SIZE = 64
UNSEEN_COLOUR = (255, 0, 255)
# texels of a chart's border repeated around it, so that filtering and mipmaps do not mix in a neighbour
PADDING = 4
# a crossing this many texels before a point does not hide it: the texels at a surface's edges stay seen
HIDING_TEXELS = 2.0


def textured_room(
    layout: Layout,
    image: UInt8[np.ndarray, "H W 3"],
    cam: NonCentralPanorama,
    texture_size: int | None = None,
    photographed: Bool[np.ndarray, "H W"] | None = None,
) -> TexturedRoom:
    """The room of ``layout`` with ``image`` resampled onto its walls, floor and ceiling.

    Args:
        layout: one unbatched layout with its geometry (:func:`~ncjax.io.export.has_geometry`).
        image: the panorama the layout was found on, RGB.
        cam: its camera.
        texture_size: the side N of the square texture, in texels; the charts are scaled together to fill it.
            None: the panorama's width (at least :data:`MIN_TEXTURE_SIZE`). The texture then has twice the
            panorama's pixels, as many as carry its detail onto the near floor and walls, and stays small.
        photographed: where ``image`` holds the photograph (None: everywhere); a texel whose pixels fall outside
            it is unseen (a photo sphere padded to the full sphere, :mod:`ncjax.io.photo_sphere`).

    Returns:
        The surfaces (walls in image order, floor, ceiling; normals out of the room as in
        :func:`~ncjax.io.mesh.room_mesh`), the texture and its texels no ray sees.

    Raises:
        ValueError: for a texture size below :data:`MIN_TEXTURE_SIZE` texels.
    """
    if texture_size is None:
        texture_size = max(MIN_TEXTURE_SIZE, image.shape[1])
    if texture_size < MIN_TEXTURE_SIZE:
        raise ValueError(f"the texture needs at least {MIN_TEXTURE_SIZE} texels a side, got {texture_size}")
    ceiling, floor = valid_corners(layout)
    plan = floor[:, :2]
    n = len(plan)
    top, bottom = float(ceiling[0, 2]), float(floor[0, 2])
    inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
    lengths = wall_lengths(plan)
    # the floor's and the ceiling's charts are aligned with the longest wall: little of them lies outside the room
    longest = int(np.argmax(lengths))
    axes = _plan_axes(plan[longest], plan[(longest + 1) % n])
    local = plan @ axes.T
    low, high = local.min(axis=0), local.max(axis=0)
    extents = [(length, top - bottom) for length in lengths] + [tuple(high - low)] * 2
    scale, corners = _pack(extents, texture_size)
    shapes = [_chart_shape(extent, scale) for extent in extents]
    charts = [_wall_points(plan[k], plan[(k + 1) % n], top, bottom, shapes[k]) for k in range(n)]
    charts += [_plan_points(axes, low, high, bottom, shapes[n]), _plan_points(axes, low, high, top, shapes[n + 1])]
    texture = np.zeros((texture_size, texture_size, 3), np.uint8)
    unseen = np.zeros((texture_size, texture_size), bool)
    # the plan decides what a wall hides (_hidden): a wall's texels of one column share their plan point, and the
    # floor's and the ceiling's texels the same plan points
    plan_hidden = _hidden(charts[n], cam, plan, None, scale)
    for index, (points, pixels) in enumerate(zip(charts, _project_charts(cam, charts, texture_size), strict=True)):
        if index >= n:
            hidden = plan_hidden
        elif inserted[index]:
            hidden = np.ones(points.shape[:2], bool)
        else:
            hidden = np.broadcast_to(_hidden(points[:1], cam, plan, index, scale), points.shape[:2])
        _paint(texture, unseen, corners[index], *_colours(image, *pixels, hidden, photographed))
    surfaces = []
    for k in range(n):
        rows, columns = shapes[k]
        uv = _uv(corners[k], np.array([0.0, 0, rows, rows]), np.array([0.0, columns, 0, columns]), texture_size)
        surfaces.append(_wall_surface(k, plan, top, bottom, uv))
    triangles = triangulate_polygon(plan)
    along = (local - low) / (high - low)
    for chart, (name, height, faces) in enumerate(
        (("floor", bottom, triangles[:, ::-1]), ("ceiling", top, triangles)), start=n
    ):
        rows, columns = shapes[chart]
        uv = _uv(corners[chart], (1.0 - along[:, 1]) * rows, along[:, 0] * columns, texture_size)
        vertices = np.concatenate([plan, np.full((n, 1), height)], axis=1)
        surfaces.append(SurfaceMesh(name, vertices, faces, uv))
    return TexturedRoom(tuple(surfaces), texture, unseen)


def _plan_axes(start, end) -> Float[np.ndarray, "2 2"]:
    """Rows: the unit direction from ``start`` to ``end`` and its left normal, the axes of the plan's charts."""
    direction = (end - start) / np.linalg.norm(end - start)
    return np.array([direction, [-direction[1], direction[0]]])


def _chart_shape(extent: tuple[float, float], scale: float) -> tuple[int, int]:
    """Rows and columns of texels of a chart ``extent`` = (width, height) metres at ``scale`` texels per metre."""
    width, height = extent
    return max(1, math.ceil(height * scale)), max(1, math.ceil(width * scale))


def _pack(extents: list[tuple[float, float]], size: int) -> tuple[float, list[tuple[int, int]]]:
    """The largest scale (texels per metre, in steps of 2%) at which the charts, each with its padding, fit
    a ``size`` x ``size`` texture in shelves (tallest first); returns it and each chart's top-left texel (row, column).
    """
    area = sum(width * height for width, height in extents)
    scale = size / math.sqrt(area)  # no packing does better than filling the whole texture
    while True:
        shapes = [tuple(s + 2 * PADDING for s in _chart_shape(extent, scale)) for extent in extents]
        corners = _shelves(shapes, size)
        if corners is not None:
            return scale, corners
        scale *= 0.98


def _shelves(shapes: list[tuple[int, int]], size: int) -> list[tuple[int, int]] | None:
    """Top-left corners of boxes of ``shapes`` (rows, columns) in rows of shelves, or None where they do not fit."""
    corners: list[tuple[int, int]] = [(0, 0)] * len(shapes)
    row = column = shelf = 0
    for index in sorted(range(len(shapes)), key=lambda i: -shapes[i][0]):
        rows, columns = shapes[index]
        if column + columns > size:
            row, column, shelf = row + shelf, 0, 0
        if columns > size or row + rows > size:
            return None
        corners[index] = (row, column)
        column, shelf = column + columns, max(shelf, rows)
    return corners


def _wall_points(start, end, top: float, bottom: float, shape: tuple[int, int]) -> Float[np.ndarray, "r c 3"]:
    """The wall's point at each texel centre: columns from ``start`` to ``end``, rows from the ceiling down."""
    rows, columns = shape
    along = (np.arange(columns) + 0.5) / columns
    height = top - (np.arange(rows) + 0.5) / rows * (top - bottom)
    xy = start + along[:, None] * (end - start)
    return np.concatenate(
        [np.broadcast_to(xy, (rows, columns, 2)), np.broadcast_to(height[:, None, None], (rows, columns, 1))], axis=-1
    )


def _plan_points(axes, low, high, height: float, shape: tuple[int, int]) -> Float[np.ndarray, "r c 3"]:
    """The plan's point at each texel centre at ``height``: columns along the first of the ``axes``, rows
    down the second, over the box from ``low`` to ``high`` in their coordinates."""
    rows, columns = shape
    first = low[0] + (np.arange(columns) + 0.5) / columns * (high[0] - low[0])
    second = high[1] - (np.arange(rows) + 0.5) / rows * (high[1] - low[1])
    grid = np.stack(np.meshgrid(first, second), axis=-1) @ axes
    return np.concatenate([grid, np.full((rows, columns, 1), height)], axis=-1)


# one program for every chart of every room of a texture size: the points come padded to size x size
_project = jax.jit(project)


def _project_charts(
    cam: NonCentralPanorama, charts: list[np.ndarray], size: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each chart's pixels (u, v), NaN where no ray sees its point (:func:`~ncjax.geometry.camera.project`)."""
    counts = [points.shape[0] * points.shape[1] for points in charts]
    padded = np.zeros((size * size, 3), np.float32)
    ends = np.cumsum(counts)
    for points, start, end in zip(charts, ends - counts, ends, strict=True):
        padded[start:end] = points.reshape(-1, 3)
    u, v = (np.asarray(x) for x in _project(cam, padded))
    return [
        (u[start:end].reshape(points.shape[:2]), v[start:end].reshape(points.shape[:2]))
        for points, start, end in zip(charts, ends - counts, ends, strict=True)
    ]


def _hidden(
    points: Float[np.ndarray, "r c 3"], cam: NonCentralPanorama, plan: Float[np.ndarray, "n 2"], own: int | None, scale
) -> Bool[np.ndarray, "r c"]:
    """Where the ray to a point from its optical centre crosses a wall (other than the point's ``own``) first.

    Each point is seen from the optical centre of its azimuth, ``rc (cos varphi, sin varphi)``. The walls
    are vertical and reach from the floor to the ceiling, and every ray into the room starts between
    the two, so the plan decides: the segment from the centre to the point against each wall's segment.
    """
    xy = points[..., :2].reshape(-1, 2)
    azimuth = np.arctan2(xy[:, 1], xy[:, 0])
    centre = float(cam.rc) * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    ray = xy - centre
    reach = 1.0 - HIDING_TEXELS / scale / np.maximum(np.linalg.norm(ray, axis=-1), 1e-9)
    hidden = np.zeros(len(xy), bool)
    for k in range(len(plan)):
        if k == own:
            continue
        start, wall = plan[k], plan[(k + 1) % len(plan)] - plan[k]
        offset = start - centre
        denominator = _cross(ray, wall)
        with np.errstate(divide="ignore", invalid="ignore"):
            along_ray = _cross(offset, wall) / denominator
            along_wall = _cross(offset, ray) / denominator
        hidden |= (along_ray > 0) & (along_ray < reach) & (along_wall >= 0) & (along_wall <= 1)
    return hidden.reshape(points.shape[:2])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of the 2D cross product a x b, broadcast."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _colours(
    image: UInt8[np.ndarray, "H W 3"],
    u: Float[np.ndarray, "r c"],
    v: Float[np.ndarray, "r c"],
    hidden: Bool[np.ndarray, "r c"],
    photographed: Bool[np.ndarray, "H W"] | None = None,
) -> tuple[UInt8[np.ndarray, "r c 3"], Bool[np.ndarray, "r c"]]:
    """The panorama's colour at each pixel (bilinear; the columns wrap around), and where it has none: hidden,
    no pixel, or one of the four pixels it mixes outside ``photographed``."""
    unseen = hidden | ~np.isfinite(u) | ~np.isfinite(v)
    if photographed is not None:
        height, width = photographed.shape
        left = np.floor(np.where(unseen, 0.0, u)).astype(int)
        top = np.clip(np.floor(np.where(unseen, 0.0, v)).astype(int), 0, height - 1)
        bottom = np.minimum(top + 1, height - 1)
        for row in (top, bottom):
            for column in (left % width, (left + 1) % width):
                unseen |= ~photographed[row, column]
    u = np.where(unseen, 0.0, u).astype(np.float32)
    v = np.clip(np.where(unseen, 0.0, v), 0.0, image.shape[0] - 1.0).astype(np.float32)
    # OpenCV's bilinear weights are multiples of 1/32: a twentieth of a level where the panorama changes by 2 a
    # pixel. The rows wrap around too, only at v = H - 1, with a weight of 0.
    colours = cv2.remap(image, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    colours[unseen] = UNSEEN_COLOUR
    return colours, unseen


def _paint(
    texture: UInt8[np.ndarray, "N N 3"],
    unseen: Bool[np.ndarray, "N N"],
    corner: tuple[int, int],
    chart: UInt8[np.ndarray, "r c 3"],
    chart_unseen: Bool[np.ndarray, "r c"],
) -> None:
    """Put a chart's colours and unseen texels into the texture at ``corner``, its border repeated around it."""
    row, column = corner
    rows, columns = chart.shape[0] + 2 * PADDING, chart.shape[1] + 2 * PADDING
    texture[row : row + rows, column : column + columns] = np.pad(
        chart, ((PADDING,) * 2, (PADDING,) * 2, (0, 0)), "edge"
    )
    unseen[row : row + rows, column : column + columns] = np.pad(chart_unseen, PADDING, "edge")


def _uv(corner: tuple[int, int], rows: Float[np.ndarray, " V"], columns: Float[np.ndarray, " V"], size: int):
    """Texture coordinates (u to the right, v up, both in [0, 1]) of positions in a chart at ``corner``, in
    rows and columns of texels from the top-left edge of its texels (its padding not counted)."""
    return np.stack([(corner[1] + PADDING + columns) / size, 1.0 - (corner[0] + PADDING + rows) / size], axis=-1)


def _wall_surface(k: int, plan, top: float, bottom: float, uv) -> SurfaceMesh:
    """Wall ``k`` of ``plan`` as two triangles, its vertices ceiling-start, ceiling-end, floor-start, floor-end."""
    start, end = plan[k], plan[(k + 1) % len(plan)]
    vertices = np.array([[*start, top], [*end, top], [*start, bottom], [*end, bottom]])
    # as room_mesh: from corner i to corner j the room is on the left, so the normals point out of it
    faces = [[2, 3, 1], [2, 1, 0]] if signed_area(plan) > 0 else [[3, 2, 0], [3, 0, 1]]
    return SurfaceMesh(f"wall {k}", vertices, np.array(faces, np.int64), uv)
