"""How flat the network's rows are: the flatness loss that decides which panoramas are adapted, per folder.

``ncjax reconstruct`` reads a panorama again with the network fitted to its own flat floor and ceiling where the rows
it read first cost at least ``AdaptConfig().min_loss`` in ``ncjax.network.flatness.row_flatness`` (the Huber loss of
each column's ceiling-to-floor distance ratio about their median). Per folder of panoramas (``*.jpg``, ``*.jpeg``,
``*.png``, or its ``img/`` folder as ``ncjax synth`` writes it), this prints the loss of the shipped model's rows (4
views, edge snap; the panoramas as they are, not levelled as ``ncjax reconstruct`` levels central ones) at the
percentiles 0 / 10 / 25 / 50 / 75 / 90 / 100 and how many reach ``min_loss``; ``--each`` also prints every image's.

    uv run python experiments/row_flatness.py DIR [DIR ...] [--each]
"""

from __future__ import annotations

import argparse
import pathlib

import numpy as np

from ncjax.io.images import read_panorama_file
from ncjax.network.config import AdaptConfig
from ncjax.network.flatness import row_flatness
from ncjax.network.predict import predict_boundaries

SUFFIXES = (".jpg", ".jpeg", ".png")


def panoramas(folder: pathlib.Path) -> list[pathlib.Path]:
    """The panoramas of ``folder``, or of its ``img/`` folder."""
    folder = folder / "img" if (folder / "img").is_dir() else folder
    return sorted(path for path in folder.iterdir() if path.suffix.lower() in SUFFIXES)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=pathlib.Path, nargs="+")
    parser.add_argument("--each", action="store_true", help="print every image's loss too")
    args = parser.parse_args(argv)
    config = AdaptConfig()
    print(f"min_loss {config.min_loss:.2e} (huber {config.huber}); losses x 1e-4")
    for folder in args.folders:
        losses = []
        for path in panoramas(folder):
            image = read_panorama_file(path)[0]
            ceiling, floor, _ = predict_boundaries(image)
            losses.append(float(row_flatness(ceiling, floor, image.shape[0], config.huber)))
            if args.each:
                print(f"  {path.stem}: {1e4 * losses[-1]:.2f}", flush=True)
        losses = np.asarray(losses)
        percentiles = np.percentile(losses, [0, 10, 25, 50, 75, 90, 100]) * 1e4
        print(
            f"{folder}: {len(losses)} panoramas, percentiles {' / '.join(f'{p:.1f}' for p in percentiles)}; "
            f"{int(np.sum(losses >= config.min_loss))} at or above min_loss",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
