"""Export the traced programs of ``ncjax reconstruct``'s default settings into the package.

A first ``ncjax reconstruct`` traces the network and both worlds' geometry
(about 10 s on 2 CPU cores) before XLA compiles them. The package carries the
traced programs (``jax.export``, :data:`ncjax.programs.SHIPPED_DIRECTORY`: the
network's for one image, the geometry's two halves for the default ``--batch`` twice: without a height prior,
and with the default camera-height prior for central panoramas and the fallback, and the adaptation to one
image, which ``ncjax reconstruct`` runs on central panoramas whose rows are not flat) of the default settings
(shipped model, world auto, 4 views, edge snap) for 1024 x 512 panoramas, so that a user's first run only
compiles.
Other sizes and settings are traced on their first run (the network's program serves every world and pipeline
setting).

A program's name holds the digest of ncjax's sources and jax's version: a
program exported from other sources is never used, it only stops sparing the
tracing. ``tests/test_programs.py`` fails while the shipped programs are stale;
run this script after every change of ncjax's sources:

    uv run python experiments/export_default_program.py

It runs the commands a user would (``ncjax reconstruct`` on the demo panorama,
``--rc auto``, then ``--rc 0``; then its adaptation, which a render's flat rows do not ask for, through
``ncjax.reconstruct_batch``) with an empty cache, copies the six programs
they saved into the package in place of the old ones and writes the manifest.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import tempfile

import jax
import numpy as np

from ncjax import programs
from ncjax.cli.demo import DEMO_DIR
from ncjax.cli.main import main as ncjax_main
from ncjax.io.images import read_panorama_file
from ncjax.network.config import AdaptConfig
from ncjax.reconstruction import DEFAULT_BATCH_SIZE, reconstruct_batch


def main() -> int:
    for old in programs.SHIPPED_DIRECTORY.glob(f"*{programs.SUFFIX}"):
        old.unlink()  # else the run below would load it instead of exporting the current one
    with tempfile.TemporaryDirectory() as work:
        os.environ["NCJAX_CACHE"] = os.path.join(work, "cache")
        demo = next(DEMO_DIR.glob("*.png"))
        for rc in ("auto", "0"):
            code = ncjax_main(["reconstruct", str(demo), "--rc", rc, "--out", os.path.join(work, "out")])
            if code != 0:
                raise SystemExit(f"ncjax reconstruct --rc {rc} failed with exit code {code}")
        # the demo's rows are flat, so it is not adapted: its adaptation exported through the API, which the
        # default's program serves (a program does not depend on which panoramas are adapted, min_loss)
        image = read_panorama_file(demo)[0]
        always = AdaptConfig(min_loss=0.0)
        if not reconstruct_batch(image[None], np.zeros(1, np.float32), adapt=always).adapted[0]:
            raise SystemExit("the demo was not adapted with min_loss 0")
        exported = sorted(pathlib.Path(work, "cache", "programs").glob(f"*{programs.SUFFIX}"))
        if len(exported) != 6:
            raise SystemExit(
                f"expected six saved programs (network, adaptation; 2 routes' walls, layouts), got {exported}"
            )
        programs.SHIPPED_DIRECTORY.mkdir(parents=True, exist_ok=True)
        shipped = [programs.SHIPPED_DIRECTORY / path.name for path in exported]
        for source, destination in zip(exported, shipped, strict=True):
            shutil.copyfile(source, destination)
    manifest = {
        "programs": [path.name for path in shipped],
        "settings": (
            "ncjax reconstruct defaults, 1024 x 512 panoramas: the network (one image); walls and layouts (batches "
            f"of {DEFAULT_BATCH_SIZE}) without a prior (--rc > 0) and with the camera-height prior (--rc 0, and the "
            "fallback of --rc > 0); the adaptation to one image"
        ),
        "jax": jax.__version__,
        "source_digest": programs.source_digest(),
    }
    programs.SHIPPED_MANIFEST.write_text(json.dumps(manifest, indent=1) + "\n")
    for path in shipped:
        print(f"{path}: {path.stat().st_size / 1e3:.0f} kB")
    print("manifest written")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
