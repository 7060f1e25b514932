"""Two runs of a benchmark on the same panoramas, image by image: which images a change moves, and how far.

    uv run python benchmarks/compare_runs.py BASE.csv OTHER.csv [--columns NAME ...] [--sort NAME] [--top N]

Input: two CSV files written by ``benchmarks/real_panoramas.py`` (``real_panoramas.csv``) or
``benchmarks/central_layouts.py`` (``central_layouts.csv``), e.g. the shipped model's and a trained one's. Rows are
matched by their ``name``; rows whose name starts with ``mean`` are the runs' own means and are shown last.

It prints one line per image with each column as ``base -> other (change)``, sorted by the change of ``--sort``
(default: the first column) with the ``--top`` largest moves only if given, then per column the mean of both runs over
the images they share and how many images got better and worse: lower is better for errors (a column named
``*error*`` or ``*rmse*``; ``*signed*``: nearer zero), higher for everything else. The counts make a change's reach
plain where one image's swing would otherwise hide in a mean (experiments/RESULTS.md, "Real photographs"). Bad input
(a missing file, no shared image, an unknown column) is one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import math
import pathlib
import sys

DEFAULT_COLUMNS = ("ceiling_error_px", "floor_error_px", "iou_3d", "iou3d")
LOWER_IS_BETTER = ("error", "rmse")  # a column whose name holds one of these is an error


class InputError(Exception):
    """Bad input, reported as one line."""


def read_rows(path: pathlib.Path) -> dict[str, dict[str, str]]:
    """A benchmark CSV's rows by name."""
    try:
        with path.open(newline="") as file:
            rows = list(csv.DictReader(file))
    except OSError as error:
        raise InputError(f"{path}: {error.strerror or error}") from error
    if not rows or "name" not in rows[0]:
        raise InputError(f"{path}: not a benchmark CSV (no rows, or no 'name' column)")
    return {row["name"]: row for row in rows}


def value(row: dict[str, str], column: str) -> float:
    """A cell as a number (NaN when empty or not a number)."""
    try:
        return float(row.get(column) or "nan")
    except ValueError:
        return math.nan


def better(column: str, base: float, other: float) -> int:
    """+1 if ``other`` is better than ``base`` in this column, -1 if worse, 0 if equal or not comparable."""
    if not (math.isfinite(base) and math.isfinite(other)) or base == other:
        return 0
    if "signed" in column:  # a signed error is better nearer zero
        base, other = abs(base), abs(other)
        if base == other:
            return 0
    lower_is_better = any(word in column for word in LOWER_IS_BETTER)
    return 1 if (other < base) == lower_is_better else -1


def cell(base: float, other: float) -> str:
    return f"{base:.3f} -> {other:.3f} ({other - base:+.3f})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=pathlib.Path, help="the reference run's CSV")
    parser.add_argument("other", type=pathlib.Path, help="the run compared with it")
    parser.add_argument("--columns", nargs="+", help=f"columns to show (default: those of {DEFAULT_COLUMNS} present)")
    parser.add_argument("--sort", help="order the images by this column's change (default: the first column)")
    parser.add_argument("--top", type=int, help="only the N images this column moves most")
    args = parser.parse_args(argv)
    try:
        base, other = read_rows(args.base), read_rows(args.other)
        names = [name for name in base if name in other]
        images = [name for name in names if not name.startswith("mean")]
        if not images:
            raise InputError(f"{args.base} and {args.other} share no image")
        present = [c for c in base[images[0]] if c in other[images[0]]]
        columns = args.columns or [c for c in DEFAULT_COLUMNS if c in present]
        unknown = [c for c in columns + ([args.sort] if args.sort else []) if c not in present]
        if unknown or not columns:
            raise InputError(f"unknown column {unknown[0] if unknown else ''!r}; the CSVs share: {', '.join(present)}")
        if args.top is not None and args.top < 1:
            raise InputError(f"--top must be >= 1, got {args.top}")
    except InputError as error:
        print(f"compare_runs: error: {error}", file=sys.stderr)
        return 2
    key = args.sort or columns[0]

    def change(name: str) -> float:
        moved = value(other[name], key) - value(base[name], key)
        return abs(moved) if math.isfinite(moved) else -1.0

    shown = sorted(images, key=change, reverse=True)[: args.top]
    print(f"| image | {' | '.join(columns)} |")
    print("|---" * (len(columns) + 1) + "|")
    for name in shown + [n for n in names if n.startswith("mean")]:
        cells = " | ".join(cell(value(base[name], c), value(other[name], c)) for c in columns)
        print(f"| {name} | {cells} |")
    print()
    for column in columns:
        pairs = [(value(base[n], column), value(other[n], column)) for n in images]
        pairs = [(b, o) for b, o in pairs if math.isfinite(b) and math.isfinite(o)]
        verdicts = [better(column, b, o) for b, o in pairs]
        mean_base = sum(b for b, _ in pairs) / len(pairs) if pairs else math.nan
        mean_other = sum(o for _, o in pairs) / len(pairs) if pairs else math.nan
        print(
            f"{column}: mean {cell(mean_base, mean_other)} over {len(pairs)} images both scored; "
            f"{verdicts.count(1)} better, {verdicts.count(-1)} worse, {verdicts.count(0)} unchanged"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
