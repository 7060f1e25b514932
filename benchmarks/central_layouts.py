"""Central mode on real, labelled panoramas: ``ncjax reconstruct --rc 0`` against each image's label_cor.

    uv run python benchmarks/central_layouts.py --data DIR [--out DIR] [--model FILE] [--limit N] [--no-align]
        [any option of ncjax reconstruct: --no-adapt, --world manhattan, --camera-height 1.5, ...]

Input: a folder of central panoramas (``*.jpg``, ``*.jpeg``, ``*.png``), each with its label ``<stem>.txt``
(label_cor: one ``x y`` line per point, ceiling then floor of each corner, pixels of that image) beside it, or
``label_cor/<stem>.txt`` for an image in ``img/``.

It runs the command a user would (``ncjax reconstruct IMAGES --rc 0 --export label_cor``: the default camera height
prior of 1.6 m, gravity alignment, the shipped model, 4 views, a panorama whose rows are not flat read again by the
network adapted to it; any other option is passed to the command as it is, ``--no-adapt`` for the network as trained),
reads back each written ``<stem>.label_cor.txt`` and scores it against the label with
:mod:`ncjax.evaluation.central_metrics`, both back-projected at camera height 1 (HorizonNet's and LGT-Net's
convention: the metrics are up to scale). It prints per image and on average the 2D and 3D IoU, the corner error (% of
the image diagonal), the pixel error, depth RMSE (camera heights) and delta-1, and the number of images with a layout.
A written layout the metrics cannot back-project (a corner at or across the horizon, which fixes no point at camera
height 1) counts as no layout, and the count of such layouts is printed. The mean 3D IoU is given twice: over the
images with a layout, and over all images with 0 for those without, then per status of the written layouts (``OK``,
or flagged ``LOW_CONFIDENCE``: does the flag pick the worse layouts?). Each image's status and explained fraction come
from its JSON record. The same table is written to ``central_layouts.csv`` in the output folder (an image without a
layout has 2D and 3D IoU 0 and no other metric; the mean line averages the IoU over all images and the other metrics
over the layouts), for ``benchmarks/compare_runs.py``."""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import pathlib
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # OpenBLAS threads busy-wait on a loaded CPU

import numpy as np

from ncjax.cli.main import main as ncjax_main
from ncjax.evaluation.central_metrics import evaluate_corners
from ncjax.evaluation.panorama_labels import labelled_image_paths
from ncjax.evaluation.panorama_scores import csv_bytes
from ncjax.io.files import write_atomic
from ncjax.io.formats import format_path
from ncjax.io.formats_read import read_layout

COLUMNS = ("iou2d", "iou3d", "corner_error", "pixel_error", "depth_rmse", "delta1")
CSV_NAME = "central_layouts.csv"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("benchmarks/out/central_layouts"))
    parser.add_argument("--model", help="network weights (default: the shipped model)")
    parser.add_argument("--limit", type=int, help="the first N images only")
    parser.add_argument("--no-align", action="store_true", help="do not level the panoramas")
    args, reconstruct_options = parser.parse_known_args(argv)
    pairs = labelled_image_paths(args.data)
    if not pairs:
        print(f"central_layouts: error: {args.data}: no panorama with a label_cor <stem>.txt", file=sys.stderr)
        return 2
    pairs = pairs[: args.limit]
    command = ["reconstruct", *(str(image) for image, _ in pairs), "--rc", "0", "--out", str(args.out)]
    command += ["--export", "label_cor"] + (["--model", args.model] if args.model else [])
    command += (["--no-align"] if args.no_align else []) + reconstruct_options
    for image, _ in pairs:  # an earlier run's records are never scored as this run's
        for stale in (args.out / f"{image.stem}.json", format_path(args.out / image.stem, "label_cor")):
            stale.unlink(missing_ok=True)
    start = time.perf_counter()
    messages = io.StringIO()
    try:
        with contextlib.redirect_stderr(messages):
            code = ncjax_main(command)
    except SystemExit as refused:  # an option ncjax reconstruct does not know
        code = refused.code
    seconds = time.perf_counter() - start
    if code not in (0, 1):  # 1: some images gave no layout, which is scored
        print(messages.getvalue().strip(), file=sys.stderr)
        print(f"central_layouts: error: ncjax reconstruct exited with code {code}", file=sys.stderr)
        return 2
    print(f"| image | status | explained | {' | '.join(COLUMNS)} |")
    print("|---" * (len(COLUMNS) + 3) + "|")
    entries, unscored = [], 0  # per image: (name, status, explained fraction, scores or None)
    for image, label in pairs:
        record_path = args.out / f"{image.stem}.json"
        if not record_path.exists():  # the image could not be read: reported by ncjax reconstruct
            print(f"| {image.stem} | unreadable | |")
            entries.append((image.stem, "unreadable", None, None))
            continue
        record = json.loads(record_path.read_text())
        explained = record.get("explained_fraction")
        flags = f"| {record['status']} | {'-' if explained is None else f'{explained:.2f}'} |"
        written = format_path(args.out / image.stem, "label_cor")
        if not written.exists():
            print(f"| {image.stem} {flags} no layout |")
            entries.append((image.stem, record["status"], explained, None))
            continue
        truth = read_layout(label)
        predicted = read_layout(written, truth.width, truth.height)
        try:
            scores = evaluate_corners(predicted, truth)
        except ValueError as error:  # a corner at the horizon is no point at camera height 1
            print(f"| {image.stem} {flags} not scored: {error} |")
            entries.append((image.stem, record["status"], explained, None))
            unscored += 1
            continue
        entries.append((image.stem, record["status"], explained, scores))
        print(f"| {image.stem} {flags} " + " | ".join(f"{scores[c]:.3f}" for c in COLUMNS) + " |")
    rows = [None if scores is None else scores | {"status": status} for _, status, _, scores in entries]
    table = [_csv_row(*entry) for entry in entries]
    found = [row for row in rows if row is not None]
    means = {c: float(np.nanmean([row[c] for row in found])) if found else math.nan for c in COLUMNS}
    print(f"| mean of {len(found)} layouts | " + " | ".join(f"{means[c]:.3f}" for c in COLUMNS) + " |")
    all_iou = np.mean([row["iou3d"] if row is not None else 0.0 for row in rows])
    print(
        f"{len(found)} of {len(rows)} images gave a layout; mean 3D IoU {means['iou3d']:.3f} over them, "
        f"{all_iou:.3f} over all {len(rows)} (no layout as 0); {seconds:.0f} s for ncjax reconstruct"
    )
    if unscored:
        print(f"  {unscored} written layouts could not be scored (counted as no layout)")
    for status in sorted({row["status"] for row in found}):
        ious = [row["iou3d"] for row in found if row["status"] == status]
        print(f"  {status}: {len(ious)} layouts, mean 3D IoU {np.mean(ious):.3f}")
    mean_row = {c: float(np.mean([row[c] for row in table])) if c.startswith("iou") else means[c] for c in COLUMNS}
    table.append(_csv_row(f"mean ({len(rows)} images)", "", None, mean_row))
    write_atomic(args.out / CSV_NAME, csv_bytes(table))
    print(f"wrote {args.out / CSV_NAME}")
    return 0


def _csv_row(name: str, status: str, explained: float | None, scores: dict | None) -> dict:
    """One line of the CSV: without scores (no layout) 2D and 3D IoU 0 and no other metric."""
    metrics = {c: (0.0 if c.startswith("iou") else "") if scores is None else scores[c] for c in COLUMNS}
    return {"name": name, "status": status, "explained": "" if explained is None else explained} | metrics


if __name__ == "__main__":
    sys.exit(main())
