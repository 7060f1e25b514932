"""A slightly tilted rig: how much of the scale it costs, and how much levelling its image as a central one gives back.

A rig on a tripod is never quite level. Tilted by ``tau``, its rows of a level room wave by up to ``tau`` (0.1 degree
is 0.28 px of a 512-row panorama), the order of what fixes its scale (``experiments/parallax_budget.py``). A central
panorama is levelled exactly by resampling its directions (:func:`ncjax.geometry.levelling.level_panorama`); a
non-central one is not, as its optical centres stay on the tilted circle, but the centres move by ``rc tau`` at most:
what resampling leaves is about ``rc / range`` of the tilt.

Rooms: ``ncjax.synth.random_room`` (Manhattan, no occlusion, rc ``--rc``), exact boundaries. Each room's visible
boundary points (its labels at 8 times the panorama's width) are projected into the rig tilted about a random
horizontal axis by ``tau`` (its frame the room's turned by the tilt; optical centres on the tilted circle), giving the
tilted rig's exact rows; levelled as ``ncjax reconstruct`` levels a central panorama (each tilted pixel's direction
turned back by the true tilt: what the estimate gives to 0.03 degrees, RESULTS "Levelling tilted panoramas").
The pipeline (``PipelineConfig()``, the Manhattan world, the exact corner targets) lays out the level rig's rows, the
tilted rows and the levelled rows. Printed per tilt: the median and 90th percentile of the room height's relative
error, and the mean 3D IoU (no layout as 0).

With ``--renders N`` it also levels the first N non-central test renders of each world (level, rc 0.3-1.0 m; the
shipped model's rows, ``NETWORK_PIPELINE_CONFIG``) with their estimated tilt and prints the tilts read, and the
layouts' mean 3D IoU (no layout as 0) and room height's median relative error as they are and levelled: what
levelling an image that needs none costs.

    uv run python experiments/rig_tilt.py [--rooms 32] [--tilts 0.1 0.25 0.5 1] [--rc 0.6] [--renders 32]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.cli.outputs import align_to_gravity
from ncjax.evaluation import layout_metrics
from ncjax.geometry.camera import project
from ncjax.geometry.gravity import input_to_level_pixels, rotation_from_tilt
from ncjax.synth.dataset import list_samples, read_sample

from common import ground_truth, test_renders

WIDTH, HEIGHT = 1024, 512
OUT = Path(__file__).parent / "out"
DENSITY = 8  # boundary points per column of the panorama, to interpolate the tilted rows from
SEED = 0


def generate_rooms(count: int, rc: float) -> ncjax.synth.Room:
    """``count`` Manhattan rooms without occlusion whose circle of optical centres has radius ``rc``."""
    config = ncjax.RoomConfig(world="manhattan", max_walls=8, capacity=16, occlusion="none", rc_range=(rc, rc))
    keys = jax.random.split(jax.random.PRNGKey(SEED), 2 * count)
    rooms = jax.jit(jax.vmap(lambda key: ncjax.synth.random_room(key, config)))(keys)
    index = np.nonzero(np.asarray(rooms.ok))[0][:count]
    return jax.tree.map(lambda x: x[index], rooms)


def column_rows(u: np.ndarray, v: np.ndarray, width: int) -> np.ndarray:
    """Each column's row, linearly between the samples ``(u, v)`` around the panorama (wrap-around)."""
    order = np.argsort(u)
    u, v = u[order], v[order]
    u = np.concatenate([u[-1:] - width, u, u[:1] + width])
    v = np.concatenate([v[-1:], v, v[:1]])
    return np.interp(np.arange(width, dtype=np.float64), u, v)


def tilted_rows(points: np.ndarray, cam, tilt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels of ``points`` (room frame) in the rig whose frame is the room's turned by ``tilt`` (rig = tilt^T room)."""
    u, v = project(cam, points @ tilt)  # row vectors: p @ tilt = tilt^T p
    return np.asarray(u, np.float64), np.asarray(v, np.float64)


class ExactBoundaries(NamedTuple):
    """What a room's tilted views are made from, computed once per room."""

    rc: float
    level: tuple[np.ndarray, np.ndarray]  # the level rig's ceiling and floor rows
    target: np.ndarray  # its corner target
    points: tuple[np.ndarray, np.ndarray]  # the visible ceiling and floor boundary points, DENSITY per column


def exact_boundaries(room) -> ExactBoundaries:
    """The level rig's rows and corner target of ``room``, and its visible boundary points."""
    level = ncjax.synth.room_labels(room, ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=room.rc))
    dense = ncjax.synth.room_labels(room, ncjax.NonCentralPanorama(DENSITY * WIDTH, HEIGHT, rc=room.rc))
    return ExactBoundaries(
        float(room.rc),
        (np.asarray(level.ceiling_v, np.float64), np.asarray(level.floor_v, np.float64)),
        np.asarray(level.corner_target),
        (np.asarray(dense.ceiling_points, np.float64), np.asarray(dense.floor_points, np.float64)),
    )


