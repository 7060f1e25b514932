"""Single-wall solver, minimal solver, horizontal-line baseline (paper Section 4.1, 5.3).

Rooms come from the public generator (``ncjax.synth.random_room`` without
occlusion, Manhattan at any yaw and Atlanta) with exact labels
(``ncjax.synth.room_labels``); the helpers here are shared with
``test_layout_solvers.py``.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import ncjax
import ncjax.geometry.linalg
import ncjax.solvers.wall
import ncjax.solvers.wall_at_heights

WIDTH, HEIGHT = 256, 128
CAPACITY = 12
MIN_COLUMNS = 3  # per wall: the over-determined case of the single-wall solver
CONFIGS = {
    world: ncjax.RoomConfig(
        world=world, max_walls=6, capacity=CAPACITY, occlusion="none", min_step=0.5, rc_range=(0.1, 1.0), room_tries=2
    )
    for world in ("manhattan", "atlanta")
}


def boundary_rays(cam, ceiling_v, floor_v):
    """Rays of the per-column boundary rows (column ``u`` at its centre)."""
    columns = jnp.arange(cam.width, dtype=ceiling_v.dtype)
    return ncjax.geometry.pixel_to_ray(cam, columns, ceiling_v), ncjax.geometry.pixel_to_ray(cam, columns, floor_v)


def room_data(room):
    """A room as a dict of the solver inputs and the truth (walls in the room's order)."""
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=room.rc)
    labels = ncjax.synth.room_labels(room, cam)
    directions, distances, _, _ = ncjax.synth.room_walls(room)
    capacity = room.mask.shape[0]
    columns = jnp.sum(labels.wall_index[:, None] == jnp.arange(capacity), 0)
    usable = labels.ok & ~jnp.any(labels.corner_is_occlusion) & jnp.all(~room.mask | (columns >= MIN_COLUMNS))
    return dict(
        cam=cam,
        ceiling_v=labels.ceiling_v,
        floor_v=labels.floor_v,
        wall_index=labels.wall_index,
        mask=room.mask,
        directions=directions,
        distances=jnp.where(room.mask, distances, 0.0),
        labels=jnp.where(room.mask & (jnp.abs(directions @ directions[0]) < 0.5), 1, 0),
        corners=room.corners,
        h_c=room.ceiling_height,
        h_f=room.floor_height,
        usable=usable,
    )


@functools.partial(jax.jit, static_argnames="world")
def _candidate_rooms(keys, world):
    return jax.vmap(lambda k: room_data(ncjax.synth.random_room(k, CONFIGS[world])))(keys)


def sample_rooms(seed, world, n):
    """``n`` usable random rooms (batched dict): no occlusion, every wall seen by >= 3 columns."""
    return _sample_rooms(seed, world, n, bool(jax.config.jax_enable_x64))


