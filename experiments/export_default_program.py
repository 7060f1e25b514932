"""Export the traced program of ``ncjax reconstruct``'s default settings into the package.

A first ``ncjax reconstruct`` traces the network and both worlds' geometry
(about 10 s on 2 CPU cores) before XLA compiles them. The package carries the
traced program (``jax.export``, :data:`ncjax.programs.SHIPPED_DIRECTORY`) of
the default settings (shipped model, world auto, 4 views, edge snap, no
height prior) for one 1024 x 512 panorama, so that a user's first run only
compiles. Other sizes and settings are traced on their first run, as before.

The program's name holds the digest of ncjax's sources and jax's version: a
program exported from other sources is never used, it only stops sparing the
tracing. ``tests/test_programs.py`` fails while the shipped program is stale;
run this script after every change of ncjax's sources:

    uv run python experiments/export_default_program.py

It runs the command a user would (``ncjax reconstruct`` on the demo panorama,
``--rc auto``) with an empty cache, moves the program it saved into the
package in place of the old one and writes the manifest.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import tempfile

import jax

from ncjax import programs
from ncjax.cli.main import main as ncjax_main
from ncjax.cli.reconstruct import DEMO_DIR


def main() -> int:
    for old in programs.SHIPPED_DIRECTORY.glob(f"*{programs.SUFFIX}"):
        old.unlink()  # else the run below would load it instead of exporting the current one
    with tempfile.TemporaryDirectory() as work:
        os.environ["NCJAX_CACHE"] = os.path.join(work, "cache")
        demo = next(DEMO_DIR.glob("*.png"))
        code = ncjax_main(["reconstruct", str(demo), "--rc", "auto", "--out", os.path.join(work, "out")])
        if code != 0:
            raise SystemExit(f"ncjax reconstruct failed with exit code {code}")
        exported = sorted(pathlib.Path(work, "cache", "programs").glob(f"*{programs.SUFFIX}"))
        if len(exported) != 1:
            raise SystemExit(f"expected one saved program, found {[path.name for path in exported]}")
        programs.SHIPPED_DIRECTORY.mkdir(parents=True, exist_ok=True)
        shipped = programs.SHIPPED_DIRECTORY / exported[0].name
        shutil.copyfile(exported[0], shipped)
    manifest = {
        "program": shipped.name,
        "settings": "ncjax reconstruct defaults (--rc > 0, no prior), one 1024 x 512 panorama",
        "jax": jax.__version__,
        "source_digest": programs.source_digest(),
    }
    programs.SHIPPED_MANIFEST.write_text(json.dumps(manifest, indent=1) + "\n")
    print(f"{shipped}: {shipped.stat().st_size / 1e3:.0f} kB; manifest written")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
