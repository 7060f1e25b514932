"""Fuzzing the geometry with inputs no network should give: nothing raises, nothing ok carries a NaN.

Hypothesis draws each case: the exact rows of one of a few rendered rooms (256 x 128), then any mix of
NaN and infinite rows, rows off the image, ceiling and floor rows swapped, row noise, a corner
probability that is exact, flat, zero, NaN, noise or has only 0-2 peaks, and a radius of 0, 1e-9,
1e-4, 1 cm or the room's. Cases come in batches of ``--batch``; each batch runs
``ncjax.layout_from_boundaries`` (world auto, the network's configuration) twice, without and with a
camera-height prior, and ``ncjax.solvers.solve_wall`` on the rays of the room's first wall's columns.

A case FAILS when a call raises, when any field of any result is NaN (failed layouts carry finite fill
values; only the covariances may be infinite, for what the rows leave free), or when an ok layout has a
non-finite corner or height. The script prints the counts and the statuses, and exits 1 on a failure.

    uv run python experiments/fuzz_pipeline.py [--cases 10000] [--seed 0] [--time-budget SECONDS]

Different ``--seed`` values draw different cases, so a long run can be split into parts (in parallel
on several cores, or in slots); ``--time-budget`` stops drawing once that much time has passed (the
summary counts the cases run).
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, seed, settings
from hypothesis import strategies as st

import ncjax
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

WIDTH, HEIGHT = 256, 128
ROOMS = 6
RADII = ("zero", "1e-9", "1e-4", "1 cm", "the room's", "the room's")
PROBABILITIES = ("exact", "flat", "zero", "nan", "noise", "no peak", "one peak", "two peaks")
# covariances may be infinite (a wall or height the rows leave free); nothing may be NaN
MAY_BE_INFINITE = ("corner_covariance", "height_covariance")


def rendered_rooms():
    config = ncjax.RoomConfig(world="mix", room_tries=2, camera_tries=64)
    batch = jax.jit(jax.vmap(lambda k: ncjax.synth.random_room(k, config)))(jax.random.split(jax.random.key(5), ROOMS))
    labels = jax.jit(jax.vmap(lambda r: ncjax.synth.room_labels(r, r.camera(WIDTH, HEIGHT))))(batch)
    return jax.device_get(batch), jax.device_get(labels)


@st.composite
def cases(draw):
    """One corrupted input: (room index, radius kind, probability kind, corruption parameters)."""
    return {
        "room": draw(st.integers(0, ROOMS - 1)),
        "radius": draw(st.sampled_from(RADII)),
        "probability": draw(st.sampled_from(PROBABILITIES)),
        "nan_columns": draw(st.sampled_from([0.0, 0.0, 0.0, 0.01, 0.1, 0.3, 0.7, 1.0])),
        "inf_columns": draw(st.sampled_from([0.0, 0.0, 0.0, 0.01, 0.1, 1.0])),
        "off_image": draw(st.sampled_from([0.0, 0.05, 0.5])),
        "swapped": draw(st.sampled_from([0.0, 0.1, 1.0])),
        "noise": draw(st.sampled_from([0.0, 0.5, 3.0, 40.0])),
        "flat_value": draw(st.floats(0.0, 1.0)),
        "seed": draw(st.integers(0, 2**31 - 1)),
    }


def corrupted_input(case: dict, labels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(case["seed"])
    ceiling = np.array(labels.ceiling_v[case["room"]], np.float32)
    floor = np.array(labels.floor_v[case["room"]], np.float32)
    exact = np.array(labels.corner_target[case["room"]], np.float32)
    ceiling += case["noise"] * rng.standard_normal(WIDTH).astype(np.float32)
    floor += case["noise"] * rng.standard_normal(WIDTH).astype(np.float32)
    swap = rng.random(WIDTH) < case["swapped"]
    ceiling, floor = np.where(swap, floor, ceiling), np.where(swap, ceiling, floor)
    off = rng.random(WIDTH) < case["off_image"]
    ceiling = np.where(off, -ceiling - 50.0, ceiling)
    floor = np.where(rng.random(WIDTH) < case["off_image"], floor + HEIGHT, floor)
    for fraction, value in ((case["nan_columns"], np.nan), (case["inf_columns"], np.inf)):
        ceiling = np.where(rng.random(WIDTH) < fraction, value, ceiling)
        floor = np.where(rng.random(WIDTH) < fraction, -value, floor)
    kind = case["probability"]
    probability = {
        "exact": exact,
        "flat": np.full(WIDTH, case["flat_value"], np.float32),
        "zero": np.zeros(WIDTH, np.float32),
        "nan": np.where(rng.random(WIDTH) < 0.5, np.nan, exact).astype(np.float32),
        "noise": rng.random(WIDTH).astype(np.float32),
    }.get(kind)
    if probability is None:  # 0, 1 or 2 peaks of a tent at random columns
        peaks = PROBABILITIES.index(kind) - PROBABILITIES.index("no peak")
        distance = np.full(WIDTH, np.inf)
        for column in rng.integers(0, WIDTH, peaks):
            offset = np.abs(np.arange(WIDTH) - column)
            distance = np.minimum(distance, np.minimum(offset, WIDTH - offset))
        probability = (0.96**distance).astype(np.float32)
    return ceiling, floor, probability


def radius_of(case: dict, room_rc: float) -> float:
    return {"1e-9": 1e-9, "1e-4": 1e-4, "1 cm": 0.01, "the room's": room_rc}.get(case["radius"], 0.0)


def problems(result, ok: bool | None = None) -> list[str]:
    """What is wrong with one result (a Layout or a Wall)."""
    found = []
    for name, value in vars(result).items():
        value = np.asarray(value)
        if value.dtype == bool or value.dtype.kind in "iu":
            continue
        if np.isnan(value).any():
            found.append(f"{name} has NaN")
        elif name not in MAY_BE_INFINITE and not np.isfinite(value).all():
            found.append(f"{name} is infinite")
    if ok and found:
        found.append("and the result is ok")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=10_000, help="layouts in all (half of them with a prior)")
    parser.add_argument(
        "--batch",
        type=int,
        default=1,
        help="cases per hypothesis example, one batched call (a batch of 100 compiles for over 17 min on 2 cores)",
    )
    parser.add_argument("--seed", type=int, default=0, help="hypothesis's seed: which cases are drawn")
    parser.add_argument(
        "--time-budget", type=float, default=None, help="stop running cases after this many seconds (default: none)"
    )
    args = parser.parse_args(argv)
    batch, labels = rendered_rooms()
    config = NETWORK_PIPELINE_CONFIG
    solve_walls = jax.jit(jax.vmap(ncjax.solvers.solve_wall))
    first_wall = np.asarray(labels.wall_index == 0)  # (rooms, W): the columns of each room's first wall
    counts, statuses, failures = collections.Counter(), collections.Counter(), []
    start = time.perf_counter()

    def check(results, oks, what, drawn):
        for i, case in enumerate(drawn):
            found = problems(jax.tree.map(lambda x: x[i], results), bool(oks[i]))
            if found:
                counts[f"{what} with NaN or inf"] += 1
                failures.append(f"{case}: {what}: {', '.join(found)}")

    @seed(args.seed)
    @settings(max_examples=max(1, args.cases // (2 * args.batch)), database=None, deadline=None)
    @given(st.lists(cases(), min_size=args.batch, max_size=args.batch))
    def one(drawn):
        if args.time_budget is not None and time.perf_counter() - start > args.time_budget:
            return
        inputs = [corrupted_input(case, labels) for case in drawn]
        ceiling, floor, probability = (np.stack(part) for part in zip(*inputs, strict=True))
        rc = np.array([radius_of(case, float(batch.rc[case["room"]])) for case in drawn], np.float32)
        cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=jnp.asarray(rc))
        key = jax.random.key(drawn[0]["seed"])
        # every case twice: the radius alone gives the scale, then a camera-height prior does
        for prior in (None, ncjax.HeightPrior("camera_height", 1.6)):
            try:
                layouts = jax.device_get(
                    ncjax.layout_from_boundaries(ceiling, floor, probability, cam, "auto", config, key=key, prior=prior)
                )
            except Exception as error:  # noqa: BLE001 - counting what raises is the point
                counts["raised"] += len(drawn)
                failures.append(f"batch of {len(drawn)} (prior {prior}): raised {type(error).__name__}: {error}")
                continue
            counts["cases"] += len(drawn)
            counts["ok layouts"] += int(np.sum(layouts.ok))
            statuses.update(ncjax.LayoutStatus(int(code)).name for code in layouts.status)
            check(layouts, layouts.ok, "layout", drawn)
        rays = jax.vmap(lambda c, f: ncjax.geometry.pixel_to_ray(cam, jnp.arange(WIDTH) + 0.5, jnp.stack([c, f])))(
            jnp.asarray(ceiling), jnp.asarray(floor)
        )
        used = first_wall[[case["room"] for case in drawn]]
        try:
            walls = jax.device_get(solve_walls(rays[:, 0], rays[:, 1], used, used))
        except Exception as error:  # noqa: BLE001
            failures.append(f"solve_wall: raised {type(error).__name__}: {error}")
            return
        counts["walls"] += len(drawn)
        counts["ok walls"] += int(np.sum(walls.ok))
        check(walls, walls.ok, "wall", drawn)
        progress = f"{counts['cases']} layouts, {counts['walls']} walls, {counts['raised']} raised"
        progress += f", {len(failures)} failures, {time.perf_counter() - start:.0f} s"
        print(progress, file=sys.stderr, flush=True)

    one()
    elapsed = time.perf_counter() - start
    print(
        f"{counts['cases'] + counts['raised']} layouts and {counts['walls']} walls in {elapsed:.0f} s "
        f"({WIDTH} x {HEIGHT}, world auto, batches of {args.batch}, seed {args.seed})"
    )
    print(f"  raised: {counts['raised']}")
    print(f"  layouts with a NaN (or a non-finite corner or height): {counts['layout with NaN or inf']}")
    print(f"  walls with a NaN (or a non-finite field): {counts['wall with NaN or inf']}")
    print(f"  ok layouts: {counts['ok layouts']}, ok walls: {counts['ok walls']}")
    print("  statuses: " + ", ".join(f"{name} {n}" for name, n in statuses.most_common()))
    for line in failures[:20]:
        print("FAIL", line)
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
