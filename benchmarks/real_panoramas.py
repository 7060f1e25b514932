"""The shipped network on real, labelled equirectangular panoramas: boundary rows, corners and raw-layout IoU.

    uv run python benchmarks/real_panoramas.py --data DIR [--views N] [--model FILE] [--out DIR] [--limit N] [--adapt]

Input: a folder of full panoramas (``*.jpg``, ``*.jpeg``, ``*.png``; width = 2 x height, any size), each with
a ``label_cor`` file of the same stem: ``<stem>.txt`` beside the image, or ``label_cor/<stem>.txt`` for an
image in ``img/`` (the layout ``ncjax synth`` writes). Images without a label are skipped. ``label_cor`` is
HorizonNet's format: one ``x y`` line per point, the ceiling then the floor point of each corner, corners in
polygon order, pixels of that image with pixel centres at integers. A ``<stem>.json`` beside the image may add
``tags`` (``closed`` / ``open_plan`` give separate means; ``ceiling_not_flat`` leaves the ceiling rows
unscored) and per-corner ``counted`` / ``occluded`` flags (which label corners a peak must find, and on which
a peak counts neither way). Without flags every label corner counts, once per column: an occlusion's near and
far points share theirs.

The label's boundaries per column come from its 3D room, seen by a central camera: the floor at z = -1
(camera height 1), each floor corner placed in plan from its row, the flat ceiling at the median height its
corners' ceiling rows give, and every column's ray cast to the nearest wall of that polygon (a straight
wall is a curve in the panorama, not a line between its corners' pixels).

Per image and on average it prints (and writes to ``real_panoramas.csv``):

- ceiling and floor row error: mean |predicted - label row| over the columns where the label sees a wall,
  in pixels of a 512-row image (``REFERENCE_WIDTH / W`` = 512 / H);
- corner precision and recall within 1% and 2.5% of the width: the peaks of the corner probability found
  by the pipeline's peak finder with the network pipeline's settings, matched one-to-one (nearest pairs
  first, wrap-around) to the label's corner columns; pooled over the images in the means;
- whether the number of peaks equals the label's corner count (the mean: the share of images);
- the 2D and 3D IoU of the raw prediction (every column's floor row back-projected at camera height 1,
  the ceiling at the median height its ceiling rows give) and the label, up to scale (a central panorama
  has none).

With ``--adapt`` the network is first fitted to each panorama's own flat floor and ceiling
(:func:`ncjax.network.adapt.adapt_to_panorama`, its default settings; no label is used), from the same weights for
every panorama, however flat its rows (``ncjax reconstruct`` adapts the central panoramas whose rows are not).

It also writes ``contact_sheet.png``: each panorama downscaled with the label's boundaries and corners in
green, the prediction's in red, and the corner probability below it with the peak threshold in grey.
Bad input (a missing folder, no labelled image, an unreadable image, a malformed label) is one line on
stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
from collections.abc import Callable

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # OpenBLAS threads busy-wait on a loaded CPU

import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.evaluation.contact_sheet import contact_sheet_png, contact_tile
from ncjax.evaluation.panorama_labels import (
    FLAT_CEILING_EXCLUSION_TAG,
    InputError,
    load_network,
    load_panoramas,
    read_labelled_image,
)
from ncjax.evaluation.panorama_scores import (
    csv_bytes,
    predicted_corners,
    score_image,
    summaries,
    table_header,
    table_line,
)
from ncjax.io.files import write_atomic
from ncjax.network.adapt import adapt_to_panorama
from ncjax.network.model import check_views

DEFAULT_OUT = pathlib.Path(__file__).resolve().parent / "out" / "real_panoramas"
CSV_NAME = "real_panoramas.csv"
SHEET_NAME = "contact_sheet.png"


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor files")
    parser.add_argument("--views", type=int, default=4, help="views the network averages (1 or even; default 4)")
    parser.add_argument("--model", type=pathlib.Path, default=None, help="model file (default: the shipped model)")
    parser.add_argument("--out", type=pathlib.Path, default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    parser.add_argument("--limit", type=int, default=None, help="only the first N images (by name)")
    parser.add_argument(
        "--adapt", action="store_true", help="fit the network to each panorama's flat floor and ceiling first"
    )
    args = parser.parse_args(argv)
    try:
        check_views(args.views)
    except ValueError as error:
        parser.error(str(error))
    if args.limit is not None and args.limit < 1:
        parser.error(f"--limit must be >= 1, got {args.limit}")
    return args


def run(args: argparse.Namespace, transform: Callable[[np.ndarray], np.ndarray] | None = None) -> None:
    """Score every labelled panorama of ``args.data``, print the table, write the CSV and the contact sheet;
    ``transform`` (RGB uint8 in and out, the same size) changes each image before the network and the sheet."""
    panoramas = load_panoramas(args.data, args.limit)
    if args.out.exists() and not args.out.is_dir():
        raise InputError(f"--out {args.out} exists and is not a folder")
    model = load_network(args.model)
    config = ncjax.NETWORK_PIPELINE_CONFIG
    rows, tiles = [], []
    tqdm.write(table_header())
    for panorama in tqdm(panoramas, desc="panoramas", unit="image"):
        image = read_labelled_image(panorama.image_path)
        image = image if transform is None else transform(image)
        network = adapt_to_panorama(model, image)[0] if args.adapt else model
        prediction = tuple(
            np.asarray(a, np.float64) for a in ncjax.predict_boundaries(image, network, views=args.views)
        )
        peaks = predicted_corners(prediction[2], config)
        scores = score_image(panorama, prediction[0], prediction[1], peaks)
        rows.append(scores)
        tiles.append(contact_tile(panorama, image, prediction, peaks, scores, config.corners.threshold))
        tqdm.write(table_line(scores))
    means = summaries(rows)
    for mean in means:
        print(table_line(mean))
    corners = config.corners
    print(
        f"row errors in px of a 512-row image (ceiling not scored for '{FLAT_CEILING_EXCLUSION_TAG}'); gt, pred: "
        f"corners (totals in the means); corner P/R pooled over images; count: share with the label's corner "
        f"count; peaks: find_corners(threshold={corners.threshold}, nms_radius={corners.nms_radius} columns at 1024, "
        f"min_corners={corners.min_corners}, fallback={corners.fallback_threshold}); views {args.views}"
    )
    table, sheet = csv_bytes(rows + means), contact_sheet_png(tiles)
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / CSV_NAME, table)
    write_atomic(args.out / SHEET_NAME, sheet)
    print(f"wrote {args.out / CSV_NAME} and {args.out / SHEET_NAME}")


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark; 0 on success, 2 on bad input (one line on stderr, nothing written)."""
    args = parse_arguments(argv)
    try:
        run(args)
    except InputError as error:
        print(f"real_panoramas: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
