"""Small synthetic rooms with exact per-column boundaries, for the solver tests
and experiments (a stand-in for ``ncjax.random_room``/``ncjax.room_labels``).

A room is a counter-clockwise polygon of ``n`` corners (static) in the camera
frame (the camera axis at the origin, strictly inside, with a margin larger
than ``rc``), a ceiling height ``h_c > 0`` and a floor height ``h_f < 0``.
Wall ``i`` goes from corner ``i`` to corner ``i + 1``. Every function is pure
and jit/vmap-able; random ones take a PRNG key.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PRNGKeyArray

from ._camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles, pixel_to_ray
from ._plucker import horizontal_wall_line

_MARGIN = 0.25  # metres between the circle of optical centres and any wall


def _rotate(points: Array, angle: Array) -> Array:
    c, s = jnp.cos(angle), jnp.sin(angle)
    return points @ jnp.array([[c, s], [-s, c]])


def convex_room(key: PRNGKeyArray, n: int, rc: Float[Array, ""]) -> Float[Array, "n 2"]:
    """A random convex ``n``-gon (Atlanta world) around the camera.

    Corners on an ellipse at jittered angles (every gap < 1.4 * 2 pi / n, so
    the inradius of the unit polygon is > 0.3 for n >= 4), stretched, rotated
    and shifted so that every wall is at least ``rc + 0.25`` m from the axis.
    """
    k_angle, k_jitter, k_size, k_stretch, k_shift, k_heading = jax.random.split(key, 6)
    angles = 2 * math.pi * (jnp.arange(n) + 0.2 * jax.random.uniform(k_jitter, (n,), minval=-1, maxval=1)) / n
    unit = jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)
    stretch = jnp.exp(jax.random.uniform(k_stretch, (), minval=-0.2, maxval=0.2))
    unit = unit * jnp.stack([stretch, 1 / stretch])  # inradius > 0.3 * 0.8
    inradius = 0.24
    size = (rc + _MARGIN + 0.5) / inradius + jax.random.uniform(k_size, (), minval=0.0, maxval=2.0)
    shift_radius = size * inradius - rc - _MARGIN
    heading = jax.random.uniform(k_heading, (), maxval=2 * math.pi)
    shift = shift_radius * jnp.sqrt(jax.random.uniform(k_shift, ())) * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
    return _rotate(size * unit - shift, jax.random.uniform(k_angle, (), maxval=2 * math.pi))


def rectangle_room(key: PRNGKeyArray, rc: Float[Array, ""]) -> Float[Array, "4 2"]:
    """A random rectangle at a random yaw (Manhattan world), camera inside with a margin."""
    k_size, k_shift, k_yaw = jax.random.split(key, 3)
    half = rc + _MARGIN + jax.random.uniform(k_size, (2,), minval=0.5, maxval=3.0)
    shift = (half - rc - _MARGIN) * jax.random.uniform(k_shift, (2,), minval=-1, maxval=1)
    corners = jnp.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]) * half - shift
    return _rotate(corners, jax.random.uniform(k_yaw, (), maxval=2 * math.pi))


def l_shaped_room(key: PRNGKeyArray, rc: Float[Array, ""]) -> Float[Array, "6 2"]:
    """A random L-shaped room (6 walls, one reflex corner) at a random yaw.

    The camera is inside the kernel (the rectangle from which the whole room
    is visible), with a margin, so no wall is occluded.
    """
    k_kernel, k_arm, k_cam, k_yaw = jax.random.split(key, 4)
    kernel = 2 * (rc + _MARGIN) + jax.random.uniform(k_kernel, (2,), minval=0.3, maxval=2.5)
    outer = kernel + jax.random.uniform(k_arm, (2,), minval=0.8, maxval=2.5)
    (c, e), (a, b) = kernel, outer
    corners = jnp.array([[0.0, 0.0], [a, 0.0], [a, e], [c, e], [c, b], [0.0, b]])
    camera = (rc + _MARGIN) + (kernel - 2 * (rc + _MARGIN)) * jax.random.uniform(k_cam, (2,))
    return _rotate(corners - camera, jax.random.uniform(k_yaw, (), maxval=2 * math.pi))


def random_heights(key: PRNGKeyArray) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """``(h_c, h_f)``: ceiling 0.5..1.5 m above the camera, floor 1.0..1.8 m below."""
    k_c, k_f = jax.random.split(key)
    return jax.random.uniform(k_c, (), minval=0.5, maxval=1.5), -jax.random.uniform(k_f, (), minval=1.0, maxval=1.8)


def wall_parameters(corners: Float[Array, "n 2"]) -> tuple[Float[Array, "n 2"], Float[Array, " n"]]:
    """Unit directions ``(P_i+1 - P_i) / |...|`` and distances ``d_i = P_i . e2`` (< 0 inside a CCW room)."""
    edges = jnp.roll(corners, -1, axis=0) - corners
    directions = edges / jnp.linalg.norm(edges, axis=-1, keepdims=True)
    normals = jnp.stack([-directions[:, 1], directions[:, 0]], -1)
    return directions, jnp.sum(corners * normals, -1)


def wall_lines(
    corners: Float[Array, "n 2"], h_c: Float[Array, ""], h_f: Float[Array, ""]
) -> tuple[Float[Array, "n 6"], Float[Array, "n 6"]]:
    """Exact ceiling and floor Plücker lines of every wall."""
    directions, distances = wall_parameters(corners)
    return horizontal_wall_line(directions, distances, h_c), horizontal_wall_line(directions, distances, h_f)


def exact_boundaries(
    cam: NonCentralPanorama, corners: Float[Array, "n 2"], h_c: Float[Array, ""], h_f: Float[Array, ""]
) -> tuple[Float[Array, " W"], Float[Array, " W"], Int[Array, " W"]]:
    """Exact ceiling/floor boundary rows and the wall seen, for every column.

    2D ray casting from the optical centre ``rc (cos az, sin az)`` along
    ``(cos az, sin az)``: ``t`` the horizontal distance to the first wall hit,
    the ceiling is seen at elevation ``atan2(h_c, t)`` and the floor at
    ``atan2(h_f, t)`` (paper eq. forward), mapped to rows by eq. img.

    Returns:
        ``(ceiling_v, floor_v, wall_index)``, each (W,).
    """
    columns = jnp.arange(cam.width, dtype=corners.dtype)
    azimuth, _ = pixel_to_angles(cam, columns, 0.0)
    direction = jnp.stack([jnp.cos(azimuth), jnp.sin(azimuth)], -1)
    origin = cam.rc * direction
    edges = jnp.roll(corners, -1, axis=0) - corners
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    offset = corners[None] - origin[:, None]  # (W, n, 2)
    denominator = cross(direction[:, None], edges[None])
    safe = jnp.where(denominator == 0, 1.0, denominator)
    t = cross(offset, edges[None]) / safe
    s = cross(offset, direction[:, None]) / safe
    hit = (denominator != 0) & (t > 0) & (s >= 0) & (s <= 1)
    t = jnp.where(hit, t, jnp.inf)
    wall_index = jnp.argmin(t, axis=1).astype(jnp.int32)
    distance = jnp.min(t, axis=1)
    _, ceiling_v = angles_to_pixel(cam, azimuth, jnp.arctan2(h_c, distance))
    _, floor_v = angles_to_pixel(cam, azimuth, jnp.arctan2(h_f, distance))
    return ceiling_v, floor_v, wall_index



def exact_rays(
    cam: NonCentralPanorama, corners: Float[Array, "n 2"], h_c: Float[Array, ""], h_f: Float[Array, ""]
) -> tuple[Float[Array, "W 6"], Float[Array, "W 6"], Int[Array, " W"]]:
    """:func:`exact_boundaries` back-projected: ``(ceiling_rays, floor_rays, wall_index)``."""
    ceiling_v, floor_v, wall_index = exact_boundaries(cam, corners, h_c, h_f)
    return (*boundary_rays(cam, ceiling_v, floor_v), wall_index)


def boundary_rays(
    cam: NonCentralPanorama, ceiling_v: Float[Array, " W"], floor_v: Float[Array, " W"]
) -> tuple[Float[Array, "W 6"], Float[Array, "W 6"]]:
    """Rays of the per-column boundary rows (column ``u`` at its centre, ``u = 0..W-1``)."""
    columns = jnp.arange(cam.width, dtype=ceiling_v.dtype)
    return pixel_to_ray(cam, columns, ceiling_v), pixel_to_ray(cam, columns, floor_v)


def manhattan_labels(directions: Float[Array, "n 2"]) -> Int[Array, " n"]:
    """0 for walls parallel to wall 0, 1 for walls perpendicular to it."""
    return (jnp.abs(directions @ directions[0]) < 0.5).astype(jnp.int32)
