"""How ``ncjax reconstruct`` develops a linear HDR panorama: the local compression of its light, measured.

An HDR panorama file (Radiance ``.hdr``, OpenEXR) holds the scene's light, not a picture: windows hundreds of times
brighter than the walls. ``ncjax.io.images.develop_hdr`` develops it as a 360-degree camera's HDR capture does: the
large-scale light compressed in log luminance by ``HDR_LOCAL_COMPRESSION`` (1 leaves it, a single exposure), metered
to 18% grey, a filmic tone curve. Which compression the network reads best is measured two ways, each through the
product's own reader (the constant set for the run):

- **Labelled**: ``--rooms`` central home rooms (``synth-photoreal-home``'s rooms, seed ``--seed``) path-traced at
  the network's 512 x 1024 (``ncjax.synth.photoreal.photoreal_radiance``: interreflection, the windows' real CC0
  views and sun), written as Radiance ``.hdr`` files with their ``label_cor``, scored by
  ``benchmarks/real_panoramas.py`` (rows in px of a 512-row image). About 15 s a room on 2 cores, once (kept in
  ``--out``).
- **Real, unlabelled**: the indoor CC0 HDR photographs of ``--hdri`` (apartment, hall, lab, lobby, studio,
  warehouse, workshop): how far each compression moves the network's rows from those of the default (mean absolute
  difference over the columns, px of 512). Without labels this says how much the choice matters on photographs,
  not which is right.

    uv run python experiments/hdr_development.py [--rooms 24] [--seed 1701] [--compressions 1 0.8 0.6 0.4]
        [--hdri ../shared/data/cc0-hdri]
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib

import cv2
import jax
import jax.numpy as jnp
import numpy as np

import ncjax.io.images as images
from ncjax.network.predict import predict_boundaries
from ncjax.synth.dataset import label_cor_rows, rendered_samples
from ncjax.synth.photoreal import photoreal_radiance, window_views
from ncjax.training.data import SYNTH_SOURCES

from common import benchmark_module, csv_means, quietly

real_panoramas = benchmark_module("real_panoramas")

OUT = pathlib.Path(__file__).resolve().parent / "out" / "hdr_development"
HDRI = pathlib.Path(__file__).resolve().parents[2] / "shared" / "data" / "cc0-hdri"
KIND = "synth-photoreal-home"
HEIGHT, WIDTH = 512, 1024
INDOOR_HDRI = ("apartment", "hall", "lab", "lobby", "studio", "warehouse", "workshop")


def write_radiance_rooms(folder: pathlib.Path, rooms: int, seed: int) -> None:
    """``rooms`` central rooms of :data:`KIND` path-traced as Radiance ``.hdr`` files with their ``label_cor``, in
    ``folder`` (rooms already there are kept)."""
    folder.mkdir(parents=True, exist_ok=True)
    source = SYNTH_SOURCES[KIND]
    central = dataclasses.replace(source.room, rc_range=(0.0, 0.0))
    # The scenes and labels from the ray caster (cheap); the light from the path tracer below.
    config = dataclasses.replace(source, room=central, photoreal=None, width=WIDTH, height=HEIGHT)
    views = jnp.asarray(window_views())
    traced = jax.jit(photoreal_radiance, static_argnames="config")
    for index, scene, _, labels in rendered_samples(rooms, seed, config, batch_size=4):
        name = f"room_{index:03d}"
        if (folder / f"{name}.hdr").is_file():
            continue
        cam = scene.room.camera(WIDTH, HEIGHT)
        key = jax.random.fold_in(jax.random.key(seed), index)
        radiance = np.asarray(traced(key, jax.tree.map(jnp.asarray, scene), cam, views, config=source.photoreal))
        (folder / f"{name}.txt").write_text("".join(f"{x} {y}\n" for x, y in label_cor_rows(labels, cam)))
        cv2.imwrite(str(folder / f"{name}.hdr"), np.ascontiguousarray(radiance[..., ::-1], np.float32))
        print(f"rendered {name} ({index + 1} of {rooms})", flush=True)


def benchmark_row(folder: pathlib.Path, out: pathlib.Path) -> list[str]:
    """The benchmark's means of ``folder``: ceiling, floor, signed floor px, P / R 1%, raw 3D IoU."""
    quietly(real_panoramas.run, real_panoramas.parse_arguments(["--data", str(folder), "--out", str(out)]))
    means = csv_means(out / real_panoramas.CSV_NAME)
    every = next(row for name, row in means.items() if name.split(" (")[0] == "mean")
    return [
        f"{float(every['ceiling_error_px']):.1f}",
        f"{float(every['floor_error_px']):.1f}",
        f"{float(every['floor_signed_error_px']):+.1f}",
        f"{float(every['precision_1pct']):.2f} / {float(every['recall_1pct']):.2f}",
        f"{float(every['iou_3d']):.3f}",
    ]


def network_rows(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """The network's ceiling and floor rows of a panorama file, in rows of a 512-row image."""
    image = quietly(images.read_panorama, path)
    ceiling, floor, _ = predict_boundaries(image)
    scale = 512 / image.shape[0]
    return ceiling * scale, floor * scale


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=24)
    parser.add_argument("--seed", type=int, default=1701)
    parser.add_argument("--compressions", type=float, nargs="+", default=[1.0, 0.8, 0.6, 0.4])
    parser.add_argument("--hdri", type=pathlib.Path, default=HDRI, help=f"the CC0 HDR photographs (default {HDRI})")
    parser.add_argument("--out", type=pathlib.Path, default=OUT)
    args = parser.parse_args(argv)
    if any(not 0 < c <= 1 for c in args.compressions):
        parser.error("--compressions must be in (0, 1]")
    default = images.HDR_LOCAL_COMPRESSION
    rooms = args.out / f"{KIND}_{args.seed}_{args.rooms}"
    write_radiance_rooms(rooms, args.rooms, args.seed)
    hdri = [args.hdri / f"{name}.exr" for name in INDOOR_HDRI if (args.hdri / f"{name}.exr").is_file()]
    reference = {path: network_rows(path) for path in hdri}

    header = "| local compression | ceiling px | floor px | floor signed px | P / R 1% | raw 3D IoU |"
    header += f" real HDR ({len(hdri)}): ceiling / floor rows moved, px |"
    print(header)
    print("| --- " * 7 + "|")
    for compression in args.compressions:
        images.HDR_LOCAL_COMPRESSION = compression
        cells = benchmark_row(rooms, args.out / f"compression_{compression:g}")
        moved = np.array(
            [
                [np.mean(np.abs(a - b)) for a, b in zip(network_rows(path), reference[path], strict=True)]
                for path in hdri
            ]
        )
        cells.append("-" if not hdri else f"{moved[:, 0].mean():.1f} / {moved[:, 1].mean():.1f}")
        label = f"{compression:g}" + (" (a single exposure)" if compression == 1 else "")
        label += " (the default)" if compression == default else ""
        print(f"| {label} | {' | '.join(cells)} |", flush=True)
    images.HDR_LOCAL_COMPRESSION = default
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
