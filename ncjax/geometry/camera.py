"""The non-central circular panorama (paper Section 3, eqs. forward, img, backproj, pluckerray).

Conventions (docs/design.md section 2): metres, z up, the circle of optical centres of
radius ``rc`` in the plane z = 0. Column ``u`` has azimuth
``varphi = fov_h/2 - fov_h (u + 0.5) / W`` (pi - 2 pi (u + 0.5) / W for the full
panorama: azimuth DEcreases to the right) and row ``v`` has elevation
``phi = fov_v/2 - fov_v (v + 0.5) / H`` (the top row looks up).

Visibility policy: a point whose horizontal distance to the axis is not larger
than ``rc`` lies inside (or on) the circle of optical centres; no ray of the
panorama reaches it, so :func:`project` returns NaN pixels for it and
:func:`is_visible` returns False. Gradients stay finite everywhere (double
``where``). Points outside the vertical field of view still get their (out of
image) pixel coordinates.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from .plucker import _as_float


class NonCentralPanorama(eqx.Module):
    """A non-central circular panorama camera.

    Static fields (part of the pytree structure, changing them recompiles):
    ``width`` W and ``height`` H in pixels. Traced fields (pytree leaves, may be
    batched with ``jax.vmap`` and differentiated): ``rc`` the radius of the
    circle of optical centres in metres (0 gives the central equirectangular
    panorama), ``fov_horizontal`` and ``fov_vertical`` in radians (defaults
    2 pi and pi), centred on azimuth 0 and elevation 0.
    """

    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)
    rc: Float[Array, ""] = eqx.field(converter=_as_float)
    fov_horizontal: Float[Array, ""] = eqx.field(converter=_as_float)
    fov_vertical: Float[Array, ""] = eqx.field(converter=_as_float)

    def __init__(
        self,
        width: int = 1024,
        height: int = 512,
        rc: ArrayLike = 0.0,
        fov_horizontal: ArrayLike = 2.0 * math.pi,
        fov_vertical: ArrayLike = math.pi,
    ):
        if int(width) != width or width <= 0 or int(height) != height or height <= 0:
            raise ValueError(f"width and height must be positive integers, got {width} x {height}")
        self.width = int(width)
        self.height = int(height)
        self.rc = rc
        self.fov_horizontal = fov_horizontal
        self.fov_vertical = fov_vertical

    def __check_init__(self):
        # Only concrete values can be checked; traced ones are the caller's job.
        try:
            rc = float(jnp.min(self.rc))
        except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):
            return
        if not math.isfinite(rc) or rc < 0.0:
            raise ValueError(f"rc must be a finite radius >= 0 in metres, got {rc}")


def pixel_to_angles(
    cam: NonCentralPanorama, u: Float[ArrayLike, "*#batch"], v: Float[ArrayLike, "*#batch"]
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Azimuth ``varphi`` and elevation ``phi`` of pixel (u, v) (paper eq. backproj).

    Args:
        cam: the camera.
        u: column coordinate (pixel centres at integer + 0.5 edges, i.e. u = 0 is
            the centre of the first column).
        v: row coordinate, same convention.

    Returns:
        ``(azimuth, elevation)`` in radians, broadcast to a common shape.
    """
    u, v = _as_float(u), _as_float(v)
    azimuth = cam.fov_horizontal / 2 - cam.fov_horizontal * (u + 0.5) / cam.width
    elevation = cam.fov_vertical / 2 - cam.fov_vertical * (v + 0.5) / cam.height
    return tuple(jnp.broadcast_arrays(azimuth, elevation))


