"""Acceptance of the geometric solvers on exact rays .

1000 random rooms from ``ncjax.synth.random_room`` without occlusion (500 Manhattan
at a random yaw, 500 Atlanta), 1024 x 512, rc in 0.3-1.0 m, exact per-column
labels from ``ncjax.synth.room_labels``. For every solver, the maximum direction
(deg), distance, height and corner (m) errors, in float32 and float64, against
the goals (<= 5 mm and 0.2 deg in float32, <= 0.1 mm in float64):

- ``solve_manhattan_layout`` (Manhattan rooms) and ``solve_atlanta_layout``
  (all rooms, true directions given): every wall, both heights, every corner;
- ``solve_wall``: every wall alone, from its own columns;
- ``solve_wall_minimal``: every wall from 2 ceiling + 2 floor rays (its first
  and last columns for the ceiling, the columns at 1/3 and 2/3 for the floor),
  the best valid candidate;
- ``solve_horizontal_line`` (the baseline): every ceiling and floor line alone;
- dtype ``f32 rays``: the single-wall solvers in float64 on the float32 rays,
  i.e. the error that rounding the input to float32 causes by itself.

Single walls are reported for walls seen by at least ``--min-columns``
columns (default 64, 22.5 degrees of azimuth) and, separately, for all walls
of >= 8 columns: a wall seen under a few degrees determines its scale through
``rc`` alone and float32 cannot hold millimetres there.

One ``jit(vmap)`` per solver and precision.

    uv run python experiments/solver_accuracy.py [--rooms 1000]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax
import jax.numpy as jnp
import numpy as np

import ncjax

WIDTH, HEIGHT = 1024, 512
CAPACITY = 16


def config(world):
    return ncjax.RoomConfig(world=world, max_walls=8, capacity=CAPACITY, occlusion="none")


def room_arrays(room):
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=room.rc)
    labels = ncjax.synth.room_labels(room, cam)
    directions, distances, _, _ = ncjax.synth.room_walls(room)
    columns = jnp.arange(WIDTH, dtype=room.rc.dtype)
    wall_columns = jnp.sum(labels.wall_index[:, None] == jnp.arange(CAPACITY), 0)
    return dict(
        ceiling_rays=ncjax.geometry.pixel_to_ray(cam, columns, labels.ceiling_v),
        floor_rays=ncjax.geometry.pixel_to_ray(cam, columns, labels.floor_v),
        wall_index=labels.wall_index,
        mask=room.mask,
        wall_columns=wall_columns,
        directions=directions,
        distances=distances,
        labels=jnp.where(room.mask & (jnp.abs(directions @ directions[0]) < 0.5), 1, 0),
        corners=room.corners,
        h_c=room.ceiling_height,
        h_f=room.floor_height,
        usable=room.ok & labels.ok & ~jnp.any(labels.corner_is_occlusion) & jnp.all(~room.mask | (wall_columns >= 3)),
    )


def generate(n_rooms):
    parts = []
    for world, seed in (("manhattan", 0), ("atlanta", 1)):
        count = n_rooms // 2
        keys = jax.random.split(jax.random.PRNGKey(seed), 2 * count)
        arrays = jax.jit(jax.vmap(lambda k, w=world: room_arrays(ncjax.synth.random_room(k, config(w)))))(keys)
        index = np.nonzero(np.asarray(arrays["usable"]))[0][:count]
        parts.append(jax.tree.map(lambda x: x[index], arrays))
    return parts


def _angle(a, b):
    """Degrees between 2D directions, sign-free."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.degrees(jnp.arctan2(jnp.abs(cross), jnp.abs(jnp.sum(a * b, -1))))


