"""Acceptance check of the foundation: exact labels of many random rooms (float64).

For N random rooms (half Manhattan at random yaw, half Atlanta; a third of each
generated with the "at least one occlusion" option), project the ground-truth 3D
boundary points and corners and compare with the label rows/columns. Prints the
status counts (failure modes), the max errors and the occlusion statistics.

    uv run python experiments/label_consistency.py [--rooms 1000]
"""

import argparse
from functools import partial

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp
import numpy as np

import ncjax


def check(room, width, height):
    cam = room.camera(width, height)
    labels = ncjax.synth.room_labels(room, cam)
    columns = jnp.arange(width, dtype=jnp.float64)
    u_c, v_c = ncjax.geometry.project(cam, labels.ceiling_points)
    u_f, v_f = ncjax.geometry.project(cam, labels.floor_points)
    row_error = jnp.maximum(jnp.max(jnp.abs(v_c - labels.ceiling_v)), jnp.max(jnp.abs(v_f - labels.floor_v)))
    column_error = jnp.max(jnp.abs(jnp.stack([u_c, u_f]) - columns))
    corner_u, _ = ncjax.geometry.project(cam, labels.ceiling_corners)
    corner_error = jnp.max(jnp.where(labels.corner_mask, jnp.abs(corner_u - labels.corner_u), 0.0))
    return labels.ok, row_error, column_error, corner_error, jnp.any(labels.corner_is_occlusion)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rooms", type=int, default=1000)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=512)
    args = parser.parse_args()
    groups = []
    per_world = args.rooms // 2
    for world in ("manhattan", "atlanta"):
        occluded = per_world // 3
        groups += [(world, "required", occluded), (world, "any", per_world - occluded)]
    total_ok, worst = 0, np.zeros(3)
    for seed, (world, occlusion, n) in enumerate(groups):
        config = ncjax.RoomConfig(world=world, occlusion=occlusion)
        rooms = jax.jit(jax.vmap(partial(ncjax.synth.random_room, config=config)))(
            jax.random.split(jax.random.key(seed), n)
        )
        ok, row, column, corner, has_occlusion = jax.jit(
            jax.vmap(partial(check, width=args.width, height=args.height))
        )(rooms)
        statuses = np.bincount(np.asarray(rooms.status), minlength=len(ncjax.synth.RoomStatus))
        named = ", ".join(f"{s.name}={statuses[s]}" for s in ncjax.synth.RoomStatus if statuses[s])
        errors = np.array([np.max(row), np.max(column), np.max(corner)])
        worst = np.maximum(worst, errors)
        total_ok += int(np.sum(ok))
        print(
            f"{world:9s} occlusion={occlusion:8s} n={n:4d}: status {named}; labels ok {int(np.sum(ok))}/{n}; "
            f"with occlusion {int(np.sum(has_occlusion))}; walls {np.asarray(rooms.num_walls).min()}-"
            f"{np.asarray(rooms.num_walls).max()}; max |row| {errors[0]:.2e} px, |column| {errors[1]:.2e} px, "
            f"|corner column| {errors[2]:.2e} px"
        )
    print(
        f"TOTAL: {total_ok}/{sum(g[2] for g in groups)} rooms ok; max row error {worst[0]:.2e} px "
        f"(goal < 1e-3), column {worst[1]:.2e} px, corner column {worst[2]:.2e} px"
    )


if __name__ == "__main__":
    main()
