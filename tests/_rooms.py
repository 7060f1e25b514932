"""Test helpers: exact synthetic rooms padded to a fixed wall capacity."""

import functools

import jax
import jax.numpy as jnp

import ncjax
from ncjax import _exact_rooms as rooms

WIDTH, HEIGHT = 256, 128


@functools.partial(jax.jit, static_argnames=("kind", "capacity"))
def sample_room(key, kind: str, capacity: int = 8, rc=None):
    """One random room as a dict of fixed-shape arrays (jit/vmap-able).

    kind: "convex" (6 walls, Atlanta), "rectangle" (4) or "l_shape" (6).
    """
    k_rc, k_room, k_h = jax.random.split(key, 3)
    if rc is None:
        rc = jax.random.uniform(k_rc, (), minval=0.1, maxval=1.0)
    generator = {
        "convex": lambda k: rooms.convex_room(k, 6, rc),
        "rectangle": lambda k: rooms.rectangle_room(k, rc),
        "l_shape": lambda k: rooms.l_shaped_room(k, rc),
    }[kind]
    return room_data(generator(k_room), *rooms.random_heights(k_h), rc, capacity)


def room_data(corners, h_c, h_f, rc, capacity: int = 8):
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=rc)
    n = corners.shape[0]
    ceiling_v, floor_v, wall_index = rooms.exact_boundaries(cam, corners, h_c, h_f)
    directions, distances = rooms.wall_parameters(corners)
    pad = lambda x: jnp.zeros((capacity,) + x.shape[1:], x.dtype).at[:n].set(x)  # noqa: E731
    return dict(
        cam=cam,
        ceiling_v=ceiling_v,
        floor_v=floor_v,
        wall_index=wall_index,
        mask=jnp.arange(capacity) < n,
        directions=pad(directions),
        distances=pad(distances),
        labels=pad(rooms.manhattan_labels(directions)),
        corners=pad(corners),
        h_c=h_c,
        h_f=h_f,
    )


def rays(room):
    return rooms.boundary_rays(room["cam"], room["ceiling_v"], room["floor_v"])


def direction_error_deg(a, b):
    """Angle between unit 2D directions, degrees (signs must agree)."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.degrees(jnp.arctan2(jnp.abs(cross), jnp.sum(a * b, -1)))
