"""Sensitivity of the geometric solvers to boundary noise (paper Section 5.3, Fig. Geomcomparison).

Rooms come from ``ncjax.synth.random_room`` without occlusion (Manhattan rooms at a
random yaw and Atlanta rooms, 4-8 Manhattan walls before clipping), with
exact per-column labels from ``ncjax.synth.room_labels``. Gaussian noise of
standard deviation sigma (pixels) is added to the exact ceiling and floor
boundary ROWS; the rays are back-projected and fed, with the true wall
labels / directions, to the Manhattan layout solver (Manhattan rooms), the
Atlanta layout solver and the single-line baseline [bermudez2016line] (each
ceiling and floor line alone; all rooms). Metrics as in the paper: corner
error (m, mean L2 over ceiling and floor corners), direction error (deg,
arccos |l . l_gt|) and depth error (m, | |lbar| - |lbar_gt| |).

Each method's sigma and rc sweeps are ONE jitted call (``lax.map`` over chunks
of a ``vmap``, split over one XLA device per core with ``shard_map``: no
Python loop over rooms or draws); the rooms and their exact labels (one set
per rc) are generated once before, and all the sweeps' programs are compiled
in parallel threads before any runs.

    uv run python experiments/noise_sweep.py            # the full sweep
    uv run python experiments/noise_sweep.py --small    # quick check (CI)

Writes CSV and log-scale PNG plots to experiments/out/.
"""

from __future__ import annotations

import argparse
import concurrent.futures
import csv
import os
import time
import warnings
from pathlib import Path

# jaxlib's LAPACK kernels split their batch over XLA's CPU thread pool and wait for it; with
# one busy device per pool thread that wait never ends (seen in gdb: both devices in
# CholeskyFactorizationKernel -> ParallelBatchMap -> BlockingCounter::Wait). XLA sizes the
# pool from NPROC when it is set: twice the cores leaves threads free for those kernels.
os.environ.setdefault("NPROC", str(2 * os.cpu_count()))
# One single-threaded XLA device per core: the sweep's cases are split over them. LLVM at -O1
# instead of -O2: the room generator compiles in half the time (7.3 -> 3.5 s) and runs as
# fast; the sweeps' programs run as fast too (their compile time is in XLA's own passes).
os.environ.setdefault(
    "XLA_FLAGS",
    f"--xla_cpu_multi_thread_eigen=false --xla_force_host_platform_device_count={os.cpu_count()} "
    "--xla_backend_optimization_level=1",
)

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

import ncjax

OUT = Path(__file__).parent / "out"
MIN_COLUMNS = 3  # every wall seen by at least this many columns (else it is not measurable)


def room_config(world: str) -> ncjax.RoomConfig:
    """Rooms of 4-8 Manhattan walls (Atlanta: plus clipped corners), no occlusion."""
    return ncjax.RoomConfig(world=world, max_walls=8, capacity=16, occlusion="none", rc_range=(1.0, 1.0))


def generate_rooms(n_rooms: int, seed: int = 0) -> ncjax.synth.Room:
    """``n_rooms // 2`` Manhattan rooms, then ``n_rooms - n_rooms // 2`` Atlanta rooms (batched Room).

    Generated with rc = 1 m (the largest of the sweep, so the camera keeps its
    clearance when rc is lowered); rooms that fail are replaced by the next key.
    """
    parts = []
    for world, count, offset in (("manhattan", n_rooms // 2, 0), ("atlanta", n_rooms - n_rooms // 2, 1)):
        keys = jax.random.split(jax.random.PRNGKey(seed + offset), 2 * count)
        rooms = jax.jit(jax.vmap(lambda k, w=world: ncjax.synth.random_room(k, room_config(w))))(keys)
        index = np.nonzero(np.asarray(rooms.ok))[0][:count]
        parts.append(jax.tree.map(lambda x: x[index], rooms))
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), *parts)


def rooms_per_rc(rooms: ncjax.synth.Room, rcs, width: int, height: int) -> dict:
    """:func:`room_arrays` of every room (axis 1) for every rc (axis 0)."""
    return jax.vmap(jax.vmap(room_arrays, (0, None, None, None)), (None, 0, None, None))(rooms, rcs, width, height)