def layout_errors(room, layout, mask):
    corners = ncjax.solvers.layout_corners(layout.ceiling_lines, layout.mask)
    heights = jnp.concatenate([room["corners"], jnp.full((CAPACITY, 1), room["h_c"])], -1)
    distance = jnp.abs(jnp.abs(layout.distances) - jnp.abs(room["distances"]))
    return dict(
        direction=jnp.where(mask, _angle(layout.directions, room["directions"]), 0.0),
        distance=jnp.where(mask, distance, 0.0),
        height=jnp.maximum(jnp.abs(layout.ceiling_height - room["h_c"]), jnp.abs(layout.floor_height - room["h_f"])),
        corner=jnp.where(mask, jnp.linalg.norm(corners - heights, axis=-1), 0.0),
        ok=layout.ok,
    )


def manhattan(room):
    layout = ncjax.solvers.solve_manhattan_layout(
        room["ceiling_rays"], room["floor_rays"], room["wall_index"], room["mask"], room["labels"]
    )
    return layout_errors(room, layout, room["mask"])


def atlanta(room):
    layout = ncjax.solvers.solve_atlanta_layout(
        room["ceiling_rays"], room["floor_rays"], room["wall_index"], room["mask"], room["directions"]
    )
    return layout_errors(room, layout, room["mask"])


def _wall_errors(room, wall, mask):
    return dict(
        direction=jnp.where(mask, _angle(wall.direction, room["directions"]), 0.0),
        distance=jnp.where(mask, jnp.abs(wall.distance - room["distances"]), 0.0),
        height=jnp.where(
            mask, jnp.maximum(jnp.abs(wall.ceiling_height - room["h_c"]), jnp.abs(wall.floor_height - room["h_f"])), 0.0
        ),
        corner=jnp.zeros(()),
        ok=jnp.all(wall.ok | ~mask),
    )


def single_wall(room):
    masks = room["wall_index"][None, :] == jnp.arange(CAPACITY)[:, None]
    walls = jax.vmap(lambda m: ncjax.solvers.solve_wall(room["ceiling_rays"], room["floor_rays"], m, m))(masks)
    return _wall_errors(room, walls, room["mask"])


def minimal_wall(room):
    def one(k):
        columns = jnp.nonzero(room["wall_index"] == k, size=WIDTH, fill_value=0)[0]
        n = jnp.maximum(room["wall_columns"][k], 1)
        pick = columns[jnp.round(jnp.array([0.0, 1.0, 1 / 3, 2 / 3]) * (n - 1)).astype(jnp.int32)]
        walls, valid = ncjax.solvers.solve_wall_minimal(room["ceiling_rays"][pick[:2]], room["floor_rays"][pick[2:]])
        error = jnp.abs(walls.distance - room["distances"][k]) + jnp.abs(walls.ceiling_height - room["h_c"])
        best = jnp.argmin(jnp.where(valid, error, jnp.inf))
        return jax.tree.map(lambda x: x[best], walls)

    walls = jax.vmap(one)(jnp.arange(CAPACITY))
    return _wall_errors(room, walls, room["mask"])


def baseline(room):
    masks = room["wall_index"][None, :] == jnp.arange(CAPACITY)[:, None]
    worst = None
    for rays, height in ((room["ceiling_rays"], room["h_c"]), (room["floor_rays"], room["h_f"])):
        lines = jax.vmap(ncjax.solvers.solve_horizontal_line, (None, 0))(rays, masks)
        mask = room["mask"]
        errors = dict(
            direction=jnp.where(mask, _angle(lines.direction, room["directions"]), 0.0),
            distance=jnp.where(mask, jnp.abs(lines.distance - room["distances"]), 0.0),
            height=jnp.where(mask, jnp.abs(lines.height - height), 0.0),
            corner=jnp.zeros(()),
            ok=jnp.all(lines.ok | ~mask),
        )
        worst = (
            errors
            if worst is None
            else {k: jnp.maximum(worst[k], v) if k != "ok" else worst[k] & v for k, v in errors.items()}
        )
    return worst


def run(solver, rooms, column_mask=None):
    """Max errors over rooms (and walls with ``column_mask``) of one jit(vmap)-ed solver."""
    errors = jax.jit(jax.vmap(solver))(rooms)
    out = {}
    for key in ("direction", "distance", "height", "corner"):
        values = np.asarray(errors[key])
        if column_mask is not None and values.ndim == 2:
            values = np.where(column_mask, values, 0.0)
        out[key] = float(np.max(values))
    ok = np.asarray(errors["ok"])
    out["ok"] = float(np.mean(ok))
    return out


