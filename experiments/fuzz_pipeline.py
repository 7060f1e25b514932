"""Fuzzing the geometry with inputs no network should give: nothing raises, nothing ok carries a NaN.

Hypothesis draws each case: the exact rows of one of a few rendered rooms (256 x 128), then any mix of
NaN and infinite rows, rows off the image, ceiling and floor rows swapped, row noise, a corner
probability that is exact, flat, zero, NaN, noise or has only 0-2 peaks, and a radius of 0 (with and
without a height prior), 1e-9, 1e-4, 1 cm or the room's. Each case runs ``ncjax.layout_from_boundaries``
(world auto, the network's configuration) and ``ncjax.solve_wall`` on the first wall's rays.

A case FAILS when a call raises, when any field of any result is NaN (failed layouts carry finite fill
values; only the covariances may be infinite, for what the rows leave free), or when an ok layout has a
non-finite corner or height. The script prints the counts and the statuses, and exits 1 on a failure.

    uv run python experiments/fuzz_pipeline.py [--cases 10000] [--seed 0]
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import ncjax  # noqa: E402
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG  # noqa: E402

WIDTH, HEIGHT = 256, 128
ROOMS = 6
RADII = ("zero", "zero with prior", "1e-9", "1e-4", "1 cm", "the room's")
PROBABILITIES = ("exact", "flat", "zero", "nan", "noise", "no peak", "one peak", "two peaks")
# covariances may be infinite (a wall or height the rows leave free); nothing may be NaN
MAY_BE_INFINITE = ("corner_covariance", "height_covariance")


def rendered_rooms():
    config = ncjax.RoomConfig(world="mix", room_tries=2, camera_tries=64)
    batch = jax.jit(jax.vmap(lambda k: ncjax.random_room(k, config)))(jax.random.split(jax.random.key(5), ROOMS))
    labels = jax.jit(jax.vmap(lambda r: ncjax.room_labels(r, r.camera(WIDTH, HEIGHT))))(batch)
    return jax.device_get(batch), jax.device_get(labels)


@st.composite
def cases(draw):
    """One corrupted input: (room index, radius kind, probability kind, corruption parameters)."""
    return {
        "room": draw(st.integers(0, ROOMS - 1)),
        "radius": draw(st.sampled_from(RADII)),
        "probability": draw(st.sampled_from(PROBABILITIES)),
        "nan_columns": draw(st.sampled_from([0.0, 0.01, 0.3, 0.7, 1.0])),
        "inf_columns": draw(st.sampled_from([0.0, 0.01, 0.3, 1.0])),
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
    parser.add_argument("--cases", type=int, default=10_000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    batch, labels = rendered_rooms()
    config = NETWORK_PIPELINE_CONFIG
    prior = ncjax.HeightPrior("camera_height", 1.6)
    solve_wall = jax.jit(ncjax.solve_wall)
    counts, statuses, failures = collections.Counter(), collections.Counter(), []
    start = time.perf_counter()

    @settings(
        max_examples=args.cases,
        database=None,
        deadline=None,
        derandomize=False,
        suppress_health_check=list(HealthCheck),
    )
    @given(cases())
    def one(case):
        ceiling, floor, probability = corrupted_input(case, labels)
        rc = radius_of(case, float(batch.rc[case["room"]]))
        cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=jnp.float32(rc))
        use_prior = prior if case["radius"] == "zero with prior" else None
        try:
            layout = ncjax.layout_from_boundaries(
                ceiling, floor, probability, cam, "auto", config, key=jax.random.key(case["seed"]), prior=use_prior
            )
            rays = ncjax.pixel_to_ray(cam, jnp.arange(WIDTH) + 0.5, jnp.stack([ceiling, floor]))
            used = np.asarray(labels.wall_index[case["room"]] == 0)  # the columns of the room's first wall
            wall = solve_wall(rays[0], rays[1], used, used)
        except Exception as error:  # noqa: BLE001 - counting what raises is the point
            counts["raised"] += 1
            failures.append(f"{case}: raised {type(error).__name__}: {error}")
            return
        counts["cases"] += 1
        statuses[ncjax.LayoutStatus(int(layout.status)).name] += 1
        counts["ok layouts"] += bool(layout.ok)
        counts["ok walls"] += bool(wall.ok)
        for what, found in (("layout", problems(layout, bool(layout.ok))), ("wall", problems(wall, bool(wall.ok)))):
            if found:
                counts[f"{what} with NaN or inf"] += 1
                failures.append(f"{case}: {what}: {', '.join(found)}")
        if counts["cases"] % 500 == 0:
            print(f"  {counts['cases']} cases, {time.perf_counter() - start:.0f} s", file=sys.stderr, flush=True)

    try:
        one()
    except Exception as error:  # noqa: BLE001 - hypothesis re-raises nothing here (one() catches); report anyway
        failures.append(f"hypothesis: {type(error).__name__}: {error}")
    elapsed = time.perf_counter() - start
    print(f"{counts['cases'] + counts['raised']} cases in {elapsed:.0f} s ({WIDTH} x {HEIGHT}, world auto)")
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