@functools.cache
def _sample_rooms(seed, world, n, x64):
    chunk = 64  # one compilation per world and dtype
    keys = jax.random.split(jax.random.PRNGKey(seed), chunk * (1 + 2 * n // chunk)).reshape(-1, chunk, 2)
    rooms = [_candidate_rooms(k, world) for k in keys]
    rooms = jax.tree.map(lambda *x: jnp.concatenate(x), *rooms)
    index = np.nonzero(np.asarray(rooms["usable"]))[0][:n]
    assert len(index) == n, f"only {len(index)} usable rooms"
    return jax.tree.map(lambda x: x[index], rooms)


def sample_room(seed, world):
    return jax.tree.map(lambda x: x[0], sample_rooms(seed, world, 1))


def box_room(corners, h_c=1.0, h_f=-1.5, rc=0.5, capacity=CAPACITY):
    """An explicit counter-clockwise room around the camera (e.g. axis-aligned)."""
    corners = jnp.asarray(corners, float)
    n = corners.shape[0]
    room = ncjax.synth.Room(
        corners=jnp.zeros((capacity, 2), corners.dtype).at[:n].set(corners),
        mask=jnp.arange(capacity) < n,
        ceiling_height=jnp.asarray(h_c, corners.dtype),
        floor_height=jnp.asarray(h_f, corners.dtype),
        rc=jnp.asarray(rc, corners.dtype),
        camera_position=jnp.array([0.0, 0.0, -h_f], corners.dtype),
        is_atlanta=jnp.array(False),
        status=jnp.array(0, jnp.int32),
    )
    return room_data(room)


def rays(room):
    return boundary_rays(room["cam"], room["ceiling_v"], room["floor_v"])


def direction_error_deg(a, b):
    """Angle between unit 2D directions, degrees (signs must agree)."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.degrees(jnp.arctan2(jnp.abs(cross), jnp.sum(a * b, -1)))


def _line_of(direction, distance, height):
    return ncjax.geometry.horizontal_wall_line(direction, distance, height)


@pytest.mark.slow
def test_rows_are_side():
    """eqs. manx/many (with the corrected sign) equal side(ray, wall line)."""
    key = jax.random.PRNGKey(0)
    k1, k2, k3, k4 = jax.random.split(key, 4)
    angle = jax.random.uniform(k1, (50,), maxval=7.0)
    u = jnp.stack([jnp.cos(angle), jnp.sin(angle)], -1)
    d, h_c, h_f = jax.random.normal(k2, (3, 50))
    ray = ncjax.geometry.angles_to_ray(0.4, *jax.random.uniform(k3, (2, 50), minval=-1.5, maxval=1.5))
    ceiling, floor = ncjax.solvers.wall.wall_rows(ray, ray)
    unknown = jnp.concatenate([u, h_c[:, None] * u, h_f[:, None] * u, d[:, None]], -1)
    np.testing.assert_allclose(jnp.sum(ceiling * unknown, -1), ncjax.geometry.side(ray, _line_of(u, d, h_c)), atol=1e-5)
    np.testing.assert_allclose(jnp.sum(floor * unknown, -1), ncjax.geometry.side(ray, _line_of(u, d, h_f)), atol=1e-5)


def test_parallel_quadratic_is_cross_product():
    a0, a1, b0, b1 = jax.random.normal(jax.random.PRNGKey(1), (4, 2))
    p, r, t = ncjax.solvers.wall.parallel_quadratic(a0, a1, b0, b1)
    for alpha, beta in [(0.3, -1.2), (1.0, 0.5)]:
        a, b = alpha * a0 + beta * a1, alpha * b0 + beta * b1
        np.testing.assert_allclose(p * alpha**2 + r * alpha * beta + t * beta**2, a[0] * b[1] - a[1] * b[0], rtol=1e-5)
    for theta in ncjax.solvers.wall.quadratic_root_angles(jnp.array([p, r, t])):
        alpha, beta = jnp.cos(theta), jnp.sin(theta)
        np.testing.assert_allclose(p * alpha**2 + r * alpha * beta + t * beta**2, 0.0, atol=1e-5)


def _all_walls(room, method):
    ceiling_rays, floor_rays = rays(room)
    masks = room["wall_index"][None, :] == jnp.arange(CAPACITY)[:, None]
    return jax.vmap(lambda m: ncjax.solvers.solve_wall(ceiling_rays, floor_rays, m, m, method=method))(masks)


@functools.partial(jax.jit, static_argnames="method")
def _solve_many(rooms, method="paper"):
    return jax.vmap(lambda r: _all_walls(r, method))(rooms)


WALL_COLUMNS = 24  # single walls seen by fewer columns (< 34 degrees here) are too ill-conditioned for float32


def _errors(rooms, walls):
    columns = jnp.sum(rooms["wall_index"][:, :, None] == jnp.arange(CAPACITY), 1)
    mask = rooms["mask"] & (columns >= WALL_COLUMNS)

    def worst(x):
        return float(jnp.max(jnp.where(mask, x, 0.0)))

    return dict(
        direction=worst(direction_error_deg(walls.direction, rooms["directions"])),
        distance=worst(jnp.abs(walls.distance - rooms["distances"])),
        ceiling=worst(jnp.abs(walls.ceiling_height - rooms["h_c"][:, None])),
        floor=worst(jnp.abs(walls.floor_height - rooms["h_f"][:, None])),
        ok=bool(jnp.all(walls.ok | ~mask)),
    )


N_ROOMS = 24  # Atlanta rooms, 5-10 walls each


@pytest.mark.slow
def test_exact_walls_float32():
    rooms = sample_rooms(2, "atlanta", N_ROOMS)
    walls = _solve_many(rooms)
    assert walls.distance.dtype == jnp.float32 and walls.direction.shape == (N_ROOMS, CAPACITY, 2)
    errors = _errors(rooms, walls)
    assert errors["ok"]
    assert errors["direction"] < 0.2
    assert max(errors["distance"], errors["ceiling"], errors["floor"]) < 5e-3, errors


@pytest.mark.slow
@pytest.mark.parametrize("method", ["paper", "refined", "null_vector"])
def test_exact_walls_float64(x64, method):
    rooms = sample_rooms(2, "atlanta", N_ROOMS)
    walls = _solve_many(rooms, method)
    assert walls.distance.dtype == jnp.float64
    errors = _errors(rooms, walls)
    assert errors["ok"]
    assert max(errors["distance"], errors["ceiling"], errors["floor"]) < 1e-4, errors
    # canonical orientation: the wall runs counter-clockwise, camera on its left
    assert bool(jnp.all(jnp.where(rooms["mask"], walls.distance, -1.0) < 0))


@pytest.mark.slow
def test_unknown_method_is_a_value_error():
    room = sample_room(3, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    mask = room["wall_index"] == 0
    with pytest.raises(ValueError, match="method"):
        ncjax.solvers.solve_wall(ceiling_rays, floor_rays, mask, mask, method="quadratic")


@pytest.mark.slow
def test_failure_is_a_value():
    room = sample_room(4, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    none = jnp.zeros(ceiling_rays.shape[0], bool)
    wall = _solve_jit(ceiling_rays, floor_rays, none, none)
    assert not bool(wall.ok)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(wall) if x.dtype != bool)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["one ray repeated", "one column", "two columns", "NaN rays"])
def test_degenerate_rays_fix_no_wall(case):
    """Inputs that do not determine a wall give ok=False and finite fields, never a confident wall."""
    room = sample_room(4, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    mask = room["wall_index"] == 0
    first, second = np.flatnonzero(mask)[:2]
    if case == "one ray repeated":  # every used row the wall's first ray
        ceiling_rays, floor_rays = (jnp.broadcast_to(r[first], r.shape) for r in (ceiling_rays, floor_rays))
    elif case == "one column":  # one column's rays, many times: the same rows as above, by another road
        mask = jnp.zeros_like(mask).at[first].set(True)
        ceiling_rays, floor_rays = (jnp.where(mask[:, None], r, r[first]) for r in (ceiling_rays, floor_rays))
        mask = jnp.ones_like(mask)
    elif case == "two columns":
        keep = (jnp.arange(mask.shape[0]) % 2 == 0) & mask
        ceiling_rays, floor_rays = (jnp.where(keep[:, None], r[first], r[second]) for r in (ceiling_rays, floor_rays))
    else:
        ceiling_rays = jnp.where(mask[:, None], jnp.nan, ceiling_rays)
    wall = _solve_jit(ceiling_rays, floor_rays, mask, mask)
    assert not bool(wall.ok), case
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree.leaves(wall) if x.dtype != bool)


def test_distinct_azimuths_counts_columns_not_rows():
    room = sample_room(4, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    mask = room["wall_index"] == 0
    columns = int(np.sum(mask))
    assert int(ncjax.solvers.wall.distinct_azimuths(ceiling_rays, mask)) == columns
    doubled = jnp.concatenate([ceiling_rays, ceiling_rays])
    assert int(ncjax.solvers.wall.distinct_azimuths(doubled, jnp.concatenate([mask, mask]))) == columns
    assert int(ncjax.solvers.wall.distinct_azimuths(ceiling_rays, jnp.zeros_like(mask))) == 0


@pytest.mark.slow
@given(seed=st.integers(0, 2**31 - 1))
def test_order_and_masked_rows(seed):
    """Permuting rays changes nothing; masked-out rows (even NaN) have no effect."""
    room = sample_room(5, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    mask = room["wall_index"] == 1
    reference = _solve_jit(ceiling_rays, floor_rays, mask, mask)
    perm = jax.random.permutation(jax.random.PRNGKey(seed), ceiling_rays.shape[0])
    garbage = jnp.where(mask[:, None], ceiling_rays, jnp.nan)
    shuffled = _solve_jit(garbage[perm], floor_rays[perm], mask[perm], mask[perm])
    for a, b in zip(jax.tree.leaves(reference), jax.tree.leaves(shuffled), strict=True):
        np.testing.assert_allclose(a, b, atol=2e-4)


_solve_jit = jax.jit(ncjax.solvers.solve_wall)


def _wall_outputs(room, wall_id, method="paper"):
    """Solver outputs as a function of the boundary ROWS (pixels -> rays -> solver)."""
    mask = room["wall_index"] == wall_id

    def f(rows):
        ceiling_rays, floor_rays = _wall_rays(room, rows)
        wall = ncjax.solvers.solve_wall(ceiling_rays, floor_rays, mask, mask, method=method)
        return jnp.concatenate(
            [wall.direction, wall.distance[None], wall.ceiling_height[None], wall.floor_height[None]]
        )

    return f


def _wall_rays(room, rows):
    return boundary_rays(room["cam"], rows[0], rows[1])


AXIS_ALIGNED = [[-1.5, -1.0], [2.0, -1.0], [2.0, 1.2], [-1.5, 1.2]]


def check_gradients(f, x, eps=1e-6, rtol=1e-3, directions=6):
    """Forward (jvp) = central finite differences along random directions, reverse (vjp)
    consistent with forward (``<w, J v> = <J^T w, v>``), never NaN (float64).

    Returns ``J^T w`` for the random cotangents ``w`` (directions, *x.shape).
    """
    key_v, key_w = jax.random.split(jax.random.PRNGKey(0))
    v = jax.random.normal(key_v, (directions,) + x.shape, x.dtype)
    forward = jax.jit(jax.vmap(lambda d: jax.jvp(f, (x,), (d,))[1]))(v)
    numeric = jax.jit(jax.vmap(lambda d: (f(x + eps * d) - f(x - eps * d)) / (2 * eps)))(v)
    w = jax.random.normal(key_w, forward.shape, x.dtype)
    reverse = jax.jit(jax.vmap(lambda c: jax.vjp(f, x)[1](c)[0]))(w)
    assert bool(jnp.all(jnp.isfinite(forward))) and bool(jnp.all(jnp.isfinite(reverse)))
    scale = float(jnp.max(jnp.abs(numeric)))
    np.testing.assert_allclose(forward, numeric, atol=rtol * scale)
    pairing_forward = jnp.sum((w * forward).reshape(directions, -1), -1)
    pairing_reverse = jnp.sum((reverse * v).reshape(directions, -1), -1)
    np.testing.assert_allclose(
        pairing_forward, pairing_reverse, rtol=1e-8, atol=1e-10 * float(jnp.max(jnp.abs(pairing_forward)))
    )
    return reverse


@pytest.mark.extended
@pytest.mark.parametrize(("axis_aligned", "method"), [(True, "paper"), (False, "paper"), (True, "refined")])
def test_wall_gradients(x64, axis_aligned, method):
    room = box_room(AXIS_ALIGNED) if axis_aligned else sample_room(6, "manhattan")
    rows = jnp.stack([room["ceiling_v"], room["floor_v"]])
    reverse = check_gradients(_wall_outputs(room, 0, method), rows)
    # rows of other walls do not matter
    assert float(jnp.max(jnp.abs(reverse[..., room["wall_index"] != 0]))) == 0.0


@pytest.mark.slow
def test_null_space_gradient_with_repeated_singular_values(x64):
    """Repeated singular values (outside the null space) give finite, correct derivatives."""
    a = jnp.concatenate([jnp.eye(4)[:, :3] * 2.0, jnp.zeros((4, 1))], 1)  # singular values 2, 2, 2, 0
    a = jnp.concatenate([a, jnp.ones((1, 4)) * 0.0])

    def projector(m):
        v = ncjax.geometry.null_space(m, 1)
        return v @ v.T

    check_gradients(projector, a)

    def naive_projector(m):  # JAX's own SVD derivative: NaN here (why the custom JVP exists)
        v = jnp.linalg.svd(m, full_matrices=False)[2][-1:].T
        return v @ v.T

    assert bool(jnp.any(jnp.isnan(jax.jacrev(naive_projector)(a))))


_sorted_svd = jax.jit(jax.vmap(ncjax.geometry.linalg._sorted_svd))


@pytest.mark.slow
@given(
    seed=st.integers(0, 2**31 - 1), kind=st.sampled_from(["random", "rank_deficient", "repeated_column", "zero_column"])
)
def test_sorted_svd_matches_numpy(seed, kind):
    """Gram-Schmidt + one-sided Jacobi: numpy's singular values, orthonormal vectors, the same null space."""
    with jax.enable_x64(True):
        _check_sorted_svd(seed, kind)


def _check_sorted_svd(seed, kind):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(4, 12, 6)) * rng.uniform(0.1, 10.0, size=(4, 1, 6))
    if kind == "rank_deficient":
        a[..., 5] = a[..., :5] @ rng.normal(size=5)
    elif kind == "repeated_column":
        a[..., 3] = a[..., 1]
    elif kind == "zero_column":
        a[..., 2] = 0.0
    squared, vectors = _sorted_svd(jnp.asarray(a))
    _, s, vt = np.linalg.svd(a, full_matrices=False)
    scale = s[:, :1] ** 2
    np.testing.assert_allclose(np.asarray(squared) / scale, (s[:, ::-1] ** 2) / scale, atol=1e-12)
    np.testing.assert_allclose(
        np.einsum("bij,bik->bjk", vectors, vectors), np.broadcast_to(np.eye(6), (4, 6, 6)), atol=1e-12
    )
    smallest, reference = np.asarray(vectors)[:, :, 0], vt[:, -1, :]
    if kind != "random":  # an exact null vector: the same line
        np.testing.assert_allclose(np.abs(np.einsum("bi,bi->b", smallest, reference)), 1.0, atol=1e-10)


@pytest.mark.slow
def test_minimal_solver(x64):
    room = sample_room(7, "atlanta")
    ceiling_rays, floor_rays = rays(room)
    index = jnp.nonzero(room["wall_index"] == 2, size=4)[0]
    walls, valid = jax.jit(ncjax.solvers.solve_wall_minimal)(
        ceiling_rays[index[jnp.array([0, 3])]], floor_rays[index[jnp.array([1, 2])]]
    )
    assert walls.distance.shape == (3,) and valid.shape == (3,)
    assert bool(jnp.any(valid))
    error = jnp.where(
        valid, jnp.abs(walls.distance - room["distances"][2]) + jnp.abs(walls.ceiling_height - room["h_c"]), jnp.inf
    )
    assert float(jnp.min(error)) < 1e-6
    best = int(jnp.argmin(error))
    assert float(direction_error_deg(walls.direction[best], room["directions"][2])) < 1e-4


@pytest.mark.slow
def test_horizontal_line_baseline():
    room = sample_room(8, "manhattan")
    ceiling_rays, floor_rays = rays(room)
    for wall_id in range(int(room["mask"].sum())):
        mask = room["wall_index"] == wall_id
        if int(mask.sum()) < WALL_COLUMNS:
            continue
        for rays_, height in ((ceiling_rays, room["h_c"]), (floor_rays, room["h_f"])):
            line = jax.jit(ncjax.solvers.solve_horizontal_line)(rays_, mask)
            assert bool(line.ok)
            assert float(direction_error_deg(line.direction, room["directions"][wall_id])) < 0.05
            np.testing.assert_allclose(line.distance, room["distances"][wall_id], atol=2e-3)
            np.testing.assert_allclose(line.height, height, atol=2e-3)


_segment_null_spaces = jax.jit(ncjax.geometry.linalg.segment_scaled_null_spaces, static_argnums=(2, 3))
_masked_null_spaces = jax.jit(
    jax.vmap(
        lambda a, segments, s: ncjax.geometry.linalg.scaled_null_space(jnp.where((segments == s)[:, None], a, 0.0), 2),
        (None, None, 0),
    )
)


@pytest.mark.slow
@given(seed=st.integers(0, 2**31 - 1))
def test_segment_null_spaces_match_masked_ones(seed):
    """One pass over the rows gives every segment's scaled null space (empty and NaN-free segments included)."""
    with jax.enable_x64(True):
        rng = np.random.default_rng(seed)
        # >= 4 rows of 5 unknowns per segment: a unique 2-dimensional null space; -1 rows belong to none, 5 is empty
        segments = rng.permutation(np.repeat(np.arange(-1, 5), 4 + rng.multinomial(30, np.full(6, 1 / 6))))  # 54 rows
        a = rng.normal(size=(len(segments), 5)) * rng.uniform(0.1, 10.0, size=(len(segments), 1))
        a[segments == -1] = np.nan
        got = np.asarray(_segment_null_spaces(jnp.asarray(a), jnp.asarray(segments), 6, 2))
        want = np.asarray(_masked_null_spaces(jnp.asarray(np.nan_to_num(a)), jnp.asarray(segments), jnp.arange(6)))
        assert np.all(np.isfinite(got))
        for s in range(6):  # the same span (each basis is orthonormal in its equilibrated space)

            def projector(b):
                return b @ np.linalg.pinv(b)

            np.testing.assert_allclose(projector(got[s]), projector(want[s]), atol=1e-8)


@pytest.mark.slow
def test_batched_baseline_matches_one_line_at_a_time():
    room = sample_room(8, "atlanta")
    ceiling_rays, _ = rays(room)
    index = jnp.where(jnp.arange(WIDTH) % 17 == 0, -1, room["wall_index"])  # some columns of no line
    batched = jax.jit(ncjax.solvers.solve_horizontal_lines, static_argnums=2)(ceiling_rays, index, CAPACITY)
    masks = index[None, :] == jnp.arange(CAPACITY)[:, None]
    single = jax.jit(jax.vmap(ncjax.solvers.solve_horizontal_line, (None, 0)))(ceiling_rays, masks)
    assert batched.direction.shape == (CAPACITY, 2)
    np.testing.assert_array_equal(batched.ok, single.ok)
    ok = np.asarray(single.ok)
    assert ok.sum() >= 5  # lines seen by >= 4 columns
    for field in ("direction", "distance", "height"):
        np.testing.assert_allclose(
            np.asarray(getattr(batched, field))[ok], np.asarray(getattr(single, field))[ok], rtol=2e-4, atol=1e-4
        )  # float32, sums in another order


@pytest.mark.extended
def test_batched_baseline_gradient(x64):
    """Derivatives of the batched fit match central differences (rows of every line perturbed at once)."""
    room = sample_room(9, "manhattan")

    def distances(ceiling_v):
        columns = jnp.arange(WIDTH, dtype=ceiling_v.dtype)
        rays_ = ncjax.geometry.pixel_to_ray(room["cam"], columns, ceiling_v)
        lines = ncjax.solvers.solve_horizontal_lines(rays_, room["wall_index"], CAPACITY)
        return jnp.where(room["mask"], lines.distance, 0.0)

    tangent = jnp.asarray(np.random.default_rng(0).normal(size=WIDTH))
    _, derivative = jax.jvp(distances, (room["ceiling_v"],), (tangent,))
    step = 1e-4
    central = (distances(room["ceiling_v"] + step * tangent) - distances(room["ceiling_v"] - step * tangent)) / (
        2 * step
    )
    assert np.all(np.isfinite(np.asarray(derivative)))
    np.testing.assert_allclose(derivative, central, rtol=1e-3, atol=1e-6)


def _walls_at_heights(room):
    ceiling_rays, floor_rays = rays(room)
    masks = room["wall_index"][None, :] == jnp.arange(CAPACITY)[:, None]
    return jax.vmap(
        lambda m: ncjax.solvers.wall_at_heights.solve_wall_at_heights(
            ceiling_rays, floor_rays, m, m, room["h_c"], room["h_f"]
        )
    )(masks)


@pytest.mark.parametrize("rc", [0.0, 0.3])
def test_walls_at_known_heights_are_exact(rc):
    """Exact rows of a box room (central and non-central) at the true heights give the true walls."""
    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=rc)
    walls = _walls_at_heights(room)
    mask = room["mask"]
    assert bool(jnp.all(walls.ok[mask]))
    assert float(jnp.max(direction_error_deg(walls.direction, room["directions"])[mask])) < 0.01
    np.testing.assert_allclose(walls.distance[mask], room["distances"][mask], atol=2e-4)