def room_arrays(room: ncjax.synth.Room, rc, width: int, height: int) -> dict:
    """Exact labels of ``room`` seen with radius ``rc``, and the truth, as fixed-shape arrays."""
    room = eqx.tree_at(lambda r: r.rc, room, jnp.asarray(rc, room.rc.dtype))
    labels = ncjax.synth.room_labels(room, ncjax.NonCentralPanorama(width, height, rc=room.rc))
    directions, distances, _, _ = ncjax.synth.room_walls(room)
    capacity = room.mask.shape[0]
    columns = jnp.sum(labels.wall_index[:, None] == jnp.arange(capacity), 0)
    usable = labels.ok & ~jnp.any(labels.corner_is_occlusion) & jnp.all(~room.mask | (columns >= MIN_COLUMNS))
    return dict(
        rc=room.rc,
        ceiling_v=labels.ceiling_v,
        floor_v=labels.floor_v,
        wall_index=labels.wall_index,
        mask=room.mask,
        corners=room.corners,
        directions=directions,
        distances=jnp.where(room.mask, distances, 0.0),
        labels=jnp.where(room.mask & (jnp.abs(directions @ directions[0]) < 0.5), 1, 0),
        h_c=room.ceiling_height,
        h_f=room.floor_height,
        usable=usable,
    )


def _noisy_rays(room, sigma, key, width, height):
    cam = ncjax.NonCentralPanorama(width, height, rc=room["rc"])
    columns = jnp.arange(width, dtype=room["ceiling_v"].dtype)
    k_c, k_f = jax.random.split(key)
    ceiling_v = room["ceiling_v"] + sigma * jax.random.normal(k_c, (width,))
    floor_v = room["floor_v"] + sigma * jax.random.normal(k_f, (width,))
    return ncjax.geometry.pixel_to_ray(cam, columns, ceiling_v), ncjax.geometry.pixel_to_ray(cam, columns, floor_v)