def room_rows(boundaries: ExactBoundaries, tau: float, rng: np.random.Generator) -> dict[str, tuple[np.ndarray, ...]]:
    """The level, tilted and levelled rows (ceiling, floor) of one room, tilted by ``tau`` about a random axis."""
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=boundaries.rc)
    axis = rng.uniform(0.0, 2.0 * np.pi)
    tilt = rotation_from_tilt(tau * np.cos(axis), tau * np.sin(axis))
    tilted, levelled = [], []
    for points in boundaries.points:
        u, v = tilted_rows(points, cam, tilt)
        tilted.append(column_rows(u, v, WIDTH))
        # where a central levelling moves each tilted pixel: its direction turned back by the tilt
        levelled.append(column_rows(*input_to_level_pixels(u, v, tilt, WIDTH, HEIGHT), WIDTH))
    return {"level": boundaries.level, "tilted": tuple(tilted), "levelled": tuple(levelled)}


def ok_scores(layouts, truths: list, true_heights: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Each layout's relative room-height error (NaN: not ok) and 3D IoU against its truth (0: not ok)."""
    errors, ious = [], []
    for i, (truth, true_height) in enumerate(zip(truths, true_heights, strict=True)):
        layout = jax.tree.map(lambda x, i=i: x[i], layouts)
        ok = bool(layout.ok)
        ious.append(layout_metrics.iou_3d(layout, truth) if ok else 0.0)
        height = float(layout.ceiling_height - layout.floor_height)
        errors.append(abs(height / true_height - 1.0) if ok else np.nan)
    return np.array(errors), np.array(ious)


def rows_cell(rooms, rows: list[tuple[np.ndarray, np.ndarray]], targets: np.ndarray) -> str:
    """The table cell of the rooms laid out from ``rows``: the room height's relative error median / p90 and the mean
    3D IoU (%)."""
    cam = ncjax.NonCentralPanorama(WIDTH, HEIGHT, rc=jnp.asarray(rooms.rc))
    layouts = ncjax.layout_from_boundaries(
        np.stack([r[0] for r in rows]), np.stack([r[1] for r in rows]), targets, cam, world="manhattan"
    )
    count = len(rows)
    truths = [jax.tree.map(lambda x, i=i: x[i], rooms) for i in range(count)]
    errors, ious = ok_scores(layouts, truths, [float(r.ceiling_height - r.floor_height) for r in truths])
    median, p90 = 100 * np.nanquantile(errors, [0.5, 0.9])
    return f"{median:.1f} / {p90:.1f}, {100 * ious.mean():.1f}"


def level_renders(count: int) -> None:
    """The ``--renders`` part (module docstring)."""
    print(f"\n{count} level non-central test renders per world, the shipped model's rows:")
    print("| world | tilt read (degrees): median / max | as they are: 3D IoU, height error | levelled |")
    print("| --- | --- | --- | --- |")
    for world in ("manhattan", "atlanta"):
        folder = test_renders(world, count, OUT)
        samples = [read_sample(str(folder), name) for name in list_samples(str(folder))[:count]]
        images = np.stack([sample.image for sample in samples])
        radii = np.array([sample.rc for sample in samples], np.float32)
        aligned = [align_to_gravity(image) for image in images]  # every one levelled, however little its tilt
        levelled = np.stack([image for image, _ in aligned])
        tilts = [np.hypot(r["roll_deg"], r["pitch_deg"]) if r["reliable"] else 0.0 for _, r in aligned]
        truths = [ground_truth(sample, world) for sample in samples]
        true_heights = [sample.metadata["ceiling_height"] - sample.metadata["floor_height"] for sample in samples]
        cells = []
        for batch in (images, levelled):
            result = ncjax.reconstruct_batch(batch, radii, world, batch_size=8)
            errors, ious = ok_scores(result.layout, truths, true_heights)
            cells.append(f"{100 * np.mean(ious):.2f}%, {100 * np.nanmedian(errors):.2f}%")
        print(f"| {world} | {np.median(tilts):.3f} / {np.max(tilts):.3f} | " + " | ".join(cells) + " |", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=32, help="rooms per tilt")
    parser.add_argument("--tilts", type=float, nargs="+", default=[0.1, 0.25, 0.5, 1.0], help="degrees")
    parser.add_argument("--rc", type=float, default=0.6, help="radius of the circle of optical centres (m)")
    parser.add_argument("--renders", type=int, default=0, help="also level this many test renders per world")
    args = parser.parse_args(argv)
    if args.rooms < 1 or args.rc <= 0 or min(args.tilts) < 0 or args.renders < 0:
        parser.error("--rooms must be >= 1, --rc > 0, the tilts and --renders >= 0")
    rooms = generate_rooms(args.rooms, args.rc)
    count = int(rooms.rc.shape[0])
    boundaries = [exact_boundaries(jax.tree.map(lambda x, i=i: x[i], rooms)) for i in range(count)]
    targets = np.stack([b.target for b in boundaries])
    rng = np.random.default_rng(SEED)
    print(f"{count} Manhattan rooms, rc {args.rc} m; room height's relative error median / p90 (%), mean 3D IoU (%)")
    print("| tilt (degrees) | level rig | tilted | tilted, levelled as a central panorama |")
    print("| --- | --- | --- | --- |")
    level = rows_cell(rooms, [b.level for b in boundaries], targets)  # the same for every tilt
    for tau in args.tilts:
        per_room = [room_rows(b, tau, rng) for b in boundaries]
        cells = [level] + [rows_cell(rooms, [r[name] for r in per_room], targets) for name in ("tilted", "levelled")]
        print(f"| {tau:g} | " + " | ".join(cells) + " |", flush=True)
    if args.renders:
        level_renders(args.renders)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