def test_boundary_points_at_a_height_lie_on_their_rays():
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=0.4)
    columns = jnp.arange(0.0, WIDTH, 7.0)
    ray = ncjax.geometry.pixel_to_ray(cam, columns, jnp.full_like(columns, 20.0))  # above the horizon
    points, ahead = ncjax.solvers.wall_at_heights.boundary_points_at(ray, jnp.asarray(1.3))
    assert bool(jnp.all(ahead))
    on_ray = ncjax.geometry.side(
        ray,
        ncjax.geometry.line_from_point_direction(jnp.pad(points, ((0, 0), (0, 1)), constant_values=1.3), ray[:, :3]),
    )
    np.testing.assert_allclose(on_ray, 0.0, atol=1e-5)
    # rays going up never reach the floor
    _, behind = ncjax.solvers.wall_at_heights.boundary_points_at(ray, jnp.asarray(-1.3))
    assert not bool(jnp.any(behind))


@pytest.mark.parametrize("rc", [0.0, 0.4])
def test_boundary_ranges_are_the_boundary_points_range_from_the_axis_and_nan_where_there_is_none(rc):
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=rc)
    rng = np.random.default_rng(5)
    _, horizon = ncjax.geometry.angles_to_pixel(cam, jnp.asarray(0.3), jnp.asarray(0.0))
    rows = jnp.asarray(np.concatenate([rng.uniform(0, HEIGHT, WIDTH - 2), [float(horizon), np.nan]]), jnp.float32)
    columns = np.arange(WIDTH)
    _, elevation = ncjax.geometry.pixel_to_angles(cam, jnp.asarray(columns, jnp.float32), rows)
    for height in (1.2, -1.5):
        _, ranges = ncjax.geometry.reprojection.boundary_ranges(cam, rows, height)
        slope = np.tan(np.asarray(elevation, np.float64))
        with np.errstate(divide="ignore", invalid="ignore"):
            expected = np.where(slope * height > 0, rc + height / slope, np.nan)
        np.testing.assert_allclose(np.asarray(ranges), expected, rtol=1e-4)
        assert np.isnan(np.asarray(ranges)[-2:]).all()  # the horizon's row and a missing one: no point
        gradient = jax.grad(lambda r, h=height: jnp.nansum(ncjax.geometry.reprojection.boundary_ranges(cam, r, h)[1]))(
            rows
        )
        assert np.isfinite(np.asarray(gradient)[:-1]).all()


