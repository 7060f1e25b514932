"""How well does ``ncjax.geometry.levelling.estimate_tilt`` recover the roll and pitch of tilted panoramas?

Rooms: ``--n`` synthetic rooms (Manhattan and Atlanta, furnished, ``rc = 0``, or a rig's radius in ``--rc``) rendered
level at ``--size`` by ``ncjax.synth`` into ``experiments/out/gravity_renders_<n>_<size>_<seed>/``
(on first use). Each is tilted by a random roll and pitch, uniform in
[-``--max-tilt``, ``--max-tilt``] degrees (seeded), by resampling
(``level_panorama(image, rotation.T)``), and the tilt is estimated from the tilted image.

Printed: the absolute roll and pitch errors and the angle between the true and the
estimated vertical (mean, median, max, degrees), the share of estimates flagged reliable,
the mean absolute grey-level difference between the levelled tilted image and the level
render (rows within 60 degrees of the horizon), and the wall-clock seconds per image (CPU) of
``estimate_tilt`` and of ``level_panorama``.

    uv run python experiments/gravity_alignment.py                 # 20 rooms at 512 x 1024
    uv run python experiments/gravity_alignment.py --n 4 --size 256x512
    uv run python experiments/gravity_alignment.py --rc 0.3:1.0 --max-tilt 2

With ``--rc`` the renders are a rig's, tilted by the same resampling: the image of a tilted rig to within its optical
centres' rc times the tilt (experiments/rig_tilt.py), which is what the estimate reads.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.geometry.gravity import rotation_from_tilt
from ncjax.geometry.levelling import estimate_tilt, level_panorama
from ncjax.synth.dataset import list_samples, read_sample, write_dataset

OUT = Path(__file__).parent / "out"
RENDER_SEED = 2024  # the rooms' seed (the tilts have their own, --seed)


def renders(n: int, height: int, width: int, out: Path, rc: tuple[float, float] = (0.0, 0.0)) -> list[np.ndarray]:
    """``n`` level panoramas (RGB uint8) of a rig of radius in ``rc`` (central by default), rendered on first use."""
    radii = "" if rc == (0.0, 0.0) else f"_rc{rc[0]:g}-{rc[1]:g}"
    folder = out / f"gravity_renders_{n}_{height}x{width}_{RENDER_SEED}{radii}"
    if not (folder.is_dir() and len(list_samples(str(folder))) == n):
        config = ncjax.SynthConfig(room=ncjax.RoomConfig(world="mix", rc_range=rc), width=width, height=height)
        with tqdm(total=n, desc=f"render {height}x{width}") as bar:
            write_dataset(str(folder), n, RENDER_SEED, config, batch_size=4, overwrite=True, progress=bar.update)
    return [read_sample(str(folder), name).image for name in list_samples(str(folder))]


def angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two unit vectors, degrees."""
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b))))


def summary(name: str, values) -> str:
    values = np.asarray(values, np.float64)
    return f"{name:<26} mean {values.mean():7.3f}  median {np.median(values):7.3f}  max {values.max():7.3f}"


def main(argv: list[str] | None = None) -> dict[str, np.ndarray]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=20, help="rooms (default 20)")
    parser.add_argument("--size", default="512x1024", help="HxW of the renders (default 512x1024)")
    parser.add_argument("--max-tilt", type=float, default=10.0, help="largest roll and pitch, degrees (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random tilts (default 0)")
    parser.add_argument("--out", type=Path, default=OUT, help="folder of the cached renders")
    parser.add_argument(
        "--rc", default="0", help="the rig's radius, metres, or a range LOW:HIGH (default 0: central panoramas)"
    )
    args = parser.parse_args(argv)
    height, width = (int(x) for x in args.size.lower().split("x"))
    try:
        bounds = [float(x) for x in args.rc.split(":")]
    except ValueError:
        bounds = []
    if len(bounds) not in (1, 2) or min(bounds) < 0 or bounds[0] > bounds[-1]:
        parser.error(f"--rc must be a radius >= 0 or a range LOW:HIGH, got {args.rc}")
    images = renders(args.n, height, width, args.out, (bounds[0], bounds[-1]))
    rng = np.random.default_rng(args.seed)
    tilts = rng.uniform(-args.max_tilt, args.max_tilt, size=(args.n, 2))
    estimate_tilt(images[0])  # warm-up (OpenCV's first calls)
    rows = slice(height // 6, height - height // 6)  # within 60 degrees of the horizon
    results: dict[str, list] = {k: [] for k in ("roll", "pitch", "vertical", "reliable", "segments", "residual")}
    times: dict[str, list] = {"estimate": [], "level": []}
    for image, (roll, pitch) in zip(images, tilts, strict=True):
        rotation = rotation_from_tilt(roll, pitch)
        tilted = level_panorama(image, rotation.T)
        start = time.perf_counter()
        estimate = estimate_tilt(tilted)
        times["estimate"].append(time.perf_counter() - start)
        start = time.perf_counter()
        levelled = level_panorama(tilted, estimate.rotation)
        times["level"].append(time.perf_counter() - start)
        results["roll"].append(abs(estimate.roll - roll))
        results["pitch"].append(abs(estimate.pitch - pitch))
        results["vertical"].append(angle_between(estimate.up, rotation[2]))
        results["reliable"].append(estimate.reliable)
        results["segments"].append(estimate.segments)
        difference = np.abs(levelled[rows].astype(np.float64) - image[rows].astype(np.float64)).mean()
        results["residual"].append(difference)
    print(
        f"{args.n} rooms at {height}x{width}, rc {args.rc} m, roll and pitch uniform in +-{args.max_tilt:g} deg "
        f"(seed {args.seed})"
    )
    print(summary("|roll error| (deg)", results["roll"]))
    print(summary("|pitch error| (deg)", results["pitch"]))
    print(summary("vertical error (deg)", results["vertical"]))
    print(summary("supporting segments", results["segments"]))
    print(summary("levelled - level (grey)", results["residual"]))
    print(f"{'reliable':<26} {np.mean(results['reliable']) * 100:.0f} %")
    print(summary("estimate_tilt (wall s)", times["estimate"]))
    print(summary("level_panorama (wall s)", times["level"]))
    return {k: np.asarray(v) for k, v in (results | times).items()}


if __name__ == "__main__":
    main()
