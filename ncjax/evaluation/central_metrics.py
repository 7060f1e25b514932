"""Layout metrics as the central-panorama papers compute them, from two corner sets of one image.

The inputs are two :class:`~ncjax.io.layout_corners.LayoutCorners` (e.g. from
:func:`ncjax.io.formats_read.read_layout`): a prediction and its ground truth, each
the ceiling and floor pixels of its corners, plus 3D corners where the format holds
them. The definitions follow HorizonNet's ``eval_general.py`` / ``eval_cuboid.py``
and LGT-Net's ``evaluation/accuracy.py`` (read for their definitions; this is an
independent implementation, vectorised in numpy, with exact polygon operations in
shapely):

- **Room geometry.** When both layouts have 3D corners in metres, those are used as
  they are. Otherwise both rooms are put at camera height 1 (HorizonNet's and
  LGT-Net's convention): 3D corners are divided by their camera height; pixel-only
  corners are back-projected, the floor points onto the plane z = -1 (giving the floor
  plan) and the ceiling height is the mean over corners of the height at which each
  ceiling point's ray meets the vertical through its floor point (HorizonNet's
  ``get_z1``); the ceiling points are then back-projected onto that ceiling plane. The
  back-projection uses the camera's radius (``rc``, in camera heights where a camera
  height in metres is known, else 0: central), so it is exact for a non-central
  camera whose camera height is known.
- **2D IoU**: intersection over union of the floor plans (non-convex polygons).
- **3D IoU**: of the rooms extruded between floor and ceiling height, each room with
  the heights it implies: area of the plans' intersection times the overlap of the
  height intervals, over the union volume.
- **Corner error (CE)**: mean pixel distance between matched corners (ceiling and
  floor point of each), as a percentage of the image diagonal ``sqrt(W^2 + H^2)``.
  HorizonNet compares the corners in their stored order; here they are matched one to
  one by the assignment of least total distance (horizontal distances wrap around the
  panorama), so the starting corner and the direction of the list do not matter.
  With different corner counts only min(n_pred, n_gt) corners are matched and
  ``corner_count_match`` is 0.
- **Pixel error (PE)**: percentage of the image's pixels whose class (ceiling, wall,
  floor) differs. Each layout's class boundary in column u is where the column's ray
  first meets a wall of its floor plan (ceiling plan for the ceiling boundary), as
  HorizonNet's per-column boundaries of the corners.
- **Depth RMSE and delta-1**: on the per-pixel layout depth (distance along each
  pixel's ray to the layout's ceiling, walls or floor), as HorizonNet's
  ``layout_2_depth`` and LGT-Net's ``layout2depth``: floor pixels at the floor plane,
  wall pixels at the floor boundary's wall distance, ceiling pixels at the height the
  column's ceiling boundary implies over that distance. RMSE =
  ``sqrt(mean((d_pred - d_gt)^2))`` (in metres or camera heights, see ``metric``);
  delta-1 = share of pixels with ``max(d_pred / d_gt, d_gt / d_pred) < 1.25``. Pixels
  whose column meets no wall (the camera outside a predicted room) are left out.

A prediction whose image size differs from the ground truth's is rescaled to it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping

import numpy as np
import shapely
from jaxtyping import Float, Int8

from ..io.layout_corners import LayoutCorners, back_project, pixel_angles, resized_pixels

__all__ = [
    "RoomGeometry",
    "aggregate_central",
    "corner_error_percent",
    "evaluate_corners",
    "iou_2d_3d",
    "layout_depth",
    "pixel_error_percent",
    "rescaled",
    "room_geometry",
    "surface_classes",
]

DELTA_THRESHOLD = 1.25
CEILING, WALL, FLOOR = 0, 1, 2


@dataclasses.dataclass(frozen=True)
class RoomGeometry:
    """A layout as a room: plans, heights and the camera's radius in one unit.

    Attributes:
        floor_plan: (n, 2) floor corners (x, y) in ncjax's camera frame.
        ceiling_plan: (n, 2) ceiling corners (x, y).
        ceiling_height: ``h_c`` > 0 above the camera.
        floor_height: ``h_f`` < 0.
        rc: radius of the circle of optical centres.
    """

    floor_plan: Float[np.ndarray, "n 2"]
    ceiling_plan: Float[np.ndarray, "n 2"]
    ceiling_height: float
    floor_height: float
    rc: float


def rescaled(corners: LayoutCorners, width: int, height: int) -> LayoutCorners:
    """The corners' pixels in a W x H image of the same panorama (pixel centres at integers)."""
    if (corners.width, corners.height) == (width, height):
        return corners
    size, new_size = (corners.width, corners.height), (width, height)
    return dataclasses.replace(
        corners,
        ceiling=resized_pixels(corners.ceiling, size, new_size),
        floor=resized_pixels(corners.floor, size, new_size),
        width=width,
        height=height,
    )


