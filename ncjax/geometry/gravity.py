"""Frames of a tilted panorama read as a central one: the roll/pitch rotation, and maps of points and pixels.

Also which image sizes are full panoramas (:func:`panorama_size_error`).

Conventions (docs/design.md section 2, central panorama ``rc = 0``): z up, pixel (u, v) of a
W x H equirectangular image looks along azimuth ``varphi = pi - 2 pi (u + 0.5) / W`` and
elevation ``phi = pi/2 - pi (v + 0.5) / H``, i.e. along
``(cos phi cos varphi, cos phi sin varphi, sin phi)``.

The *input frame* is the frame of the camera that took the (possibly tilted) image; the
*levelled frame* has its z axis along the true vertical. ``rotation`` (3 x 3) takes input
coordinates to levelled ones, ``p_level = rotation @ p_input``. With roll (about the
camera's x axis, the centre column's direction) and pitch (about its y axis, azimuth +90
degrees, a quarter of the width left of the centre), in degrees, right-handed:
``rotation = Ry(pitch) @ Rx(roll)``, and the true vertical seen in the input frame is
``rotation.T @ e_z = rotation[2] = (-sin pitch, cos pitch sin roll, cos pitch cos roll)``.

Everything here is numpy float64 (the image side, :mod:`ncjax.geometry.levelling`, works with OpenCV).
"""

from __future__ import annotations

import math

import numpy as np
from jaxtyping import ArrayLike, Float, Real

_ORTHONORMAL_TOLERANCE = 1e-5


def rotation_from_tilt(roll: float, pitch: float) -> Float[np.ndarray, "3 3"]:
    """The rotation ``Ry(pitch) @ Rx(roll)`` (degrees) taking a camera's frame to the levelled frame.

    Args:
        roll: rotation about the x axis (azimuth 0, the image's centre column), degrees.
        pitch: rotation about the y axis (azimuth +90 degrees), degrees.

    Returns:
        (3, 3) float64 rotation matrix.
    """
    r, p = math.radians(float(roll)), math.radians(float(pitch))
    rx = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(r), -math.sin(r)], [0.0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0.0, math.sin(p)], [0.0, 1.0, 0.0], [-math.sin(p), 0.0, math.cos(p)]])
    return ry @ rx


def tilt_from_up(up: Real[ArrayLike, 3]) -> tuple[float, float]:
    """Roll and pitch (degrees) of a camera that sees the true vertical along ``up`` (its own frame).

    Inverse of :func:`rotation_from_tilt`: ``tilt_from_up(rotation_from_tilt(r, p)[2]) == (r, p)``
    for pitch in (-90, 90) degrees.

    Raises:
        ValueError: ``up`` is zero or not finite.
    """
    up = np.asarray(up, np.float64)
    norm = float(np.linalg.norm(up)) if np.all(np.isfinite(up)) else 0.0
    if norm == 0.0:
        raise ValueError(f"up must be a finite non-zero vector, got {up.tolist()}")
    x, y, z = up / norm
    return math.degrees(math.atan2(y, z)), math.degrees(math.atan2(-x, math.hypot(y, z)))


def _check_rotation(rotation) -> np.ndarray:
    rotation = np.asarray(rotation, np.float64)
    if rotation.shape != (3, 3) or not np.all(np.isfinite(rotation)):
        raise ValueError(f"rotation must be a finite 3 x 3 matrix, got shape {rotation.shape}")
    if np.abs(rotation @ rotation.T - np.eye(3)).max() > _ORTHONORMAL_TOLERANCE or np.linalg.det(rotation) < 0:
        raise ValueError("rotation must be a proper rotation matrix (orthonormal, determinant +1)")
    return rotation


def _check_points(points) -> np.ndarray:
    points = np.asarray(points, np.float64)
    if points.ndim < 1 or points.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {points.shape}")
    return points


def to_input_frame(
    points: Real[ArrayLike, "*batch 3"], rotation: Float[ArrayLike, "3 3"]
) -> Float[np.ndarray, "*batch 3"]:
    """Points (or directions) of the levelled frame expressed in the input camera's frame.

    Args:
        points: (..., 3) coordinates in the levelled frame (e.g. a layout's corners, metres).
        rotation: the input -> levelled rotation (:attr:`GravityEstimate.rotation`).

    Returns:
        (..., 3) float64 coordinates ``rotation.T @ p`` in the input frame.

    Raises:
        ValueError: ``points`` is not (..., 3) or ``rotation`` is not a rotation matrix.
    """
    return _check_points(points) @ _check_rotation(rotation)