def _direction_error(a, b):
    """Degrees between line directions (sign-free), accurate near 0."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return jnp.degrees(jnp.arctan2(jnp.abs(cross), jnp.abs(jnp.sum(a * b, -1))))


def _depth(line):
    return jnp.linalg.norm(line[..., 3:], axis=-1)


def _masked_mean(x, mask):
    return jnp.sum(jnp.where(mask, x, 0.0)) / jnp.maximum(jnp.sum(mask), 1)


def _gt_lines(room):
    capacity = room["mask"].shape[0]
    line = lambda h: ncjax.geometry.horizontal_wall_line(room["directions"], room["distances"], jnp.full(capacity, h))  # noqa: E731
    return line(room["h_c"]), line(room["h_f"])


def _layout_metrics(room, layout):
    mask = room["mask"]
    gt_ceiling, gt_floor = _gt_lines(room)
    corner = 0.0
    for lines, height in ((layout.ceiling_lines, room["h_c"]), (layout.floor_lines, room["h_f"])):
        corners = ncjax.solvers.layout_corners(lines, layout.mask)
        truth = jnp.concatenate([room["corners"], jnp.full((mask.shape[0], 1), height)], -1)
        corner = corner + 0.5 * _masked_mean(jnp.linalg.norm(corners - truth, axis=-1), mask)
    depth = 0.5 * (
        _masked_mean(jnp.abs(_depth(layout.ceiling_lines) - _depth(gt_ceiling)), mask)
        + _masked_mean(jnp.abs(_depth(layout.floor_lines) - _depth(gt_floor)), mask)
    )
    direction = _masked_mean(_direction_error(layout.directions, room["directions"]), mask)
    return dict(corner=corner, direction=direction, depth=depth, ok=layout.ok.astype(jnp.float32))


def manhattan(room, ceiling_rays, floor_rays, method="refined"):
    layout = ncjax.solvers.solve_manhattan_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["labels"], method=method
    )
    return _layout_metrics(room, layout)


def atlanta(room, ceiling_rays, floor_rays, method="refined"):
    layout = ncjax.solvers.solve_atlanta_layout(
        ceiling_rays, floor_rays, room["wall_index"], room["mask"], room["directions"], method=method
    )
    return _layout_metrics(room, layout)


def baseline(room, ceiling_rays, floor_rays):
    """[bermudez2016line]: every ceiling and floor line fitted alone."""
    gt_ceiling, gt_floor = _gt_lines(room)
    direction, depth = 0.0, 0.0
    for rays, truth in ((ceiling_rays, gt_ceiling), (floor_rays, gt_floor)):
        lines = ncjax.solvers.solve_horizontal_lines(rays, room["wall_index"], room["mask"].shape[0])
        direction = direction + 0.5 * _masked_mean(_direction_error(lines.direction, room["directions"]), room["mask"])
        depth = depth + 0.5 * _masked_mean(jnp.abs(_depth(lines.line) - _depth(truth)), room["mask"])
    return dict(corner=jnp.nan, direction=direction, depth=depth, ok=jnp.float32(1.0))


def single_walls(room, ceiling_rays, floor_rays, method="refined"):
    """Every wall with the single-wall solver (the ablation of the parallelism constraint)."""
    capacity = room["mask"].shape[0]
    masks = room["wall_index"][None, :] == jnp.arange(capacity)[:, None]
    walls = jax.vmap(lambda m: ncjax.solvers.solve_wall(ceiling_rays, floor_rays, m, m, method=method))(masks)
    gt_ceiling, _ = _gt_lines(room)
    return dict(
        corner=jnp.nan,
        direction=_masked_mean(_direction_error(walls.direction, room["directions"]), room["mask"]),
        depth=_masked_mean(jnp.abs(_depth(walls.ceiling_line) - _depth(gt_ceiling)), room["mask"]),
        ok=_masked_mean(walls.ok.astype(jnp.float32), room["mask"]),
    )


class Sweep:
    """All (level, draw, room) cases of one method as ONE jitted call, split over the CPU devices.

    ``rooms`` holds the room arrays per rc level (leading axis; only their
    shapes are kept: :meth:`run` takes the arrays). ``levels`` is
    a list of ``(sigma, rc_index, draws)``: noise ``sigma`` on the rooms of rc
    level ``rc_index``, ``draws`` noise draws per room. The cases are padded
    to a multiple of the device count and each device maps over its share
    (``shard_map`` of ``lax.map``), so every core works. :meth:`compile` and
    :meth:`run` are separate so that several sweeps compile at once
    (:func:`compile_all`).
    """

    def __init__(self, method, rooms, room_ids, levels, width, height, batch_size=32):
        sigmas = np.concatenate([np.full(draws * len(room_ids), sigma, np.float32) for sigma, _, draws in levels])
        rc_index = np.concatenate([np.full(draws * len(room_ids), rc) for _, rc, draws in levels])
        room_index = np.concatenate([np.tile(room_ids, draws) for _, _, draws in levels])
        self.n_cases = len(sigmas)
        self.bounds = np.cumsum([0] + [draws * len(room_ids) for _, _, draws in levels])
        devices = jax.devices()
        padded = -(-self.n_cases // (len(devices) * batch_size)) * len(devices) * batch_size
        pad = lambda x: np.concatenate([x, np.repeat(x[:1], padded - self.n_cases, 0)])  # noqa: E731
        cases = (
            pad(rc_index),
            pad(room_index),
            pad(np.asarray(jax.random.key_data(jax.random.split(jax.random.PRNGKey(12345), self.n_cases)))),
            pad(sigmas),
        )

        def one(case, rooms):
            rc, room_index, key, sigma = case
            room = jax.tree.map(lambda x: x[rc, room_index], rooms)
            result = method(room, *_noisy_rays(room, sigma, jax.random.wrap_key_data(key), width, height))
            return {k: jnp.where(room["usable"], v, jnp.nan) for k, v in result.items()}

        mesh = jax.make_mesh((len(devices),), ("cases",), devices=devices)
        self._function = jax.jit(
            jax.shard_map(
                lambda c, r: jax.lax.map(lambda case: one(case, r), c, batch_size=batch_size),
                mesh=mesh,
                in_specs=(P("cases"), P()),
                out_specs=P("cases"),
                check_vma=False,
            )
        )
        self._cases = jax.device_put(cases, NamedSharding(mesh, P("cases")))
        self._rooms_sharding = NamedSharding(mesh, P())
        self._room_shapes = jax.tree.map(
            lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=self._rooms_sharding), rooms
        )
        self._compiled = None

    def compile(self) -> None:
        self._compiled = self._function.lower(self._cases, self._room_shapes).compile()

    def run(self, rooms) -> dict:
        """A dict of lists (one array of ``draws * len(room_ids)`` values per level); unusable rooms' cases are NaN."""
        if self._compiled is None:
            self.compile()
        output = self._compiled(self._cases, jax.device_put(rooms, self._rooms_sharding))
        result = {k: np.asarray(v)[: self.n_cases] for k, v in output.items()}
        return {
            k: [v[lo:hi] for lo, hi in zip(self.bounds[:-1], self.bounds[1:], strict=False)] for k, v in result.items()
        }


