"""Manhattan and Atlanta layout solvers, layout corners (paper Sections 4.2, 4.3)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_wall import (
    AXIS_ALIGNED,
    CAPACITY,
    boundary_rays,
    box_room,
    check_gradients,
    direction_error_deg,
    rays,
    sample_room,
    sample_rooms,
)

import ncjax
from ncjax.solvers.wall_fit import FitRows, refine_walls, search_scale

N_ROOMS = 40  # per world (experiments/solver_accuracy.py checks 1000)


def _manhattan(room):
    ceiling_rays, floor_rays = rays(room)
    return ncjax.solvers.solve_manhattan_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["labels"]
    )


def _atlanta(room):
    ceiling_rays, floor_rays = rays(room)
    return ncjax.solvers.solve_atlanta_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"]
    )


@jax.jit
def _manhattan_many(rooms):
    return jax.vmap(_manhattan)(rooms)


@jax.jit
def _atlanta_many(rooms):
    return jax.vmap(_atlanta)(rooms)


def _errors(rooms, layout):
    mask = rooms["mask"]
    corners = jax.vmap(ncjax.solvers.layout_corners)(layout.ceiling_lines, layout.mask)
    corner_error = jnp.linalg.norm(corners[..., :2] - rooms["corners"], axis=-1)
    return dict(
        ok=bool(jnp.all(layout.ok)),
        mask=bool(jnp.all(layout.mask == mask)),
        direction=float(jnp.max(jnp.where(mask, direction_error_deg(layout.directions, rooms["directions"]), 0))),
        distance=float(jnp.max(jnp.where(mask, jnp.abs(layout.distances - rooms["distances"]), 0))),
        heights=float(
            jnp.max(jnp.abs(layout.ceiling_height - rooms["h_c"]) + jnp.abs(layout.floor_height - rooms["h_f"]))
        ),
        corners=float(jnp.max(jnp.where(mask, corner_error, 0))),
    )


def _check(errors, metres, degrees):
    assert errors["ok"] and errors["mask"], errors
    assert errors["direction"] < degrees, errors
    assert max(errors["distance"], errors["heights"], errors["corners"]) < metres, errors


@pytest.mark.slow
def test_manhattan_float32():
    rooms = sample_rooms(0, "manhattan", N_ROOMS)
    layout = _manhattan_many(rooms)
    assert layout.distances.shape == (N_ROOMS, CAPACITY) and layout.distances.dtype == jnp.float32
    _check(_errors(rooms, layout), 5e-3, 0.2)


@pytest.mark.extended
def test_manhattan_float64(x64):
    rooms = sample_rooms(0, "manhattan", N_ROOMS)
    _check(_errors(rooms, _manhattan_many(rooms)), 1e-4, 1e-3)


@pytest.mark.slow
def test_atlanta_float32():
    rooms = sample_rooms(1, "atlanta", N_ROOMS)
    _check(_errors(rooms, _atlanta_many(rooms)), 5e-3, 1e-3)


@pytest.mark.extended
def test_atlanta_float64(x64):
    rooms = sample_rooms(1, "atlanta", N_ROOMS)
    _check(_errors(rooms, _atlanta_many(rooms)), 1e-4, 1e-6)


def _padded(room, capacity):
    """The same room with ``capacity`` wall slots."""

    def pad(x):
        return jnp.concatenate([x, jnp.zeros((capacity - x.shape[0],) + x.shape[1:], x.dtype)])

    return {**room, **{k: pad(room[k]) for k in ("mask", "labels", "directions", "distances", "corners")}}


@pytest.mark.slow
def test_capacity_padding_and_label_swap():
    """K = 12 or K = 32 give the same walls; swapping the labels 0 <-> 1 too."""
    room = sample_room(2, "manhattan")
    a, b = jax.jit(_manhattan)(room), jax.jit(_manhattan)(_padded(room, 32))
    np.testing.assert_allclose(a.distances, b.distances[:CAPACITY], atol=1e-4)
    swapped = jax.jit(_manhattan)({**room, "labels": jnp.where(room["mask"], 1 - room["labels"], 0)})
    np.testing.assert_allclose(a.distances, swapped.distances, atol=1e-4)
    present = room["mask"][:, None]
    np.testing.assert_allclose(
        jnp.where(present, a.directions, 0), jnp.where(present, swapped.directions, 0), atol=1e-5
    )


@pytest.mark.slow
def test_unseen_wall_is_not_ok():
    room = sample_room(3, "manhattan")
    n = int(room["mask"].sum())
    layout = jax.jit(_atlanta)({**room, "mask": room["mask"].at[n].set(True)})
    assert not bool(layout.ok)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(layout) if x.dtype != bool)


@jax.jit
def _both_solvers(ceiling_rays, floor_rays, room):
    index, mask = room["wall_index"], room["mask"]
    manhattan = ncjax.solvers.solve_manhattan_layout(ceiling_rays, floor_rays, index, mask, room["labels"])
    atlanta = ncjax.solvers.solve_atlanta_layout(ceiling_rays, floor_rays, index, mask, room["directions"])
    return jnp.concatenate([manhattan.distances, atlanta.distances])


@pytest.mark.slow
@given(seed=st.integers(0, 2**31 - 1))
def test_column_order_invariance(seed):
    """Shuffling the columns (rays with their wall index) changes nothing."""
    room = sample_room(4, "manhattan")
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
        corners = ncjax.solvers.layout_corners(layout.ceiling_lines, layout.mask)
        return jnp.concatenate(
            [
                layout.directions[:4].ravel(),
                layout.distances[:4],
                layout.ceiling_height[None],
                layout.floor_height[None],
                corners[:4].ravel(),
            ]
        )

    return f


def _manhattan_from(room, ceiling_rays, floor_rays):
    return ncjax.solvers.solve_manhattan_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["labels"]
    )


def _atlanta_from(room, ceiling_rays, floor_rays):
    return ncjax.solvers.solve_atlanta_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"]
    )


@pytest.mark.extended
def test_layout_gradients(x64):
    """jacfwd = jacrev = finite differences for both solvers, axis-aligned room included."""
    room = box_room(AXIS_ALIGNED, h_f=-1.4, capacity=6)
    for solver in (_manhattan_from, _atlanta_from):
        rows = jnp.stack([room["ceiling_v"], room["floor_v"]])
        check_gradients(_layout_outputs(room, solver), rows)


@pytest.mark.slow
def test_layout_corners_of_parallel_walls_are_invalid_not_nan():
    """Consecutive parallel walls (and a lone wall) have no corner: zero, flagged invalid, finite gradients."""
    directions = jnp.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [1.0, 0.0]])
    distances = jnp.array([-1.0, -2.0, -1.5, -1.0, -1.0])
    lines = ncjax.geometry.horizontal_wall_line(directions, distances, jnp.full(5, 1.2))
    mask = jnp.array([True, True, True, True, False])
    corners, valid = ncjax.solvers.layout_corners(lines, mask, return_valid=True)
    np.testing.assert_array_equal(valid, [False, False, True, True, False])  # 3 -> 0 and 0 -> 1 are parallel
    np.testing.assert_allclose(corners[2], [1.5, -2.0, 1.2], atol=1e-6)  # wall 1 (y = -2) meets wall 2 (x = 1.5)
    assert bool(jnp.all(corners[~valid] == 0))
    grad = jax.grad(lambda x: jnp.sum(ncjax.solvers.layout_corners(x, mask)))(lines)
    assert bool(jnp.all(jnp.isfinite(grad)))
    lone, lone_valid = ncjax.solvers.layout_corners(lines, jnp.arange(5) == 2, return_valid=True)
    assert not bool(jnp.any(lone_valid)) and bool(jnp.all(lone == 0))


def _stacked_rows(room, ceiling_rays, floor_rays):
    """The Atlanta arguments ``(rays, base_directions, row_wall, is_floor)`` of the :mod:`ncjax.solvers.wall_fit`
    stages (ceiling rows, then floor rows) and the true ``(h_c, h_f, d_1..d_K)``."""
    column_wall = jnp.where(
        room["mask"][jnp.maximum(room["wall_index"], 0)] & (room["wall_index"] >= 0), room["wall_index"], -1
    )
    directions = room["directions"][jnp.maximum(room["wall_index"], 0)]
    is_floor = jnp.arange(2 * ceiling_rays.shape[0]) >= ceiling_rays.shape[0]
    arguments = (
        jnp.concatenate([ceiling_rays, floor_rays]),
        jnp.concatenate([directions, directions]),
        jnp.concatenate([column_wall, column_wall]),
        is_floor,
    )
    truth = jnp.concatenate([jnp.stack([room["h_c"], room["h_f"]]), jnp.where(room["mask"], room["distances"], 0.0)])
    return arguments, truth


@pytest.mark.slow
def test_scale_search_recovers_a_scale_the_linear_solve_lost():
    """A linear solution whose ``x_0`` (the metric scale) came out with the wrong sign is
    re-scaled by the likelihood: the room's shape survives, the refinement recovers the room."""
    room = sample_room(3, "atlanta")
    arguments, truth = _stacked_rows(room, *rays(room))
    depths = jnp.asarray(ncjax.solvers.layout.FLOOR_DEPTHS, truth.dtype)
    corrupted = 0.37 * jnp.concatenate([jnp.array([-1.0]), truth])  # right shape, x_0 of the wrong sign
    start, ok = search_scale(corrupted, FitRows(*arguments), depths)
    assert ok
    assert start[2] < 0 and 0.85 < float(start[2] / room["h_f"]) < 1.18  # the nearest of the grid's depths
    refined = refine_walls(start, FitRows(*arguments), refine_yaw=False, steps=8)
    np.testing.assert_allclose(refined[1:], truth, atol=1e-3)
    exact, _ = search_scale(jnp.concatenate([jnp.ones(1), truth]), FitRows(*arguments), depths)
    np.testing.assert_allclose(exact[1:], truth, rtol=1e-6, atol=1e-6)  # an exact linear solution is kept


