"""Manhattan and Atlanta layout solvers, layout corners (paper Sections 4.2, 4.3)."""

import jax
import jax.numpy as jnp
import numpy as np
from _rooms import direction_error_deg, rays, room_data, sample_room
from hypothesis import given
from hypothesis import strategies as st
from test_wall import check_gradients

import ncjax
from ncjax._exact_rooms import boundary_rays

N_ROOMS = 100  # per kind


def _manhattan(room):
    ceiling_rays, floor_rays = rays(room)
    return ncjax.solve_manhattan_layout(ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["labels"])


def _atlanta(room):
    ceiling_rays, floor_rays = rays(room)
    return ncjax.solve_atlanta_layout(ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"])


@jax.jit
def _manhattan_many(keys):
    half = keys.shape[0] // 2
    rectangles = jax.vmap(lambda k: sample_room(k, "rectangle"))(keys[:half])
    l_shapes = jax.vmap(lambda k: sample_room(k, "l_shape"))(keys[half:])
    rooms = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), rectangles, l_shapes)
    return rooms, jax.vmap(_manhattan)(rooms)


@jax.jit
def _atlanta_many(keys):
    rooms = jax.vmap(lambda k: sample_room(k, "convex"))(keys)
    return rooms, jax.vmap(_atlanta)(rooms)


def _errors(rooms, layout):
    mask = rooms["mask"]
    corners = jax.vmap(ncjax.layout_corners)(layout.ceiling_lines, layout.mask)
    corner_error = jnp.linalg.norm(corners[..., :2] - rooms["corners"], axis=-1)
    return dict(
        ok=bool(jnp.all(layout.ok)),
        mask=bool(jnp.all(layout.mask == mask)),
        direction=float(jnp.max(jnp.where(mask, direction_error_deg(layout.directions, rooms["directions"]), 0))),
        distance=float(jnp.max(jnp.where(mask, jnp.abs(layout.distances - rooms["distances"]), 0))),
        heights=float(jnp.max(jnp.abs(layout.ceiling_height - rooms["h_c"]) + jnp.abs(layout.floor_height - rooms["h_f"]))),
        corners=float(jnp.max(jnp.where(mask, corner_error, 0))),
    )


def _check(errors, metres, degrees):
    assert errors["ok"] and errors["mask"], errors
    assert errors["direction"] < degrees, errors
    assert max(errors["distance"], errors["heights"], errors["corners"]) < metres, errors


def test_manhattan_float32():
    rooms, layout = _manhattan_many(jax.random.split(jax.random.PRNGKey(0), 2 * N_ROOMS))
    assert layout.distances.shape == (2 * N_ROOMS, 8) and layout.distances.dtype == jnp.float32
    _check(_errors(rooms, layout), 5e-3, 0.2)


def test_manhattan_float64(x64):
    rooms, layout = _manhattan_many(jax.random.split(jax.random.PRNGKey(0), 2 * N_ROOMS))
    _check(_errors(rooms, layout), 1e-4, 1e-3)


def test_atlanta_float32():
    rooms, layout = _atlanta_many(jax.random.split(jax.random.PRNGKey(1), 2 * N_ROOMS))
    _check(_errors(rooms, layout), 5e-3, 1e-3)


def test_atlanta_float64(x64):
    rooms, layout = _atlanta_many(jax.random.split(jax.random.PRNGKey(1), 2 * N_ROOMS))
    _check(_errors(rooms, layout), 1e-4, 1e-6)


def test_capacity_padding_and_label_swap():
    """K = 8 or K = 32 give the same walls; swapping the labels 0 <-> 1 too."""
    room = sample_room(jax.random.PRNGKey(2), "l_shape")
    big = sample_room(jax.random.PRNGKey(2), "l_shape", capacity=32)
    a, b = jax.jit(_manhattan)(room), jax.jit(_manhattan)(big)
    np.testing.assert_allclose(a.distances, b.distances[:8], atol=1e-4)
    swapped = jax.jit(_manhattan)({**room, "labels": jnp.where(room["mask"], 1 - room["labels"], 0)})
    np.testing.assert_allclose(a.distances, swapped.distances, atol=1e-4)
    np.testing.assert_allclose(a.directions[:6], swapped.directions[:6], atol=1e-5)  # the 6 present walls


def test_unseen_wall_is_not_ok():
    room = sample_room(jax.random.PRNGKey(3), "rectangle")
    layout = jax.jit(_atlanta)({**room, "mask": room["mask"].at[5].set(True)})
    assert not bool(layout.ok)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(layout) if x.dtype != bool)


@jax.jit
def _both_solvers(ceiling_rays, floor_rays, room):
    index, mask = room["wall_index"], room["mask"]
    manhattan = ncjax.solve_manhattan_layout(ceiling_rays, floor_rays, index, mask, room["labels"])
    atlanta = ncjax.solve_atlanta_layout(ceiling_rays, floor_rays, index, mask, room["directions"])
    return jnp.concatenate([manhattan.distances, atlanta.distances])


@given(seed=st.integers(0, 2**31 - 1))
def test_column_order_invariance(seed):
    """Shuffling the columns (rays with their wall index) changes nothing."""
    room = sample_room(jax.random.PRNGKey(4), "l_shape")
    ceiling_rays, floor_rays = rays(room)
    perm = jax.random.permutation(jax.random.PRNGKey(seed), ceiling_rays.shape[0])
    reference = _both_solvers(ceiling_rays, floor_rays, room)
    shuffled = _both_solvers(ceiling_rays[perm], floor_rays[perm], {**room, "wall_index": room["wall_index"][perm]})
    np.testing.assert_allclose(reference, shuffled, atol=1e-4)


def _layout_outputs(room, solver):
    """Layout outputs as a function of the boundary ROWS (pixels -> rays -> solver)."""

    def f(rows):
        ceiling_rays, floor_rays = boundary_rays(room["cam"], rows[0], rows[1])
        layout = solver(room, ceiling_rays, floor_rays)
        corners = ncjax.layout_corners(layout.ceiling_lines, layout.mask)
        return jnp.concatenate(
            [layout.directions[:4].ravel(), layout.distances[:4], layout.ceiling_height[None], layout.floor_height[None], corners[:4].ravel()]
        )

    return f


def _manhattan_from(room, ceiling_rays, floor_rays):
    return ncjax.solve_manhattan_layout(ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["labels"])


def _atlanta_from(room, ceiling_rays, floor_rays):
    return ncjax.solve_atlanta_layout(ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"])


def test_layout_gradients(x64):
    """jacfwd = jacrev = finite differences for both solvers, axis-aligned room included."""
    axis_aligned = jnp.array([[-1.5, -1.0], [2.0, -1.0], [2.0, 1.2], [-1.5, 1.2]])
    room = room_data(axis_aligned, jnp.array(1.0), jnp.array(-1.4), jnp.array(0.5), capacity=6)
    for solver in (_manhattan_from, _atlanta_from):
        rows = jnp.stack([room["ceiling_v"], room["floor_v"]])
        check_gradients(_layout_outputs(room, solver), rows)