def room_geometry(corners: LayoutCorners, *, metric: bool, rc: float = 0.0) -> RoomGeometry:
    """The room of one layout: in metres (``metric``, needs 3D corners in metres) or at camera height 1.

    Args:
        corners: the layout.
        metric: use the 3D corners in metres as they are.
        rc: the camera's radius in the unit of the result (for the back-projection of
            pixel-only layouts; kept in the result for the rays of PE and depth).

    Raises:
        ValueError: for ``metric`` without 3D corners in metres, or pixels that cannot be back-projected.
    """
    if corners.floor_corners is not None and (metric or corners.units is not None):
        if metric and corners.units != "metres":
            raise ValueError(f"metric geometry needs corners in metres, the {corners.format} layout has none")
        scale = 1.0 if metric else 1.0 / corners.camera_height
        ceiling, floor = corners.ceiling_corners * scale, corners.floor_corners * scale
        return RoomGeometry(
            floor_plan=floor[:, :2],
            ceiling_plan=ceiling[:, :2],
            ceiling_height=float(np.mean(ceiling[:, 2])),
            floor_height=float(np.mean(floor[:, 2])),
            rc=rc,
        )
    if metric:
        raise ValueError(f"metric geometry needs corners in metres, the {corners.format} layout has none")
    size = (corners.width, corners.height)
    floor_plan = back_project(corners.floor, size, -1.0, rc)
    _, ceiling_elevation = pixel_angles(*size, corners.ceiling)
    wall_distance = np.linalg.norm(floor_plan, axis=1) - rc
    ceiling_height = float(np.mean(wall_distance * np.tan(ceiling_elevation)))
    if not ceiling_height > 0:
        raise ValueError(f"the {corners.format} layout's ceiling points lie below the horizon")
    ceiling_plan = back_project(corners.ceiling, size, ceiling_height, rc)
    return RoomGeometry(floor_plan, ceiling_plan, ceiling_height, -1.0, rc)


def _polygon(plan: np.ndarray) -> shapely.Geometry:
    polygon = shapely.Polygon(plan)
    return polygon if polygon.is_valid else shapely.make_valid(polygon)


def iou_2d_3d(pred: RoomGeometry, gt: RoomGeometry) -> tuple[float, float]:
    """2D IoU of the floor plans and 3D IoU of the extruded rooms (fractions in [0, 1])."""
    a, b = _polygon(pred.floor_plan), _polygon(gt.floor_plan)
    area_a, area_b = shapely.area(a), shapely.area(b)
    intersection = shapely.area(shapely.intersection(a, b))
    union = area_a + area_b - intersection
    iou2d = intersection / union if union > 0 else 0.0
    overlap = max(0.0, min(pred.ceiling_height, gt.ceiling_height) - max(pred.floor_height, gt.floor_height))
    volume_a = area_a * (pred.ceiling_height - pred.floor_height)
    volume_b = area_b * (gt.ceiling_height - gt.floor_height)
    volume_union = volume_a + volume_b - intersection * overlap
    iou3d = intersection * overlap / volume_union if volume_union > 0 else 0.0
    return float(iou2d), float(iou3d)


def corner_error_percent(pred: LayoutCorners, gt: LayoutCorners) -> float:
    """CE: mean distance (pixels) of matched corner points, % of the image diagonal (see the module)."""
    width, height = gt.width, gt.height
    pred_points = np.stack([pred.ceiling, pred.floor], 1)  # (n, 2 points, 2)
    gt_points = np.stack([gt.ceiling, gt.floor], 1)
    difference = np.abs(pred_points[:, None] - gt_points[None])  # (n_pred, n_gt, 2, 2)
    difference[..., 0] = np.minimum(difference[..., 0], width - difference[..., 0])
    distance = np.linalg.norm(difference, axis=-1).mean(-1)  # (n_pred, n_gt)
    from scipy.optimize import linear_sum_assignment  # here: scipy.optimize costs every ncjax command 0.4 s to import

    rows, columns = linear_sum_assignment(distance)
    return float(100.0 * distance[rows, columns].mean() / math.hypot(width, height))


def _column_distances(plan: np.ndarray, azimuth: np.ndarray, rc: float) -> np.ndarray:
    """(W,) horizontal distance from each column's optical centre to the first wall its ray meets (NaN if none)."""
    direction = np.stack([np.cos(azimuth), np.sin(azimuth)], -1)[:, None]  # (W, 1, 2)
    start = plan[None]
    edge = (np.roll(plan, -1, axis=0) - plan)[None]  # (1, n, 2)
    offset = start - rc * direction  # (W, n, 2)

    def cross(p, q):
        return p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]

    denominator = cross(direction, edge)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = cross(offset, edge) / denominator
        along = cross(offset, direction) / denominator
    tolerance = 1e-9
    hit = (np.abs(denominator) > 1e-12) & (distance > tolerance) & (along >= -tolerance) & (along <= 1 + tolerance)
    nearest = np.where(hit, distance, np.inf).min(axis=1)
    return np.where(np.isfinite(nearest), nearest, np.nan)