def wall_selections(both, min_columns):
    """Which walls enter the single-wall rows: seen by >= ``min_columns`` columns, and by >= 8."""
    columns, mask = np.asarray(both["wall_columns"]), np.asarray(both["mask"])
    return mask & (columns >= min_columns), mask & (columns >= 8)


def rounded_input_rows(float32_rooms, min_columns):
    """The single-wall solvers in float64 on the float32 rooms' rays: the error float32 INPUT alone causes.

    If these errors match the float32 solves, the limit is the conditioning of
    the problem (the scale of one wall comes from ``rc`` alone), not the
    solver's arithmetic.
    """
    promote = lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x  # noqa: E731
    both = jax.tree.map(lambda a, b: promote(jnp.concatenate([a, b])), *float32_rooms)
    wide, narrow = wall_selections(both, min_columns)
    dtype = "f32 rays"
    return [
        ("solve_wall", dtype, f"{narrow.sum()} walls >= 8 col", run(single_wall, both, narrow)),
        ("solve_wall_minimal", dtype, f"{wide.sum()} walls >= {min_columns} col", run(minimal_wall, both, wide)),
    ]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=1000)
    parser.add_argument("--min-columns", type=int, default=64)
    args = parser.parse_args(argv)
    rows = []
    float32_rooms = None
    for x64 in (False, True):
        with jax.enable_x64(x64):
            start = time.perf_counter()
            manhattan_rooms, atlanta_rooms = generate(args.rooms)
            if not x64:
                float32_rooms = (manhattan_rooms, atlanta_rooms)
            both = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), manhattan_rooms, atlanta_rooms)
            wide, narrow = wall_selections(both, args.min_columns)
            dtype = "float64" if x64 else "float32"
            cases = [
                ("solve_manhattan_layout", manhattan, manhattan_rooms, None, f"{len(manhattan_rooms['h_c'])} rooms"),
                ("solve_atlanta_layout", atlanta, both, None, f"{len(both['h_c'])} rooms"),
                ("solve_wall", single_wall, both, wide, f"{wide.sum()} walls >= {args.min_columns} col"),
                ("solve_wall", single_wall, both, narrow, f"{narrow.sum()} walls >= 8 col"),
                ("solve_wall_minimal", minimal_wall, both, wide, f"{wide.sum()} walls >= {args.min_columns} col"),
                ("solve_horizontal_line", baseline, both, wide, f"{2 * wide.sum()} lines >= {args.min_columns} col"),
            ]
            for name, solver, rooms, column_mask, what in cases:
                rows.append((name, dtype, what, run(solver, rooms, column_mask)))
            if x64:
                rows += rounded_input_rows(float32_rooms, args.min_columns)
            print(f"{dtype}: {time.perf_counter() - start:.1f} s", flush=True)
    print("\nmax errors on exact rays (goal: <= 5 mm and 0.2 deg in float32, <= 0.1 mm in float64)")
    print(
        f"{'solver':24s} {'dtype':8s} {'cases':28s} {'dir (deg)':>10s} {'dist (mm)':>10s} {'height (mm)':>12s} "
        f"{'corner (mm)':>12s} {'ok':>6s}  goal"
    )
    for name, dtype, what, e in rows:
        metres = max(e["distance"], e["height"], e["corner"])
        goal = metres <= (5e-3 if dtype == "float32" else 1e-4) and (dtype == "float64" or e["direction"] <= 0.2)
        goal = "-" if dtype == "f32 rays" else "met" if goal else "MISSED"
        print(
            f"{name:24s} {dtype:8s} {what:28s} {e['direction']:10.2e} {1e3 * e['distance']:10.3f} "
            f"{1e3 * e['height']:12.3f} "
            f"{1e3 * e['corner']:12.3f} {e['ok']:6.3f}  {goal}"
        )
    return rows


if __name__ == "__main__":
    main()
