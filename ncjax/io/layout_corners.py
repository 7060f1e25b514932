"""One image's layout corners as the layout formats store them, and the maps between their frames and ncjax's.

:class:`LayoutCorners` is what :mod:`ncjax.io.formats_read` reads from any format and what
:mod:`ncjax.evaluation.central_metrics` compares: corner pixels, and 3D corners where the format holds them.
The maps: ncjax's camera model in float64 (:func:`project_points`, :func:`pixel_angles`,
:func:`back_project`), PanoAnnotator's and ZInD's axes, and 3D corners from a plan.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
from jaxtyping import Float

from ..geometry.camera import NonCentralPanorama, pixel_to_angles, project

UNITS = ("metres", "camera heights")


@dataclasses.dataclass(frozen=True)
class LayoutCorners:
    """One image's layout corners as the layout formats store them.

    Attributes:
        ceiling: (n, 2) pixel coordinates (u column, v row; pixel centres at
            integers) of the ceiling point of each corner, in polygon order.
        floor: (n, 2) the floor point of each corner.
        width: image width W in pixels.
        height: image height H in pixels.
        format: the format it was read from: "label_cor", "horizonnet", "mp3d",
            "zind", "polygon" (ZInD-derived floor polygon at camera height 1) or "ncjax".
        rc: radius of the circle of optical centres (metres; 0 for a central panorama).
        ceiling_corners: (n, 3) the corners in ncjax's camera frame (z up) when the
            format holds them, else None.
        floor_corners: (n, 3) likewise.
        units: the unit of ``ceiling_corners`` and ``floor_corners``: "metres" or
            "camera heights" (the camera's height above the floor is 1); None
            without them.
    """

    ceiling: Float[np.ndarray, "n 2"]
    floor: Float[np.ndarray, "n 2"]
    width: int
    height: int
    format: str
    rc: float = 0.0
    ceiling_corners: Float[np.ndarray, "n 3"] | None = None
    floor_corners: Float[np.ndarray, "n 3"] | None = None
    units: str | None = None

    def __post_init__(self):
        if len(self.ceiling) < 3:
            raise ValueError(f"a layout needs at least 3 corners, got {len(self.ceiling)}")
        if not (np.all(np.isfinite(self.ceiling)) and np.all(np.isfinite(self.floor))):
            raise ValueError("the corner pixels must be finite")
        if (self.floor_corners is None) != (self.units is None) or (self.ceiling_corners is None) != (
            self.units is None
        ):
            raise ValueError("ceiling_corners, floor_corners and units come together")
        if self.units is not None and self.units not in UNITS:
            raise ValueError(f"units must be one of {UNITS}, got {self.units!r}")

    @property
    def count(self) -> int:
        """The number of corners."""
        return len(self.ceiling)

    @property
    def camera_height(self) -> float | None:
        """Height of the camera above the floor (``-h_f``) in ``units``, None without 3D corners."""
        return None if self.floor_corners is None else -float(np.mean(self.floor_corners[:, 2]))

    @property
    def label_cor(self) -> Float[np.ndarray, "n2 2"]:
        """The (2n, 2) points in ``label_cor`` order: ceiling then floor of each corner."""
        return np.stack([self.ceiling, self.floor], 1).reshape(-1, 2)


# --- frames and projection -------------------------------------------------------------------------


def camera_in_float64(cam: NonCentralPanorama) -> NonCentralPanorama:
    """The same camera with float64 leaves (call inside ``jax.enable_x64``)."""
    return NonCentralPanorama(
        cam.width,
        cam.height,
        rc=float(np.asarray(cam.rc)),
        fov_horizontal=float(np.asarray(cam.fov_horizontal)),
        fov_vertical=float(np.asarray(cam.fov_vertical)),
    )


def project_points(cam: NonCentralPanorama, points: Float[np.ndarray, "*n 3"]) -> Float[np.ndarray, "*n 2"]:
    """Pixels (u, v) of points of the camera frame, with ncjax's camera model in float64.

    Raises:
        ValueError: for a point that no ray of the camera sees (inside the circle of optical centres).
    """
    points = np.asarray(points, np.float64)
    with jax.enable_x64(True):
        u, v = project(camera_in_float64(cam), points)
        pixels = np.stack([np.asarray(u, np.float64), np.asarray(v, np.float64)], -1)
    if not np.all(np.isfinite(pixels)):
        raise ValueError(f"a corner lies inside the circle of optical centres (rc = {float(np.asarray(cam.rc))} m)")
    return pixels


def pixel_angles(
    width: int, height: int, pixels: Float[np.ndarray, "*n 2"]
) -> tuple[Float[np.ndarray, "*n"], Float[np.ndarray, "*n"]]:
    """Azimuth and elevation (radians, float64) of pixels of a full W x H panorama (docs/design.md section 2)."""
    pixels = np.asarray(pixels, np.float64)
    with jax.enable_x64(True):
        cam = camera_in_float64(NonCentralPanorama(width, height))
        azimuth, elevation = pixel_to_angles(cam, pixels[..., 0], pixels[..., 1])
        return np.asarray(azimuth, np.float64), np.asarray(elevation, np.float64)


def back_project(
    pixels: Float[np.ndarray, "n 2"], size: tuple[int, int], plane_height: float, rc: float = 0.0
) -> Float[np.ndarray, "n 2"]:
    """Plan points (x, y) where the rays of pixels meet the horizontal plane ``z = plane_height``.

    The ray of column u leaves its optical centre ``rc (cos varphi, sin varphi, 0)``
    radially at elevation phi (docs/design.md section 2), so it meets the plane at the
    horizontal distance ``plane_height / tan(phi)`` from that centre.

    Args:
        pixels: (n, 2) pixel coordinates (u, v) of a full panorama.
        size: (W, H) of the image.
        plane_height: the plane's height (> 0 for a ceiling, < 0 for a floor), in the unit of ``rc``.
        rc: radius of the circle of optical centres.

    Raises:
        ValueError: for a pixel whose ray does not meet the plane (on the wrong side of the horizon).
    """
    azimuth, elevation = pixel_angles(size[0], size[1], pixels)
    with np.errstate(divide="ignore", invalid="ignore"):
        distance = plane_height / np.tan(elevation)
    bad = ~(np.isfinite(distance) & (distance > 0))
    if np.any(bad):
        what, side = ("ceiling", "below") if plane_height > 0 else ("floor", "above")
        row = float(np.asarray(pixels)[np.argmax(bad), 1])
        raise ValueError(f"a {what} point lies on or {side} the horizon (row {row})")
    return (rc + distance)[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], -1)


def resized_pixels(pixels: Float[np.ndarray, "*shape"], size, new_size) -> Float[np.ndarray, "*shape"]:
    """Pixel coordinates of a panorama of ``size`` pixels in the same panorama resized to ``new_size``.

    Pixel centres are at integers, so the image's edges (-0.5 and ``size - 0.5``) keep their places.
    ``size`` and ``new_size`` broadcast against ``pixels``: a width each for columns, (W, H) for (u, v) points.
    """
    scale = np.asarray(new_size, np.float64) / np.asarray(size, np.float64)
    return (np.asarray(pixels, np.float64) + 0.5) * scale - 0.5


def leftmost_first(*arrays: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, ...]:
    """The arrays rolled along their first axis so that the corner of the smallest column comes first."""
    shift = int(np.argmin(columns))
    return tuple(np.roll(array, -shift, axis=0) for array in arrays)


def ncjax_to_panoannotator(xyz: Float[np.ndarray, "*n 3"]) -> Float[np.ndarray, "*n 3"]:
    """PanoAnnotator's (X, Y, Z) = (-y, z, -x) of ncjax's (x, y, z): Y up, azimuth ``-atan2(X, -Z)``."""
    xyz = np.asarray(xyz, np.float64)
    return np.stack([-xyz[..., 1], xyz[..., 2], -xyz[..., 0]], -1)


def panoannotator_to_ncjax_plan(xyz: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 2"]:
    """ncjax's plan point (x, y) = (-Z, -X) of PanoAnnotator points (X, Y, Z)."""
    xyz = np.asarray(xyz, np.float64)
    return np.stack([-xyz[:, 2], -xyz[:, 0]], -1)


def swap_axes(xy: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, "n 2"]:
    """(y, x) of (x, y): ZInD's plan point of ncjax's and back (the map is its own inverse)."""
    return np.asarray(xy, np.float64)[:, ::-1].copy()


def corners_at(
    plan: Float[np.ndarray, "n 2"], ceiling_z: float, floor_z: float
) -> tuple[Float[np.ndarray, "n 3"], Float[np.ndarray, "n 3"]]:
    """(n, 3) ceiling and floor corners above and below a floor plan."""
    plan = np.asarray(plan, np.float64)

    def at(z: float) -> np.ndarray:
        return np.concatenate([plan, np.full((len(plan), 1), z)], 1)

    return at(ceiling_z), at(floor_z)


def corners_from_3d(
    ceiling_corners: Float[np.ndarray, "n 3"],
    floor_corners: Float[np.ndarray, "n 3"],
    cam: NonCentralPanorama,
    *,
    format: str,
    units: str,
    rc: float | None = None,
) -> LayoutCorners:
    """:class:`LayoutCorners` of 3D corners, their pixels projected by ``cam``."""
    ceiling_corners = np.asarray(ceiling_corners, np.float64)
    floor_corners = np.asarray(floor_corners, np.float64)
    return LayoutCorners(
        ceiling=project_points(cam, ceiling_corners),
        floor=project_points(cam, floor_corners),
        width=cam.width,
        height=cam.height,
        format=format,
        rc=float(np.asarray(cam.rc)) if rc is None else rc,
        ceiling_corners=ceiling_corners,
        floor_corners=floor_corners,
        units=units,
    )
