"""Time and memory of reading a large linear HDR panorama: developed at the working width, against at its own size.

    uv run python benchmarks/bench_hdr_input.py [--width 8192]

Writes a ``--width`` x ``--width / 2`` Radiance ``.hdr`` panorama (a synthetic room's light: walls of a few levels,
a window 200 times brighter, fine texture) to a temporary folder, then, each in a fresh process, reads it as
``ncjax reconstruct`` does (:func:`ncjax.io.images.read_panorama_file`: developed at the working width
:data:`ncjax.io.images.MAX_WIDTH`, brought back, resized to the working width), and reads it so with the
development at the file's own size instead (:func:`ncjax.io.images.develop_hdr` without its width limit). Prints each
one's wall time and peak resident memory (the process's, Python and jax included; Linux), and how far apart the two
images are at the working width (mean and 99th percentile of |difference|, grey levels).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile

import cv2
import numpy as np

READ = """
import sys, time, resource, warnings
import numpy as np
from ncjax.io import images
warnings.simplefilter("ignore")
if sys.argv[3] == "own size":  # the development at the file's own size, the reader otherwise the same
    develop_at_working_width, working_width = images.develop_hdr, images.MAX_WIDTH

    def develop_at_own_size(radiance):
        images.MAX_WIDTH = radiance.shape[1]  # develop_hdr's width limit only, for the call
        try:
            return develop_at_working_width(radiance)
        finally:
            images.MAX_WIDTH = working_width

    images.develop_hdr = develop_at_own_size  # to_rgb8 looks it up when it is called
started = time.perf_counter()
image = images.read_panorama_file(sys.argv[1]).image
seconds = time.perf_counter() - started
np.save(sys.argv[2], image)
print(seconds, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)  # Linux: KiB
"""


def room_light(width: int) -> np.ndarray:
    """A linear RGB panorama (width / 2, width, 3), float32: walls of a few levels of light with a fine texture,
    a window 200 times brighter."""
    height = width // 2
    rng = np.random.default_rng(0)
    walls = cv2.resize(
        rng.uniform(0.02, 0.2, (8, 16, 3)).astype(np.float32), (width, height), interpolation=cv2.INTER_NEAREST
    )
    texture = cv2.resize(rng.uniform(0.8, 1.2, (height // 8, width // 8)).astype(np.float32), (width, height))
    light = walls * texture[..., None]
    light[height // 4 : height // 2, width // 3 : width // 2] = 30.0
    return light


def run(hdr: pathlib.Path, out: pathlib.Path, development: str) -> tuple[float, float, np.ndarray]:
    """Read ``hdr`` in a fresh process, developed at its "working width" or its "own size": the seconds, the peak
    memory in MiB and the image read."""
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", "OPENBLAS_NUM_THREADS": "1"}
    command = [sys.executable, "-c", READ, str(hdr), str(out), development]
    printed = subprocess.run(command, capture_output=True, text=True, check=True, env=environment).stdout
    seconds, megabytes = map(float, printed.split())
    return seconds, megabytes, np.load(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=8192, help="the panorama's width (its height is half)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        hdr = pathlib.Path(folder) / "room.hdr"
        cv2.imwrite(str(hdr), room_light(args.width)[..., ::-1])
        results = {name: run(hdr, pathlib.Path(folder) / f"{name}.npy", name) for name in ("working width", "own size")}
    print(f"a {args.width} x {args.width // 2} .hdr panorama, read and developed (each in a fresh process):")
    for name, (seconds, megabytes, _) in results.items():
        print(f"  developed at its {name}: {seconds:.1f} s, peak memory {megabytes:.0f} MiB")
    difference = np.abs(results["working width"][2].astype(float) - results["own size"][2])
    print(
        f"the two at the working width differ by {difference.mean():.2f} grey levels on average, "
        f"{np.percentile(difference, 99):.0f} at the 99th percentile"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
