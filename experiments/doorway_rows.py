"""Do the network's rows cross doorways and furniture on its own photo-like renders, as they fail to on photographs?

On the photographs the rows leave the wall where a doorway shows the next room (40-60 px over a tenth of the
columns) and where furniture hides the floor line. This experiment asks whether the renders taught the network
those cases: if its rows are as good there as elsewhere on renders, what is missing is renders whose doorways and
furniture look like real ones, not more of the same.

It renders rooms of ``synth-decor-open`` (doors, half of them wide passages to the next room) and
``synth-decor-home`` (pale walls, furniture), seeds no model was trained on (those of
``experiments/central_renders.py``), each through one random camera of the training augmentation, and gets the
shipped model's rows (4 views, edge snap, as ``ncjax reconstruct``). Each column is put in one class by what the
rendering shows just above its true floor line (3 rows up, on the wall plane): a door or what is seen through an
open one (``Semantic.OPENING``), furniture in front of the wall (``OBJECT``), or the wall. Per class it prints the
share of columns, the floor and ceiling rows' mean absolute error and share of columns more than 10 px off, and the
floor rows' signed error (mean and median; positive: below the label, towards the nadir), in rows of the 512-row
image, as ``benchmarks/real_panoramas.py``.

``--kinds`` picks other sources (``synth-decor-closet``: walk-in closets whose passages fill much of a wall;
``synth-decor-hall``: corridors with doors along them; ``synth-decor-closet-door``: closets photographed from their
opening; the n-th kind given takes seed 401 + n - 1),
``--model`` another model file; ``--sheet FILE`` also writes the first ``--sheet-rooms`` renders of each kind at
half size with their true rows (green) and the model's (red).

    uv run python experiments/doorway_rows.py [--rooms 64] [--kinds KIND ...] [--model FILE] [--sheet FILE]
"""

from __future__ import annotations

import argparse
import pathlib

import cv2
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.evaluation.panorama_labels import load_network
from ncjax.synth.dataset import rendered_samples
from ncjax.synth.render import Semantic
from ncjax.training.data import SYNTH_SOURCES

from common import PHOTO_LIKE_SEED, photo_like_image

KINDS = ("synth-decor-open", "synth-decor-home")
ROWS_ABOVE = 3
FAR = 10.0  # px
CLASSES = {"doorway": Semantic.OPENING, "furniture": Semantic.OBJECT, "wall": Semantic.WALL}


def column_classes(semantic: np.ndarray, floor_v: np.ndarray) -> np.ndarray:
    """The :class:`Semantic` class of each column's pixel ``ROWS_ABOVE`` rows above its true floor line."""
    rows = np.clip(np.floor(floor_v).astype(int) - ROWS_ABOVE, 0, semantic.shape[0] - 1)
    return semantic[rows, np.arange(semantic.shape[1])]


def drawn_rows(image: np.ndarray, true_rows, predicted_rows) -> np.ndarray:
    """``image`` (RGB) at half size, BGR, with the true rows in green and the predicted ones in red."""
    tile = np.ascontiguousarray(image[..., ::-1])
    columns = np.arange(tile.shape[1]) + 0.5
    for rows, colour in ((predicted_rows, (0, 0, 255)), (true_rows, (0, 200, 0))):
        for row in rows:
            points = np.stack([columns, np.asarray(row)], 1).astype(np.int32)
            cv2.polylines(tile, [points], False, colour, 2)
    return cv2.resize(tile, (tile.shape[1] // 2, tile.shape[0] // 2), interpolation=cv2.INTER_AREA)


def kind_errors(kind: str, seed: int, rooms: int, model, sheet_rooms: int = 0) -> dict[str, np.ndarray]:
    """Per column of ``rooms`` renders of ``kind``: its class and the floor and ceiling rows' absolute errors; and
    the first ``sheet_rooms`` renders drawn with their rows (:func:`drawn_rows`), stacked."""
    classes, floor_error, ceiling_error, tiles = [], [], [], []
    for index, _scene, rendering, labels in tqdm(
        rendered_samples(rooms, seed, SYNTH_SOURCES[kind]), total=rooms, desc=kind
    ):
        image = photo_like_image(seed, index, rendering)
        ceiling_v, floor_v, _ = ncjax.predict_boundaries(image, model)
        if len(tiles) < sheet_rooms:
            tiles.append(drawn_rows(image, (labels.ceiling_v, labels.floor_v), (ceiling_v, floor_v)))
        scale = 512 / image.shape[0]
        classes.append(column_classes(np.asarray(rendering.semantic), np.asarray(labels.floor_v)))
        floor_error.append((floor_v - np.asarray(labels.floor_v)) * scale)
        ceiling_error.append(np.abs(ceiling_v - np.asarray(labels.ceiling_v)) * scale)
    return {
        "class": np.concatenate(classes),
        "floor": np.concatenate(floor_error),  # signed: positive below the label
        "ceiling": np.concatenate(ceiling_error),
        "tiles": np.concatenate(tiles) if tiles else np.zeros((0, 0, 3), np.uint8),
    }


def table_lines(name: str, errors: dict[str, np.ndarray]) -> list[str]:
    lines = []
    for label, semantic in CLASSES.items():
        picked = errors["class"] == semantic
        if not picked.any():
            continue
        signed, ceiling = errors["floor"][picked], errors["ceiling"][picked]
        floor = np.abs(signed)
        lines.append(
            f"| {name}, {label} | {np.mean(picked):.1%} | {np.mean(floor):.1f} / {np.mean(floor > FAR):.1%} "
            f"| {np.mean(signed):+.1f} / {np.median(signed):+.1f} "
            f"| {np.mean(ceiling):.1f} / {np.mean(ceiling > FAR):.1%} |"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=64, help="rooms per kind")
    parser.add_argument("--kinds", nargs="+", choices=sorted(SYNTH_SOURCES), default=list(KINDS), help="sources")
    parser.add_argument("--model", type=pathlib.Path, default=None, help="model file (default: the shipped model)")
    parser.add_argument("--sheet", type=pathlib.Path, help="also write a contact sheet (JPEG) of the first renders")
    parser.add_argument("--sheet-rooms", type=int, default=2, help="renders of each kind on the sheet")
    args = parser.parse_args(argv)
    if args.rooms < 1:
        parser.error("--rooms must be at least 1")
    model = load_network(args.model)
    seeds = {kind: PHOTO_LIKE_SEED + i for i, kind in enumerate(args.kinds)}
    sheet_rooms = min(args.sheet_rooms, args.rooms) if args.sheet else 0
    per_kind = {kind: kind_errors(kind, seed, args.rooms, model, sheet_rooms) for kind, seed in seeds.items()}
    listed = ", ".join(f"{kind} seed {seed}" for kind, seed in seeds.items())
    print(f"{args.rooms} rooms per kind ({listed}); rows of a 512-row image")
    print(
        f"| renders, column class | columns | floor: mean px / > {FAR:.0f} px | floor signed (below the label +): "
        f"mean / median px | ceiling: mean px / > {FAR:.0f} px |"
    )
    print("| --- | --- | --- | --- | --- |")
    for kind, errors in per_kind.items():
        print("\n".join(table_lines(kind, errors)))
    if args.sheet:
        sheet = np.concatenate([errors["tiles"] for errors in per_kind.values()])
        if not cv2.imwrite(str(args.sheet), sheet, [cv2.IMWRITE_JPEG_QUALITY, 85]):
            raise OSError(f"could not write {args.sheet}")
        print(f"wrote {args.sheet}: {sheet_rooms} renders of each kind, true rows green, the model's red")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