def test_wall_at_heights_is_the_weighted_principal_axis():
    """Noisy points: the fit is numpy's weighted total least squares line (eigenvector of the weighted scatter)."""
    rng = np.random.default_rng(3)
    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=0.0)
    ceiling_v = room["ceiling_v"] + jnp.asarray(rng.normal(0, 1.0, WIDTH), room["ceiling_v"].dtype)
    ceiling_rays, floor_rays = boundary_rays(room["cam"], ceiling_v, room["floor_v"])
    mask = room["wall_index"] == 1
    wall = ncjax.solvers.wall_at_heights.solve_wall_at_heights(
        ceiling_rays, floor_rays, mask, mask, room["h_c"], room["h_f"]
    )
    points = np.concatenate(
        [
            np.asarray(ncjax.solvers.wall_at_heights.boundary_points_at(r, h)[0])[np.asarray(mask)]
            for r, h in ((ceiling_rays, room["h_c"]), (floor_rays, room["h_f"]))
        ]
    )
    heights = np.repeat([float(room["h_c"]), float(room["h_f"])], int(mask.sum()))
    weight = (np.abs(heights) / (np.sum(points**2, 1) + heights**2)) ** 2
    mean = weight @ points / weight.sum()
    scatter = (weight[:, None] * (points - mean)).T @ (points - mean)
    axis = np.linalg.eigh(scatter)[1][:, -1]
    assert (
        float(direction_error_deg(jnp.asarray(axis), wall.direction)) < 1e-3
        or float(direction_error_deg(jnp.asarray(-axis), wall.direction)) < 1e-3
    )
    np.testing.assert_allclose(abs(float(wall.distance)), abs(axis[0] * mean[1] - axis[1] * mean[0]), rtol=1e-4)