def compile_all(sweeps) -> None:
    """Compile the sweeps in parallel threads (XLA compiles outside the GIL)."""
    with concurrent.futures.ThreadPoolExecutor(os.cpu_count()) as pool:
        list(pool.map(Sweep.compile, sweeps))


def _stat(values, fn):
    values = values[np.isfinite(values)]
    return float(fn(values)) if values.size else float("nan")


def _summary(result, level):
    """Mean and median of each metric at one level (the median also under the bare metric name)."""
    summary = {
        f"{m}_{stat}": _stat(result[m][level], fn)
        for m in ("corner", "direction", "depth")
        for stat, fn in (("mean", np.mean), ("median", np.median))
    }
    return summary | {m: summary[f"{m}_median"] for m in ("corner", "direction", "depth")}


def _write(path, x_name, xs, results):
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["method", x_name, "metric", "mean", "median", "ok_rate", "cases"])
        for method, res in results.items():
            for i, x in enumerate(xs):
                for metric in ("corner", "direction", "depth"):
                    values = res[metric][i]
                    writer.writerow(
                        [
                            method,
                            f"{x:.4f}",
                            metric,
                            _stat(values, np.mean),
                            _stat(values, np.median),
                            _stat(res["ok"][i], np.mean),
                            int(np.isfinite(res["ok"][i]).sum()),
                        ]
                    )


