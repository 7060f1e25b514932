"""The rooms and cameras of photographs against the renders': the proportions a layout network sees.

Where a panorama's rows lie depends on the room only through its proportions to the camera's height: the ceiling's
height above the camera, how far the walls stand, how large the room is, all in camera heights. This prints their
percentiles (5, 25, 50, 75, 95) for a folder of labelled panoramas (``*.jpg``/``*.png`` with its label_cor
``<stem>.txt``; the label's room at camera height 1) and for the rooms of training sources (``--kinds``, ``ncjax
train --data`` kinds: ``--rooms`` rooms each drawn by the kind's ``RoomConfig``, no rendering), optionally with
``RoomConfig`` ranges replaced as ``experiments/frozen_backbone.py --room`` replaces them:

- the ceiling above the camera: ``(room height - camera height) / camera height``;
- the walls' distance: per panorama the median over its columns of the horizontal distance to the wall seen;
- the room's size: the square root of its floor area.

    uv run python experiments/capture_geometry.py --data DIR --kinds synth-decor-home synth-decor-open \\
        [--room camera_height_range=1.35:1.75 ...] [--rooms 256]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import numpy as np

from ncjax.evaluation.panorama_labels import (
    central_camera,
    labelled_image_paths,
    load_panorama,
    pixel_angles,
    wall_distances,
)
from ncjax.synth.rooms import RoomStatus, random_room
from ncjax.training.data import SYNTH_SOURCES

from common import room_ranges, source_config

WIDTH = 1024  # columns over which the walls' distances are taken
PERCENTILES = (5, 25, 50, 75, 95)


def proportions(plan: np.ndarray, ceiling_above: float) -> tuple[float, float, float]:
    """``(ceiling above the camera, median wall distance, sqrt(floor area))`` of a room at camera height 1."""
    azimuth, _ = pixel_angles(central_camera(WIDTH, WIDTH // 2), np.arange(WIDTH), np.zeros(WIDTH))
    distance = wall_distances(plan, azimuth)
    x, y = plan[:, 0], plan[:, 1]
    area = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    return ceiling_above, float(np.median(distance[np.isfinite(distance)])), float(np.sqrt(area))


def photograph_proportions(folder: Path) -> np.ndarray:
    """:func:`proportions` of each labelled panorama's label."""
    rooms = [load_panorama(*pair) for pair in labelled_image_paths(folder)]
    return np.array([proportions(room.plan, room.ceiling_height) for room in rooms])


def render_proportions(kind: str, count: int, rooms: dict[str, tuple[float, float]]) -> np.ndarray:
    """:func:`proportions` of ``count`` rooms of a training source (seed 0), its room ranges replaced by ``rooms``."""
    config = source_config(kind, rooms).room
    drawn = jax.device_get(
        jax.jit(jax.vmap(lambda key: random_room(key, config)))(jax.random.split(jax.random.key(0), count))
    )
    rows = []
    for index in np.flatnonzero(drawn.status == RoomStatus.OK):
        camera_height = -float(drawn.floor_height[index])
        plan = drawn.corners[index][drawn.mask[index]] / camera_height
        rows.append(proportions(plan, float(drawn.ceiling_height[index]) / camera_height))
    return np.array(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="folder of labelled panoramas")
    parser.add_argument("--kinds", nargs="*", default=[], help="training sources (ncjax train --data kinds)")
    parser.add_argument("--room", action="append", default=[], metavar="FIELD=LOW:HIGH", help="a RoomConfig range")
    parser.add_argument("--rooms", type=int, default=256, help="rooms drawn per kind")
    args = parser.parse_args(argv)
    try:
        rooms = room_ranges(args.room)
        unknown = [kind for kind in args.kinds if kind not in SYNTH_SOURCES]
        if unknown:
            raise ValueError(f"unknown kinds {unknown}: {', '.join(SYNTH_SOURCES)}")
        sets = {str(args.data): photograph_proportions(args.data)} if args.data else {}
        for kind in args.kinds:
            sets[kind + "".join(f" {setting}" for setting in args.room)] = render_proportions(kind, args.rooms, rooms)
    except ValueError as error:
        print(f"capture_geometry: error: {error}", file=sys.stderr)
        return 2
    names = ("ceiling above the camera", "walls' median distance", "sqrt(floor area)")
    print(f"percentiles {', '.join(map(str, PERCENTILES))} in camera heights")
    print("| set | rooms | " + " | ".join(names) + " |")
    print("| --- | --- |" + " --- |" * len(names))
    for name, values in sets.items():
        cells = [" / ".join(f"{p:.2f}" for p in np.percentile(values[:, i], PERCENTILES)) for i in range(len(names))]
        print(f"| {name} | {len(values)} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