def test_a_wall_at_heights_needs_two_columns_and_a_camera_between_them():
    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=0.0)
    ceiling_rays, floor_rays = rays(room)
    one, two = jnp.arange(WIDTH) == 10, jnp.isin(jnp.arange(WIDTH), jnp.array([10, 20]))
    none = jnp.zeros(WIDTH, bool)
    solve = ncjax.solvers.wall_at_heights.solve_wall_at_heights
    assert not bool(solve(ceiling_rays, floor_rays, one, none, room["h_c"], room["h_f"]).ok)
    assert not bool(solve(ceiling_rays, floor_rays, one, one, room["h_c"], room["h_f"]).ok)  # a line through the axis
    assert bool(solve(ceiling_rays, floor_rays, two, none, room["h_c"], room["h_f"]).ok)
    assert not bool(solve(ceiling_rays, floor_rays, two, two, -room["h_c"], room["h_f"]).ok)


def test_ransac_at_known_heights_ignores_outlier_rows():
    """A third of a wall's rows 40 px off (furniture, a doorway): RANSAC at the known heights keeps the true wall."""
    from ncjax.geometry.reprojection import column_directions
    from ncjax.solvers.ransac import RansacConfig, WallColumns, ransac_wall

    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=0.0)
    cam, columns = room["cam"], jnp.flatnonzero(room["wall_index"] == 1, size=40)
    outlier = jnp.arange(columns.size) % 3 == 0
    floor_v = room["floor_v"][columns] - jnp.where(outlier, 40.0, 0.0)
    ceiling_rays = ncjax.geometry.pixel_to_ray(cam, columns.astype(float), room["ceiling_v"][columns])
    floor_rays = ncjax.geometry.pixel_to_ray(cam, columns.astype(float), floor_v)
    wall_columns = WallColumns(
        column_directions(cam, columns.astype(float)), ceiling_rays, floor_rays, jnp.ones(columns.size, bool)
    )
    config = RansacConfig(inlier_threshold=2.0 * 512 / cam.height)  # 13 hypotheses of 3 columns, inliers within 2 px
    assert config.hypotheses == 13
    wall = ransac_wall(jax.random.key(0), cam, wall_columns, config, heights=(room["h_c"], room["h_f"]))
    assert bool(wall.ok)
    assert float(direction_error_deg(wall.direction, room["directions"][1])) < 0.01
    np.testing.assert_allclose(wall.distance, room["distances"][1], atol=1e-3)


