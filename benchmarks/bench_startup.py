"""How long a user waits for a first layout: new processes of ``ncjax reconstruct`` and of the API, cold and warm.

Every run is a new Python process on the shipped demo panorama (1024 x 512), default settings (the shipped model,
4 views, world auto, edge snap, one image a geometry call), with the caches in a new folder (``NCJAX_CACHE``):

1. cold: the first run on a machine, ``ncjax reconstruct --rc auto`` with empty caches;
2. then, warm: the CLI central (``--rc 0``), the CLI on 5 copies, the API (``ncjax.reconstruct_batch``, its caches
   on by default) non-central, central and on 3 copies;
3. a batch size of the user's, ``--batch 4``: its first run on 5 copies (it compiles that size's programs), then,
   warm, 3 copies (a padded batch) and 5 (a full one and a remainder).

Per run: the seconds from starting the process to its first layout (the CLI: the first image's files on disk;
the API: ``reconstruct_batch`` returned) and to its end. The processes write and reuse Python's bytecode as a
user's Python does, whatever ``PYTHONDONTWRITEBYTECODE`` says here: without it every import compiles the sources
of jax, flax and ncjax again (about 6 s on 2 cores), a cost no user pays after the first run.

    uv run python benchmarks/bench_startup.py [--repeats 2]
"""

from __future__ import annotations

import argparse
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

from ncjax.cli.demo import DEMO_DIR
from ncjax.cli.inputs import radius_of

DEMO_IMAGE = next(DEMO_DIR.glob("*.png"))
COLD_GOAL, WARM_GOAL = 15.0, 3.0  # seconds to the first layout

# a new process of the API: the layouts of N copies of the demo panorama, then the time they were ready
API_SCRIPT = """
import sys, time
import numpy as np
import ncjax
image = ncjax.read_panorama(sys.argv[1])
count, rc = int(sys.argv[2]), float(sys.argv[3])
prior = ncjax.HeightPrior("camera_height", 1.6) if rc == 0 else None
result = ncjax.reconstruct_batch(np.stack([image] * count), np.full(count, rc, np.float32), prior=prior)
assert bool(result.layout.ok[0]), result.layout.status
print(time.time())
"""


def environment(cache: str) -> dict:
    variables = os.environ | {"NCJAX_CACHE": cache, "OPENBLAS_NUM_THREADS": "1"}
    variables.pop("PYTHONDONTWRITEBYTECODE", None)
    return variables


def run_cli(images: list[str], rc: str, out: str, cache: str, *options: str) -> tuple[float, float]:
    """Seconds of one ``ncjax reconstruct`` process to its first image's files and to its end (raises if it fails)."""
    shutil.rmtree(out, ignore_errors=True)
    first = pathlib.Path(out) / f"{pathlib.Path(images[0]).stem}.json"
    command = [sys.executable, "-m", "ncjax.cli", "reconstruct", *images, "--rc", rc, "--out", out, *options]
    start = time.perf_counter()
    process = subprocess.Popen(command, env=environment(cache), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    first_layout = None
    while process.poll() is None:
        if first_layout is None and first.exists():
            first_layout = time.perf_counter() - start
        time.sleep(0.005)
    end = time.perf_counter() - start
    if process.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{process.stderr.read().decode()}")
    return (end if first_layout is None else first_layout), end


def run_api(image: str, count: int, rc: float, cache: str) -> tuple[float, float]:
    """Seconds of a new process calling ``ncjax.reconstruct_batch`` to its layouts and to its end."""
    command = [sys.executable, "-c", API_SCRIPT, image, str(count), str(rc)]
    started = time.time()
    start = time.perf_counter()
    done = subprocess.run(command, env=environment(cache), check=True, capture_output=True, text=True)
    end = time.perf_counter() - start
    return float(done.stdout.strip().splitlines()[-1]) - started, end


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2, help="runs of each warm case (the best is printed)")
    args = parser.parse_args(argv)
    rc = radius_of(str(DEMO_IMAGE), None)
    with tempfile.TemporaryDirectory() as work:
        cache, out = os.path.join(work, "cache"), os.path.join(work, "out")
        copies = []
        for i in range(5):
            copy = os.path.join(work, f"copy{i}_{DEMO_IMAGE.name}")
            shutil.copyfile(DEMO_IMAGE, copy)
            copies.append(copy)
        image = str(DEMO_IMAGE)
        rows = [("cold: ncjax reconstruct, non-central, empty caches", COLD_GOAL, run_cli([image], "auto", out, cache))]
        warm_cases = [
            ("warm: ncjax reconstruct, non-central", lambda: run_cli([image], "auto", out, cache)),
            ("warm: ncjax reconstruct, central (--rc 0)", lambda: run_cli([image], "0", out, cache)),
            ("warm: ncjax reconstruct, 5 images", lambda: run_cli(copies, "auto", out, cache)),
            ("warm: API, new process, non-central", lambda: run_api(image, 1, rc, cache)),
            ("warm: API, new process, central", lambda: run_api(image, 1, 0.0, cache)),
            ("warm: API, new process, 3 images", lambda: run_api(image, 3, rc, cache)),
        ]
        for name, case in warm_cases:
            runs = [case() for _ in range(args.repeats)]
            rows.append((name, WARM_GOAL, min(runs)))
        # a batch size of the user's: its first run compiles its programs, the runs after it are warm
        batch = ("--batch", "4")
        rows.append(("first run of --batch 4 (5 images)", None, run_cli(copies, "auto", out, cache, *batch)))
        for name, count in (("3 images (a padded batch)", 3), ("5 images (4 + a remainder)", 5)):
            runs = [run_cli(copies[:count], "auto", out, cache, *batch) for _ in range(args.repeats)]
            rows.append((f"warm: --batch 4, {name}", WARM_GOAL, min(runs)))
    print(f"{DEMO_IMAGE.name}, default settings, each run a new process (best of {args.repeats} when warm):")
    print(f"{'run':55s} {'first layout':>13s} {'whole run':>10s}  goal")
    for name, goal, (first, whole) in rows:
        verdict = "" if goal is None else f"<= {goal:.0f} s {'met' if first <= goal else 'MISSED'}"
        print(f"{name:55s} {first:11.1f} s {whole:8.1f} s  {verdict}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
