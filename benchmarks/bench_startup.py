"""How long a user waits: ``ncjax reconstruct`` on one panorama from a fresh process, cold and warm.

Runs the command a user would, default settings (the shipped model, 4 views, world auto, edge snap), on
the shipped demo panorama (512 x 1024), each time in a new Python process:

- cold: an empty compilation cache (``NCJAX_CACHE`` pointed at a new folder): the first run on a machine;
- warm: the same cache again, as every later run with the same image size and settings;
- batch: ``--images N`` copies of the panorama in one warm run with ``--batch B``: images per second
  once the programs are compiled, the start-up included.

Wall-clock seconds of the whole process (imports, model loading, compilation or cache loading, the
reconstruction and writing the outputs). The processes write and reuse Python's bytecode as a user's
Python does, whatever ``PYTHONDONTWRITEBYTECODE`` says here: without it every import compiles the
sources of jax, flax and ncjax again (about 6 s on 2 cores), a cost no user pays after the first run.

    uv run python benchmarks/bench_startup.py [--images 8] [--batch 4] [--warm-runs 2]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

from ncjax.cli.demo import DEMO_DIR

DEMO_IMAGE = next(DEMO_DIR.glob("*.png"))


def run_reconstruct(images: list[str], out: str, cache: str, batch: int | None = None) -> float:
    """Seconds of one ``ncjax reconstruct`` process (raises if it fails); ``batch`` None: the default ``--batch``."""
    environment = os.environ | {"NCJAX_CACHE": cache, "OPENBLAS_NUM_THREADS": "1"}
    environment.pop("PYTHONDONTWRITEBYTECODE", None)
    command = [sys.executable, "-m", "ncjax.cli", "reconstruct", *images, "--rc", "auto", "--out", out]
    command += [] if batch is None else ["--batch", str(batch)]
    start = time.perf_counter()
    subprocess.run(command, env=environment, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=8, help="panoramas in the batch run")
    parser.add_argument("--batch", type=int, default=4, help="--batch of the batch run")
    parser.add_argument("--warm-runs", type=int, default=2, help="warm single-image runs (the best is printed)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as work:
        cache, out = os.path.join(work, "cache"), os.path.join(work, "out")
        image = [str(DEMO_IMAGE)]
        cold = run_reconstruct(image, out, cache)
        warm = min(run_reconstruct(image, out, cache) for _ in range(args.warm_runs))
        copies = []
        for i in range(args.images):
            copy = os.path.join(work, f"copy{i}_{DEMO_IMAGE.name}")
            shutil.copyfile(DEMO_IMAGE, copy)
            copies.append(copy)
        run_reconstruct(copies[: args.batch], out, cache, args.batch)  # compiles the batch size
        batch = run_reconstruct(copies, out, cache, args.batch)
    print(f"one panorama ({DEMO_IMAGE.name}), default settings, a new process each time:")
    print(f"  cold (empty compilation cache): {cold:.1f} s")
    print(f"  warm (cache filled):            {warm:.1f} s")
    print(
        f"  {args.images} panoramas, --batch {args.batch}, warm: {batch:.1f} s "
        f"({args.images / batch:.2f} images/s, start-up included)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