def test_ransac_gives_one_wall_whatever_the_key():
    """A non-central wall's rows with 0.2 px of noise and a desk's edge along a third of its floor: every key ends at
    the same wall (the deterministic hypotheses and the refits to a fixed point), and it is the true one."""
    from ncjax.geometry.reprojection import column_directions
    from ncjax.solvers.ransac import RansacConfig, WallColumns, ransac_wall

    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=0.3)
    cam, columns = room["cam"], jnp.flatnonzero(room["wall_index"] == 1, size=48)
    noise = np.random.default_rng(3).normal(0.0, 0.2, (2, columns.size))
    desk = jnp.arange(columns.size) >= 2 * columns.size // 3
    ceiling_v = room["ceiling_v"][columns] + noise[0]
    floor_v = room["floor_v"][columns] + noise[1] - jnp.where(desk, 30.0, 0.0)
    wall_columns = WallColumns(
        column_directions(cam, columns.astype(float)),
        ncjax.geometry.pixel_to_ray(cam, columns.astype(float), ceiling_v),
        ncjax.geometry.pixel_to_ray(cam, columns.astype(float), floor_v),
        jnp.ones(columns.size, bool),
    )
    walls = jax.vmap(lambda key: ransac_wall(key, cam, wall_columns, RansacConfig()))(
        jax.random.split(jax.random.key(7), 16)
    )
    assert bool(jnp.all(walls.ok))
    for field in (walls.distance, walls.ceiling_height, walls.floor_height):
        assert float(jnp.max(field) - jnp.min(field)) < 1e-4
    assert float(jnp.max(direction_error_deg(walls.direction, room["directions"][1]))) < 0.5
    # one wall's parallax fixes its scale loosely (the pipeline takes the heights from all walls at once)
    np.testing.assert_allclose(walls.distance, room["distances"][1], rtol=0.15)
    np.testing.assert_allclose(walls.ceiling_height, room["h_c"], rtol=0.15)


