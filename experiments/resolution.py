"""Metric accuracy against the panorama's resolution: is the CLI's cap at 2048 columns (``MAX_WIDTH``) costing accuracy?

The network always reads the panorama shrunk to 1024 x 512, but its rows are then
snapped to the edges of the full-size image (:mod:`ncjax.network.edges`) and the geometry
runs on every column, so a larger panorama could fix the boundaries, and with them
the metric scale, better.

Rooms: the first ``--rooms`` tuning rooms of ``tune_network_pipeline.py`` (seeds
71 and 72: never the test renders), rendered once at 4096 x 2048 into
``experiments/out/resolution_renders_<world>_<rooms>_4096/``. Each panorama is
shrunk by pixel-area averaging (``cv2.INTER_AREA``, as a camera's sensor
integrates light: no aliasing) to each width of ``--widths`` and reconstructed
with ``ncjax.reconstruct_batch`` (the shipped model and configuration).

Per world and width: the share of rooms given an ok layout, the share flagged
``UNCERTAIN_SCALE``, the room-height error (median and 90th percentile, m) and
the relative height sigma (median) of the ok layouts, CE (median, m) of those with
the true corner count, 3D IoU of the ok layouts and over all rooms (no layout: 0),
and the seconds per panorama (compilation excluded).

    uv run python experiments/resolution.py                  # 32 rooms per world, widths 1024 2048 4096
    uv run python experiments/resolution.py --rooms 4 --widths 1024 2048
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import cv2
import jax
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.pipeline.uncertainty import room_height_sigma
from ncjax.reconstruction import reconstruct_batch
from ncjax.synth.dataset import list_samples, read_sample, write_dataset

from common import TUNING_SEEDS, ground_truth, layout_scores

OUT = Path(__file__).parent / "out"
RENDER_WIDTH = 4096
BATCH = 4


def renders(world: str, rooms: int, out: Path) -> list:
    """The first ``rooms`` tuning rooms of ``world`` at RENDER_WIDTH x RENDER_WIDTH / 2 (rendered on first use)."""
    folder = out / f"resolution_renders_{world}_{rooms}_{RENDER_WIDTH}"
    if not (folder.is_dir() and len(list_samples(str(folder))) == rooms):
        config = ncjax.SynthConfig(
            room=ncjax.RoomConfig(world=world, rc_range=(0.3, 1.0)), width=RENDER_WIDTH, height=RENDER_WIDTH // 2
        )
        with tqdm(total=rooms, desc=f"render {world} at {RENDER_WIDTH}") as bar:
            write_dataset(
                str(folder), rooms, TUNING_SEEDS[world], config, batch_size=1, overwrite=True, progress=bar.update
            )
    return [read_sample(str(folder), name) for name in list_samples(str(folder))]


def shrunk(image: np.ndarray, width: int) -> np.ndarray:
    """``image`` at ``width`` x ``width / 2`` by pixel-area averaging."""
    return image if image.shape[1] == width else cv2.resize(image, (width, width // 2), interpolation=cv2.INTER_AREA)


def layouts_at(samples, world: str, width: int):
    """The layouts (ok or not) of ``samples`` shrunk to ``width``, and the seconds per panorama after the first
    batch (the reconstruction alone: the images are shrunk before the clock starts)."""
    images = [shrunk(s.image, width) for s in samples]
    layouts, started = [], None
    for start in tqdm(range(0, len(samples), BATCH), desc=f"reconstruct {world} at {width}"):
        chunk = list(range(start, min(start + BATCH, len(samples))))
        chunk = chunk + [chunk[-1]] * (BATCH - len(chunk))
        batch = np.stack([images[i] for i in chunk])
        radii = np.array([samples[i].rc for i in chunk], np.float32)
        result = jax.device_get(reconstruct_batch(batch, radii, world).layout)
        layouts += [jax.tree.map(lambda x: x[i], result) for i in range(min(BATCH, len(samples) - start))]
        started = started or (time.perf_counter(), start + BATCH)
    timed = len(samples) - started[1]
    return layouts, (time.perf_counter() - started[0]) / timed if timed > 0 else math.nan


def width_scores(layouts, truths) -> dict:
    """One line of the table: the scores of one world's layouts at one width (see the module docstring)."""
    per_room = layout_scores(layouts, truths)
    ok = [r for r in per_room if r["returned"]]
    strict = [r["ce"] for r in ok if not r["failed"]]
    height_error = np.array([r["height_error"] for r in ok])
    sigma = np.array(
        [
            float(room_height_sigma(layout.height_covariance)) / float(layout.ceiling_height - layout.floor_height)
            for layout in layouts
            if bool(layout.ok)
        ]
    )
    uncertain = [int(layout.status) == ncjax.LayoutStatus.UNCERTAIN_SCALE for layout in layouts]
    pct = lambda values, q: float(np.percentile(values, q)) if len(values) else math.nan  # noqa: E731
    return {
        "rooms": len(per_room),
        "ok": 100 * len(ok) / len(per_room),
        "uncertain_scale": 100 * float(np.mean(uncertain)),
        "height_error_median": pct(height_error, 50),
        "height_error_p90": pct(height_error, 90),
        "relative_sigma_median": pct(sigma, 50),
        "ce_median": pct(strict, 50),
        "true_corner_count": 100 * len(strict) / len(per_room),
        "iou3d_ok": 100 * float(np.mean([r["iou3d"] for r in ok])) if ok else math.nan,
        "iou3d_all": 100 * float(np.sum([r["iou3d"] for r in ok])) / len(per_room),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=32, help="tuning rooms per world")
    parser.add_argument("--widths", type=int, nargs="+", default=[1024, 2048, 4096])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    if any(w % 2 or not 64 <= w <= RENDER_WIDTH for w in args.widths):
        parser.error(f"widths must be even and in [64, {RENDER_WIDTH}]")
    start = time.time()
    lines = [
        f"Tuning rooms rendered at {RENDER_WIDTH} x {RENDER_WIDTH // 2}, shrunk by area averaging; "
        f"{args.rooms} rooms per world; shipped model and configuration.",
        "",
        "| world | width | ok (%) | uncertain scale (%) | height error median / p90 (m) | height sigma / height, "
        "median | "
        "true corner count (%) | CE median (m) | 3D IoU ok / all rooms (%) | s per panorama |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    record = {"rooms": args.rooms, "render_width": RENDER_WIDTH}
    for world in TUNING_SEEDS:
        samples = renders(world, args.rooms, args.out)
        truths = [ground_truth(s, world) for s in samples]
        for width in args.widths:
            layouts, seconds = layouts_at(samples, world, width)
            r = width_scores(layouts, truths) | {"seconds_per_panorama": seconds}
            record[f"{world}_{width}"] = r
            lines.append(
                f"| {world} | {width} | {r['ok']:.1f} | {r['uncertain_scale']:.1f} | {r['height_error_median']:.3f} / "
                f"{r['height_error_p90']:.3f} | {r['relative_sigma_median']:.3f} | {r['true_corner_count']:.1f} | "
                f"{r['ce_median']:.3f} | {r['iou3d_ok']:.1f} / {r['iou3d_all']:.1f} | {seconds:.2f} |"
            )
    table = "\n".join(lines)
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    name = f"resolution_{args.rooms}"
    (args.out / f"{name}.md").write_text(table + "\n")
    (args.out / f"{name}.json").write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