@pytest.mark.slow
def test_atlanta_boundary_weights_follow_the_cleaner_boundary():
    """Exact ceiling rows, floor rows with 2 px noise: weighting the floor down recovers the ceiling's
    height and the walls far better than weighting both alike; exact rows are exact with any weights."""
    room = sample_room(5, "atlanta")
    noise = 2.0 * jax.random.normal(jax.random.key(0), (8,) + room["floor_v"].shape)

    @jax.jit
    def solve(floor_noise, weights):
        ceiling_rays, floor_rays = boundary_rays(room["cam"], room["ceiling_v"], room["floor_v"] + floor_noise)
        layout = ncjax.solvers.solve_atlanta_layout(
            ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"], boundary_weights=weights
        )
        distance_error = jnp.max(jnp.where(room["mask"], jnp.abs(layout.distances - room["distances"]), 0.0))
        return jnp.abs(layout.ceiling_height - room["h_c"]), distance_error, jnp.abs(layout.floor_height - room["h_f"])

    down = jnp.array([1.0, 0.01])
    for error in solve(jnp.zeros_like(room["floor_v"]), down):
        assert float(error) < 5e-3
    alike = jax.vmap(solve, in_axes=(0, None))(noise, jnp.ones(2))
    weighted = jax.vmap(solve, in_axes=(0, None))(noise, down)
    for even, down_weighted in zip(alike, weighted, strict=True):
        assert float(jnp.median(down_weighted)) < 0.3 * float(jnp.median(even)), (down_weighted, even)