def _boundaries(room: RoomGeometry, width: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per column: ceiling and floor boundary elevations and the floor plan's wall distance."""
    azimuth, _ = pixel_angles(width, 2, np.stack([np.arange(width), np.zeros(width)], -1))
    floor_distance = _column_distances(room.floor_plan, azimuth, room.rc)
    ceiling_distance = _column_distances(room.ceiling_plan, azimuth, room.rc)
    ceiling_elevation = np.arctan2(room.ceiling_height, ceiling_distance)
    floor_elevation = np.arctan2(room.floor_height, floor_distance)
    return ceiling_elevation, floor_elevation, floor_distance


def _row_elevations(width: int, height: int) -> np.ndarray:
    _, elevation = pixel_angles(width, height, np.stack([np.zeros(height), np.arange(height)], -1))
    return elevation[:, None]  # (H, 1)


def surface_classes(room: RoomGeometry, width: int, height: int) -> Int8[np.ndarray, "H W"]:
    """(H, W) class of each pixel: 0 ceiling, 1 wall, 2 floor (columns without a wall: wall)."""
    ceiling_elevation, floor_elevation, _ = _boundaries(room, width)
    elevation = _row_elevations(width, height)
    classes = np.full((height, width), WALL, np.int8)
    classes[elevation > ceiling_elevation[None]] = CEILING
    classes[elevation < floor_elevation[None]] = FLOOR
    return classes


def pixel_error_percent(pred: RoomGeometry, gt: RoomGeometry, width: int, height: int) -> float:
    """PE: % of pixels whose ceiling / wall / floor class differs."""
    return float(100.0 * np.mean(surface_classes(pred, width, height) != surface_classes(gt, width, height)))


def layout_depth(room: RoomGeometry, width: int, height: int) -> Float[np.ndarray, "H W"]:
    """(H, W) distance along each pixel's ray to the layout (NaN in columns that meet no wall)."""
    ceiling_elevation, floor_elevation, wall_distance = _boundaries(room, width)
    elevation = _row_elevations(width, height)
    column_ceiling_height = wall_distance * np.tan(ceiling_elevation)  # as HorizonNet's layout_2_depth
    sine, cosine = np.sin(elevation), np.cos(elevation)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(
            elevation > ceiling_elevation[None],
            column_ceiling_height[None] / sine,
            np.where(elevation < floor_elevation[None], room.floor_height / sine, wall_distance[None] / cosine),
        )
    return np.where(np.isnan(wall_distance)[None], np.nan, depth)


def _camera_height_in_metres(*layouts: LayoutCorners) -> float | None:
    for corners in layouts:
        if corners.units == "metres":
            return corners.camera_height
    return None


def evaluate_corners(pred: LayoutCorners, gt: LayoutCorners) -> dict[str, float]:
    """All metrics of the module docstring for one image.

    Returns:
        "iou2d" and "iou3d" (fractions), "corner_error" and "pixel_error" (%),
        "depth_rmse" (metres when "metric" is 1, else camera heights), "delta1"
        (fraction), "corner_count_match" (1 or 0) and "metric" (1 when both layouts
        are in metres and the rooms were compared as they are).

    Raises:
        ValueError: for a layout whose corners cannot be back-projected.
    """
    pred = rescaled(pred, gt.width, gt.height)
    metric = pred.units == "metres" and gt.units == "metres"
    radius = gt.rc if gt.rc > 0 else pred.rc
    camera_height = _camera_height_in_metres(gt, pred)
    if metric:
        rc = radius
    else:
        rc = radius / camera_height if camera_height else 0.0
    pred_room = room_geometry(pred, metric=metric, rc=rc)
    gt_room = room_geometry(gt, metric=metric, rc=rc)
    iou2d, iou3d = iou_2d_3d(pred_room, gt_room)
    width, height = gt.width, gt.height
    pred_depth, gt_depth = layout_depth(pred_room, width, height), layout_depth(gt_room, width, height)
    finite = np.isfinite(pred_depth) & np.isfinite(gt_depth) & (pred_depth > 0) & (gt_depth > 0)
    if np.any(finite):
        pred_depth, gt_depth = pred_depth[finite], gt_depth[finite]
        rmse = float(np.sqrt(np.mean((pred_depth - gt_depth) ** 2)))
        delta1 = float(np.mean(np.maximum(pred_depth / gt_depth, gt_depth / pred_depth) < DELTA_THRESHOLD))
    else:
        rmse = delta1 = math.nan
    return {
        "iou2d": iou2d,
        "iou3d": iou3d,
        "corner_error": corner_error_percent(pred, gt),
        "pixel_error": pixel_error_percent(pred_room, gt_room, width, height),
        "depth_rmse": rmse,
        "delta1": delta1,
        "corner_count_match": float(pred.count == gt.count),
        "metric": float(metric),
    }


def aggregate_central(results: Iterable[Mapping[str, float]]) -> dict[str, float]:
    """Mean of each metric over images (NaN-skipping), plus "images"."""
    results = list(results)
    if not results:
        raise ValueError("no results to aggregate")
    summary = {key: float(np.nanmean([result[key] for result in results])) for key in results[0]}
    summary["images"] = float(len(results))
    return summary