def angles_to_pixel(
    cam: NonCentralPanorama,
    azimuth: Float[ArrayLike, "*#batch"],
    elevation: Float[ArrayLike, "*#batch"],
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Pixel (u, v) of an azimuth and elevation (paper eq. img, inverse of eq. backproj).

    For the full panorama an azimuth in (-pi, pi] maps to u in [-0.5, W - 0.5).
    """
    azimuth, elevation = _as_float(azimuth), _as_float(elevation)
    u = (cam.fov_horizontal / 2 - azimuth) / cam.fov_horizontal * cam.width - 0.5
    v = (cam.fov_vertical / 2 - elevation) / cam.fov_vertical * cam.height - 0.5
    return tuple(jnp.broadcast_arrays(u, v))


def angles_to_ray(
    rc: Float[ArrayLike, "*#batch"],
    azimuth: Float[ArrayLike, "*#batch"],
    elevation: Float[ArrayLike, "*#batch"],
) -> Float[Array, "*batch 6"]:
    """Plücker coordinates of the projecting ray of given angles (paper eq. pluckerray).

    The ray leaves the optical centre ``rc (cos varphi, sin varphi, 0)`` along
    the unit direction ``(cos phi cos varphi, cos phi sin varphi, sin phi)``; its
    moment is ``centre x direction``.
    """
    rc, azimuth, elevation = jnp.broadcast_arrays(_as_float(rc), _as_float(azimuth), _as_float(elevation))
    cos_el, sin_el = jnp.cos(elevation), jnp.sin(elevation)
    cos_az, sin_az = jnp.cos(azimuth), jnp.sin(azimuth)
    return jnp.stack(
        [
            cos_el * cos_az,
            cos_el * sin_az,
            sin_el,
            rc * sin_el * sin_az,
            -rc * sin_el * cos_az,
            jnp.zeros_like(rc),
        ],
        axis=-1,
    )


def pixel_to_ray(
    cam: NonCentralPanorama, u: Float[ArrayLike, "*#batch"], v: Float[ArrayLike, "*#batch"]
) -> Float[Array, "*batch 6"]:
    """Back-projection: the Plücker ray of pixel (u, v) (paper eqs. backproj, pluckerray).

    Args:
        cam: the camera.
        u: column coordinates, any shape.
        v: row coordinates, broadcastable with ``u``.

    Returns:
        Unit-direction Plücker rays, shape ``broadcast(u, v).shape + (6,)``.
    """
    azimuth, elevation = pixel_to_angles(cam, u, v)
    return angles_to_ray(cam.rc, azimuth, elevation)


def optical_centre(cam: NonCentralPanorama, u: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch 3"]:
    """The optical centre of column ``u``: ``rc (cos varphi, sin varphi, 0)``."""
    azimuth, _ = pixel_to_angles(cam, u, 0.0)
    return jnp.stack([cam.rc * jnp.cos(azimuth), cam.rc * jnp.sin(azimuth), jnp.zeros_like(azimuth)], -1)


def is_visible(cam: NonCentralPanorama, xyz: Float[ArrayLike, "*#batch 3"]) -> Bool[Array, "*batch"]:
    """True where a point lies strictly outside the circle of optical centres.

    Only such points are seen by the panorama (see the module's visibility policy).
    """
    xyz = _as_float(xyz)
    return xyz[..., 0] ** 2 + xyz[..., 1] ** 2 > cam.rc**2


def point_to_angles(
    cam: NonCentralPanorama, xyz: Float[ArrayLike, "*#batch 3"]
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Azimuth and elevation under which a point is seen (paper eq. forward, w = 1).

    ``varphi = atan2(y, x)``, ``phi = atan2(z, sqrt(x^2 + y^2) - rc)``. NaN for
    points that are not visible (inside the circle of optical centres); the
    gradients are finite (zero) there.
    """
    xyz = _as_float(xyz)
    visible = is_visible(cam, xyz)
    # Double where: feed harmless values to sqrt/atan2 where the point is not
    # visible, so that neither the value nor the gradient becomes NaN there.
    safe_x = jnp.where(visible, xyz[..., 0], cam.rc + 1.0)
    safe_y = jnp.where(visible, xyz[..., 1], 0.0)
    radius = jnp.sqrt(safe_x**2 + safe_y**2)
    azimuth = jnp.arctan2(safe_y, safe_x)
    elevation = jnp.arctan2(xyz[..., 2], radius - cam.rc)
    nan = jnp.full_like(azimuth, jnp.nan)
    return jnp.where(visible, azimuth, nan), jnp.where(visible, elevation, nan)


def project(
    cam: NonCentralPanorama, xyz: Float[ArrayLike, "*#batch 3"]
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Forward projection of 3D points to pixels (paper eqs. forward and img).

    Args:
        cam: the camera.
        xyz: points in the camera frame, metres, shape ``(..., 3)``.

    Returns:
        ``(u, v)`` each of shape ``(...)``; NaN where :func:`is_visible` is False.
    """
    azimuth, elevation = point_to_angles(cam, xyz)
    return angles_to_pixel(cam, azimuth, elevation)


def elevation_to_row(elevation: Float[ArrayLike, "*batch"], height: int) -> Float[Array, "*batch"]:
    """Sub-pixel row of an elevation in a full-sphere panorama of ``height`` rows (docs/design.md 2)."""
    return angles_to_pixel(NonCentralPanorama(2 * height, height), 0.0, elevation)[1]


def row_to_elevation(row: Float[ArrayLike, "*batch"], height: int) -> Float[Array, "*batch"]:
    """Elevation (radians) of a sub-pixel row, inverse of :func:`elevation_to_row`."""
    return pixel_to_angles(NonCentralPanorama(2 * height, height), 0.0, row)[1]