def _weighted_problem():
    """A noisy Atlanta room's stacked rows for the :mod:`ncjax.solvers.wall_fit` stages, with random row weights."""
    room = sample_room(5, "atlanta")
    noise = jax.random.normal(jax.random.key(1), (2,) + room["floor_v"].shape)
    arguments, truth = _stacked_rows(
        room, *boundary_rays(room["cam"], room["ceiling_v"] + noise[0], room["floor_v"] + noise[1])
    )
    weights = jax.random.uniform(jax.random.key(2), arguments[2].shape, minval=0.05, maxval=1.0)
    return arguments, jnp.concatenate([jnp.zeros(1), truth]), weights


@pytest.mark.slow
def test_weighted_gauss_newton_step_is_the_weighted_least_squares_step(x64):
    """The structured step equals the least-squares step of the weighted residuals' dense Jacobian."""
    (rays_, base, row_wall, is_floor), truth, weights = _weighted_problem()
    start = truth * jnp.concatenate([jnp.ones(1), jnp.full(2, 1.03), jnp.full(truth.shape[0] - 3, 0.97)])
    geometry = ncjax.solvers.wall_fit._used_geometry(rays_, row_wall)
    cost, delta = ncjax.solvers.wall_fit.gauss_newton_step(
        start, geometry, FitRows(rays_, base, row_wall, is_floor, weights), False
    )

    def residuals(p):
        return ncjax.solvers.wall_fit.residuals_of(p, geometry, FitRows(rays_, base, row_wall, is_floor, weights))

    jacobian = jax.jacfwd(residuals)(start)
    # the yaw (not refined: Atlanta) and absent walls' distances stay
    free = np.asarray(jnp.any(jacobian != 0, axis=0)) & (np.arange(start.shape[0]) > 0)
    assert free[1] and free[2] and not free.all()
    expected = np.linalg.lstsq(np.asarray(jacobian)[:, free], -np.asarray(residuals(start)), rcond=None)[0]
    np.testing.assert_allclose(cost, np.sum(np.asarray(residuals(start)) ** 2), rtol=1e-10)
    np.testing.assert_allclose(np.asarray(delta)[free], expected, rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(np.asarray(delta)[~free], 0.0)


@pytest.mark.slow
def test_equal_row_weights_change_nothing():
    """Every row weighted alike (here 0.3) gives the stages' unweighted results: only ratios of weights count."""
    arguments, truth, _ = _weighted_problem()
    rays_, base, row_wall, is_floor = arguments
    equal = jnp.full(row_wall.shape, 0.3)
    shared, distance = (
        jax.random.normal(jax.random.key(3), (row_wall.shape[0], 3)),
        jax.random.normal(jax.random.key(4), row_wall.shape),
    )
    plain, weighted = (
        ncjax.solvers.wall_fit.linear_walls(shared, distance, row_wall, CAPACITY, w) for w in (None, equal)
    )
    sign = jnp.sign(jnp.dot(plain[0], weighted[0]))
    np.testing.assert_allclose(sign * weighted[0], plain[0], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(sign * weighted[1], plain[1], rtol=1e-4, atol=1e-5)
    x, d = ncjax.solvers.wall_fit.linear_walls(shared, distance, row_wall, CAPACITY, jnp.where(is_floor, 1.0, 0.1))
    cosine = jnp.abs(jnp.dot(x, plain[0])) / (jnp.linalg.norm(x) * jnp.linalg.norm(plain[0]))
    assert float(cosine) < 0.9999  # unequal weights do change the null vector
    depths = jnp.asarray(ncjax.solvers.layout.FLOOR_DEPTHS, truth.dtype)
    vector = truth.at[0].set(0.8)  # the room at 1.25 times its scale
    start, _ = search_scale(vector, FitRows(*arguments), depths)
    np.testing.assert_array_equal(search_scale(vector, FitRows(*arguments, equal), depths)[0], start)
    np.testing.assert_allclose(
        refine_walls(start, FitRows(*arguments, equal), refine_yaw=False),
        refine_walls(start, FitRows(*arguments), refine_yaw=False),
        rtol=1e-4,
        atol=1e-5,
    )


@pytest.mark.slow
def test_boundary_weights_need_the_refined_solver():
    room = sample_room(5, "atlanta")
    ceiling_rays, floor_rays = rays(room)
    with pytest.raises(ValueError, match="refined"):
        ncjax.solvers.solve_atlanta_layout(
            ceiling_rays,
            floor_rays,
            room["wall_index"],
            room["mask"],
            room["directions"],
            method="paper",
            boundary_weights=jnp.ones(2),
        )