def test_spread_columns_span_a_window_of_the_candidates():
    from ncjax.solvers.ransac import spread_columns

    candidates = jnp.asarray(np.isin(np.arange(20), [1, 2, 4, 7, 8, 9, 12, 15, 16, 19]))
    np.testing.assert_array_equal(spread_columns(candidates, (0.0, 1.0), 3), [1, 8, 19])
    np.testing.assert_array_equal(spread_columns(candidates, (0.5, 1.0), 3), [8, 15, 19])


def test_a_wall_at_heights_has_finite_gradients_even_where_it_fails():
    """Too few points leave a zero scatter; its angle must not poison the gradient of a result that is masked out."""
    room = box_room([[-2.0, -1.5], [3.0, -1.5], [3.0, 2.5], [-2.0, 2.5]], rc=0.0)
    ceiling_rays, floor_rays = rays(room)

    def distance(rows, mask):
        rays_now = ncjax.geometry.pixel_to_ray(room["cam"], jnp.arange(WIDTH, dtype=rows.dtype), rows)
        wall = ncjax.solvers.wall_at_heights.solve_wall_at_heights(
            rays_now, floor_rays, mask, mask & False, room["h_c"], room["h_f"]
        )
        return jnp.where(wall.ok, wall.distance, 0.0)

    for columns in ([10], [10, 20, 30]):
        gradient = jax.grad(distance)(room["ceiling_v"], jnp.isin(jnp.arange(WIDTH), jnp.array(columns)))
        assert bool(jnp.all(jnp.isfinite(gradient)))
        assert bool(jnp.any(gradient != 0)) == (len(columns) > 1)
