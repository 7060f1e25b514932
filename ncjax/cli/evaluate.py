"""``ncjax evaluate PRED GT``: central-panorama layout metrics of predicted layouts against ground truth.

PRED and GT are two layout files of one image, or two folders whose layout files are
matched by image stem (:func:`ncjax.io.formats_read.layout_files`). Any format of
:mod:`ncjax.io.formats_read` is read, ncjax's JSON included. Prints one line per image
and the mean (:mod:`ncjax.evaluation.central_metrics`).
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys

from .arguments import parse_size
from .inputs import PANORAMA_SUFFIXES

# (title, metric, factor, decimals) of the printed columns
COLUMNS = (
    ("2D IoU", "iou2d", 100.0, 2),
    ("3D IoU", "iou3d", 100.0, 2),
    ("CE %", "corner_error", 1.0, 2),
    ("PE %", "pixel_error", 1.0, 2),
    ("RMSE", "depth_rmse", 1.0, 3),
    ("delta1", "delta1", 1.0, 3),
)
CELL = 7


LAYOUT_FILES = "label_cor .txt, or HorizonNet, PanoAnnotator, ZInD or ncjax .json"


def layout_pairs(pred: str, gt: str) -> tuple[list[tuple[str, pathlib.Path, pathlib.Path]], list[str], list[str]]:
    """The (name, prediction file, ground-truth file) to compare, and the stems found on one side only.

    Raises:
        ValueError: for a file and a folder, an image given as a layout file, or two folders without a common
            image stem.
        FileNotFoundError: for a path that does not exist.
    """
    from ..io.formats_read import layout_files, split_layout_name

    pred_path, gt_path = pathlib.Path(pred), pathlib.Path(gt)
    for path in (pred_path, gt_path):
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such file or folder")
    if pred_path.is_dir() != gt_path.is_dir():
        raise ValueError("PRED and GT must be two layout files or two folders")
    if not pred_path.is_dir():
        for role, path in (("PRED", pred_path), ("GT", gt_path)):
            if path.suffix.lower() in PANORAMA_SUFFIXES:
                raise ValueError(
                    f"{role} {path} is an image: give its layout file ({LAYOUT_FILES}), or a folder of them"
                )
        parts = split_layout_name(gt_path.name)
        return [(parts[0] if parts else gt_path.stem, pred_path, gt_path)], [], []
    predictions, truths = layout_files(pred_path), layout_files(gt_path)
    common = sorted(set(predictions) & set(truths))
    if not common:
        raise ValueError(f"no image has a layout file in both {pred_path} and {gt_path} (matched by file stem)")
    only_pred = sorted(set(predictions) - set(truths))
    only_gt = sorted(set(truths) - set(predictions))
    return [(stem, predictions[stem], truths[stem]) for stem in common], only_pred, only_gt


def read_pair(pred_file: pathlib.Path, gt_file: pathlib.Path, size: tuple[int, int] | None):
    """The prediction and the ground truth of one image (:func:`~ncjax.io.formats_read.read_layout`).

    A file that records no image size (label_cor) is read at ``size`` (``--size``, as (W, H)), else at the size
    the other file records, else at 1024 x 512: the labels of a panorama ncjax resized before its reconstruction
    are in the pixels of the file as given, as its exports are.
    """
    from ..io.formats_read import read_layout, recorded_size

    if size is not None:
        return read_layout(pred_file, *size), read_layout(gt_file, *size)
    pred_size, gt_size = recorded_size(pred_file), recorded_size(gt_file)
    pred = read_layout(pred_file, *(pred_size or gt_size or (None, None)))
    return pred, read_layout(gt_file, *(gt_size or pred_size or (None, None)))


def _cells(row: dict) -> str:
    """The printed metrics of one row ("n/a" where not finite)."""
    cells = []
    for _, key, factor, decimals in COLUMNS:
        value = row[key] * factor
        cells.append(f"{value:{CELL}.{decimals}f}" if math.isfinite(value) else f"{'n/a':>{CELL}}")
    return " ".join(cells)


def run_layout_evaluation(args: argparse.Namespace) -> int:
    """Evaluate ``args.pred`` against ``args.gt``; ``args.size`` (HxW or None) and ``args.json`` optional.

    Returns:
        0, or 1 when some image could not be evaluated (its line says why).
    """
    from ..evaluation.central_metrics import aggregate_central, evaluate_corners

    size = parse_size(args.size)[::-1] if args.size else None
    pairs, only_pred, only_gt = layout_pairs(args.pred, args.gt)
    name_width = max(12, *(len(name) for name, *_ in pairs))
    header = " ".join(f"{title:>{CELL}}" for title, *_ in COLUMNS)
    print(f"{'image':<{name_width}} {header}  corners  scale")
    results, failures = {}, {}
    for name, pred_file, gt_file in pairs:
        try:
            pred, gt = read_pair(pred_file, gt_file, size)
            row = evaluate_corners(pred, gt)
        except (ValueError, FileNotFoundError) as error:
            failures[name] = str(error)
            print(f"{name:<{name_width}} not evaluated: {error}")
            continue
        results[name] = row | {"corners": f"{pred.count}/{gt.count}"}
        scale = "metres" if row["metric"] else "camera height 1"
        print(f"{name:<{name_width}} {_cells(row)}  {pred.count:>3}/{gt.count:<3}  {scale}")
    summary = None
    if results:
        summary = aggregate_central(
            {key: value for key, value in row.items() if key != "corners"} for row in results.values()
        )
        if pathlib.Path(args.pred).is_dir():
            print(f"{f'mean of {len(results)}':<{name_width}} {_cells(summary)}")
        mismatched = sum(row["corner_count_match"] == 0 for row in results.values())
        if mismatched:
            print(f"{mismatched} of {len(results)} predictions have a corner count other than the ground truth's")
    for stems, side in ((only_pred, "predictions without ground truth"), (only_gt, "ground truths without prediction")):
        if stems:
            print(f"{len(stems)} {side}: {', '.join(stems[:5])}{', ...' if len(stems) > 5 else ''}")
    if args.json:
        from ..io.export import write_json

        def strict(row):
            return {
                key: value if not isinstance(value, float) or math.isfinite(value) else None
                for key, value in row.items()
            }

        write_json(
            args.json,
            {
                "pred": str(args.pred),
                "gt": str(args.gt),
                "images": {name: strict(row) for name, row in results.items()},
                "mean": strict(summary) if summary else None,
                "failures": failures,
            },
        )
    if failures:
        print(f"{len(failures)} of {len(pairs)} images not evaluated", file=sys.stderr)
        return 1
    return 0


def check_evaluate_mode(args: argparse.Namespace) -> str:
    """``"layouts"`` (PRED and GT given) or ``"network"`` (``--data``), or a one-line ValueError."""
    positionals = [path for path in (args.pred, args.gt) if path is not None]
    if args.data is not None and positionals:
        raise ValueError(
            "give either PRED GT (layout files or folders) or --data DIR (a network on a dataset), not both"
        )
    if args.data is not None:
        return "network"
    if len(positionals) == 2:
        return "layouts"
    if positionals:
        raise ValueError("layout evaluation needs both PRED and GT (two layout files or two folders)")
    raise ValueError("give PRED GT (layout files or folders) or --data DIR (a network on a dataset)")