def to_level_frame(
    points: Real[ArrayLike, "*batch 3"], rotation: Float[ArrayLike, "3 3"]
) -> Float[np.ndarray, "*batch 3"]:
    """Points (or directions) of the input camera's frame expressed in the levelled frame (``rotation @ p``).

    Inverse of :func:`to_input_frame`.

    Raises:
        ValueError: ``points`` is not (..., 3) or ``rotation`` is not a rotation matrix.
    """
    return _check_points(points) @ _check_rotation(rotation).T


def panorama_size_error(width: int, height: int) -> str | None:
    """Why a ``width x height`` image cannot be a full 360 x 180 degree panorama, or None.

    The network and the camera model read the image as the whole sphere, so
    the aspect ratio must be 2:1.
    """
    if width != 2 * height or height < 32:
        return (
            f"{width} x {height} pixels is not a full 360 x 180 degree panorama "
            "(width must be 2 x height, at least 64 x 32)"
        )
    return None


def _check_size(width: int, height: int) -> None:
    if int(width) != width or int(height) != height or width <= 0 or width != 2 * height:
        raise ValueError(f"width x height must be a positive 2:1 panorama size, got {width} x {height}")


def pixel_to_direction(
    u: Real[ArrayLike, "*#batch"], v: Real[ArrayLike, "*#batch"], width: int, height: int
) -> Float[np.ndarray, "*batch 3"]:
    """Unit direction seen by pixel (u, v) of a W x H central equirectangular panorama.

    Args:
        u: column coordinates (pixel centres at integers).
        v: row coordinates, broadcastable with ``u``.
        width: W, the image's width.
        height: H = W / 2.

    Returns:
        (..., 3) float64 unit vectors.

    Raises:
        ValueError: the size is not 2:1.
    """
    _check_size(width, height)
    u, v = np.broadcast_arrays(np.asarray(u, np.float64), np.asarray(v, np.float64))
    azimuth = math.pi - 2.0 * math.pi * (u + 0.5) / width
    elevation = 0.5 * math.pi - math.pi * (v + 0.5) / height
    cos_el = np.cos(elevation)
    return np.stack([cos_el * np.cos(azimuth), cos_el * np.sin(azimuth), np.sin(elevation)], axis=-1)


def direction_to_pixel(
    xyz: Real[ArrayLike, "*batch 3"], width: int, height: int
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """Pixel (u, v) of a W x H central panorama that sees a direction (or a point: only its direction counts).

    Args:
        xyz: (..., 3) directions or points in the panorama's frame.
        width: W, the image's width.
        height: H = W / 2.

    Returns:
        ``(u, v)`` float64, u in [-0.5, W - 0.5), v in [-0.5, H - 0.5]; NaN for a zero vector.

    Raises:
        ValueError: the size is not 2:1 or ``xyz`` is not (..., 3).
    """
    _check_size(width, height)
    xyz = _check_points(xyz)
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    zero = (x == 0) & (y == 0) & (z == 0)
    azimuth = np.arctan2(y, x)
    elevation = np.arctan2(z, np.hypot(x, y))
    u = (math.pi - azimuth) * width / (2.0 * math.pi) - 0.5
    u = np.where(u >= width - 0.5, u - width, u)  # azimuth -pi is the same column as pi
    v = (0.5 * math.pi - elevation) * height / math.pi - 0.5
    return np.where(zero, np.nan, u), np.where(zero, np.nan, v)


def level_to_input_pixels(
    u: Real[ArrayLike, "*#batch"],
    v: Real[ArrayLike, "*#batch"],
    rotation: Float[ArrayLike, "3 3"],
    width: int,
    height: int,
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """Where pixel (u, v) of the levelled image lies in the input image (both W x H).

    Args:
        u: columns of the levelled image.
        v: rows of the levelled image, broadcastable with ``u``.
        rotation: the input -> levelled rotation (:attr:`GravityEstimate.rotation`).
        width: W.
        height: H = W / 2.

    Returns:
        ``(u, v)`` in the input image, float64.

    Raises:
        ValueError: the size is not 2:1 or ``rotation`` is not a rotation matrix.
    """
    return direction_to_pixel(to_input_frame(pixel_to_direction(u, v, width, height), rotation), width, height)


def input_to_level_pixels(
    u: Real[ArrayLike, "*#batch"],
    v: Real[ArrayLike, "*#batch"],
    rotation: Float[ArrayLike, "3 3"],
    width: int,
    height: int,
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """Where pixel (u, v) of the input image lies in the levelled image (inverse of :func:`level_to_input_pixels`).

    Raises:
        ValueError: the size is not 2:1 or ``rotation`` is not a rotation matrix.
    """
    return direction_to_pixel(to_level_frame(pixel_to_direction(u, v, width, height), rotation), width, height)