def _plot(path, x_name, xs, results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {"manhattan": "tab:blue", "atlanta": "tab:green", "baseline": "tab:red"}
    labels = {"corner": "corner error (m)", "direction": "direction error (deg)", "depth": "depth error (m)"}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, metric in zip(axes, ("corner", "direction", "depth"), strict=False):
        for method, res in results.items():
            base = method.split("/")[0]
            values = np.array([_stat(v, np.mean) for v in res[metric]])
            if np.all(np.isnan(values)) or (metric == "direction" and base == "atlanta"):
                continue  # Atlanta directions are the prior (error 0); the baseline has no corners
            style = "o-" if "paper" not in method else "x--"
            ax.plot(xs, np.maximum(values, 1e-12), style, color=colours[base], label=method)
        ax.set_yscale("log")
        ax.set_xlabel(x_name)
        ax.set_ylabel(labels[metric])
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="quick version (CI)")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--rooms", type=int, default=200, help="rooms of the full sweep (half Manhattan)")
    parser.add_argument("--draws", type=int, default=20, help="noise draws per room and sigma (full sweep)")
    args = parser.parse_args(argv)
    warnings.filterwarnings("ignore", category=RuntimeWarning)  # nan-means of the baseline's (absent) corners
    if args.small:
        n_rooms, draws, rc_draws, ablation_draws = 8, 2, 1, 1
        sigmas, rcs, width, height = np.linspace(0, 2, 3), np.array([0.2, 1.0]), 256, 128
    else:
        n_rooms, draws, rc_draws, ablation_draws = args.rooms, args.draws, 5, 2
        sigmas, rcs, width, height = np.linspace(0, 2, 9), np.linspace(0.1, 1.0, 10), 1024, 512
    rc_default = 0.5
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    levels = np.concatenate([[rc_default], rcs])
    arrays = jax.block_until_ready(
        jax.jit(rooms_per_rc, static_argnums=(2, 3))(
            generate_rooms(n_rooms), jnp.asarray(levels, jnp.float32), width, height
        )
    )
    usable = np.asarray(arrays["usable"])
    timings = {"rooms and labels": time.perf_counter() - start}
    manhattan_ids, all_ids = np.arange(n_rooms // 2), np.arange(n_rooms)  # generate_rooms' order
    methods = {  # name: (function, rooms)
        "manhattan": (manhattan, manhattan_ids),
        "atlanta": (atlanta, all_ids),
        "baseline": (baseline, all_ids),
    }
    sigma_levels = [(sigma, 0, draws) for sigma in sigmas]
    rc_levels = [(1.0, i + 1, rc_draws) for i in range(len(rcs))]
    sweeps = {
        name: Sweep(method, arrays, ids, sigma_levels + rc_levels, width, height)
        for name, (method, ids) in methods.items()
    }
    # refined vs the paper's solutions (parallelism quadratics; Atlanta: the literal null vector)
    # vs the unconstrained null vector, sigma = 1 px, Manhattan rooms (Atlanta solver: all rooms).
    # The layout solvers' refined rows are the sigma = 1 px level of the main sweep.
    ablation_sweeps = {
        f"{solver_name}/{label}": Sweep(
            lambda r, c, f, s=solver, m=label: s(r, c, f, method=m),
            arrays,
            ids,
            [(1.0, 0, ablation_draws)],
            width,
            height,
        )
        for solver_name, solver, labels, ids in (
            ("manhattan", manhattan, ("paper", "null_vector"), manhattan_ids),
            ("atlanta", atlanta, ("paper",), all_ids),
            ("single_wall", single_walls, ("refined", "paper", "null_vector"), manhattan_ids),
        )
        for label in labels
    }
    t0 = time.perf_counter()
    compile_all([*sweeps.values(), *ablation_sweeps.values()])
    timings["compilation"] = time.perf_counter() - t0
    print(
        f"rooms and labels {timings['rooms and labels']:.1f} s; compiled {len(sweeps) + len(ablation_sweeps)} sweeps "
        f"{timings['compilation']:.1f} s",
        flush=True,
    )
    results, rc_results = {}, {}
    for name, method_sweep in sweeps.items():
        t0 = time.perf_counter()
        both = method_sweep.run(arrays)
        results[name] = {k: v[: len(sigmas)] for k, v in both.items()}
        rc_results[name] = {k: v[len(sigmas) :] for k, v in both.items()}
        timings[name] = time.perf_counter() - t0
        print(f"{name} (sigma and rc sweeps): {timings[name]:.1f} s", flush=True)
    t0 = time.perf_counter()
    _write(args.out / "noise_sweep.csv", "sigma_px", sigmas, results)
    _plot(args.out / "noise_sweep.png", "sigma (px)", sigmas, results)
    _write(args.out / "rc_sweep.csv", "rc_m", rcs, rc_results)
    _plot(args.out / "rc_sweep.png", "rc (m) at sigma = 1 px", rcs, rc_results)
    timings["plots and CSV"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    one_px = int(np.argmin(np.abs(sigmas - 1.0)))
    ablation = {f"{name}/refined": _summary(results[name], one_px) for name in ("manhattan", "atlanta")}
    ablation.update({name: _summary(ablation_sweep.run(arrays), 0) for name, ablation_sweep in ablation_sweeps.items()})
    timings["ablation"] = time.perf_counter() - t0

    total = time.perf_counter() - start  # everything after the imports
    print(
        f"rooms {n_rooms} ({len(manhattan_ids)} Manhattan), usable at rc = {rc_default}: {usable[0].sum()}, "
        f"draws {draws}, {width}x{height}, rc = {rc_default} m (sigma sweep)"
    )
    print(
        f"wall time (2 cores, incl. compilation): total {total:.1f} s; "
        + ", ".join(f"{k} {v:.1f} s" for k, v in timings.items())
    )
    for name, res in results.items():
        print(f"  {name}")
        for i, sigma in enumerate(sigmas):
            print(
                f"    sigma {sigma:4.2f} px: corner {_stat(res['corner'][i], np.mean):.4f} / "
                f"{_stat(res['corner'][i], np.median):.4f} m, "
                f"direction {_stat(res['direction'][i], np.mean):.4f} / {_stat(res['direction'][i], np.median):.4f} "
                "deg, "
                f"depth {_stat(res['depth'][i], np.mean):.4f} / {_stat(res['depth'][i], np.median):.4f} m (mean / "
                "median), "
                f"ok {_stat(res['ok'][i], np.mean):.3f}"
            )
    print("rc sweep at sigma = 1 px (mean / median):")
    for name, res in rc_results.items():
        print(f"  {name}")
        for i, rc in enumerate(rcs):
            print(
                f"    rc {rc:.1f} m: corner {_stat(res['corner'][i], np.mean):.4f} / "
                f"{_stat(res['corner'][i], np.median):.4f} m, "
                f"depth {_stat(res['depth'][i], np.mean):.4f} / {_stat(res['depth'][i], np.median):.4f} m"
            )
    print("sigma = 1 px, mean / median: refined vs paper vs unconstrained null vector")
    for key, v in ablation.items():
        print(
            f"  {key:24s} corner {v['corner_mean']:.4f} / {v['corner_median']:.4f} m  direction "
            f"{v['direction_mean']:.4f} / "
            f"{v['direction_median']:.4f} deg  depth {v['depth_mean']:.4f} / {v['depth_median']:.4f} m"
        )
    return results, rc_results, ablation


if __name__ == "__main__":
    main()
