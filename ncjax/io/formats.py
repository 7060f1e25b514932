"""The layout formats of the central-panorama tools (label_cor, HorizonNet, PanoAnnotator, ZInD), and their writers.

Most panoramas are central and most layout tools (HorizonNet, LGT-Net, AtlantaNet,
PanoAnnotator) read and write one of four files. :func:`write_layout_formats` writes
an ncjax layout in any of them (:mod:`ncjax.io.formats_read` reads them back into the
common in-memory form of :mod:`ncjax.io.layout_corners`):

- ``label_cor`` (``<stem>.label_cor.txt``): HorizonNet's corner labels, one ``x y`` line
  per point, the ceiling then the floor point of each corner, in polygon order,
  starting with the leftmost corner (as HorizonNet's loader rolls them). Pixel
  coordinates of the input image with pixel centres at integers: the convention of
  ncjax (docs/design.md section 2), of ``ncjax synth``'s ``label_cor`` and of the
  authors' and HorizonNet's files.
- ``horizonnet`` (``<stem>.horizonnet.json``): what HorizonNet's ``inference.py`` writes:
  ``uv``, the same points as ``label_cor`` divided by the image width and height
  (HorizonNet multiplies them back), ``z0`` = 50 the ceiling plane and ``z1`` the
  floor plane in the same unit (negative), so only their ratio ``h_f / h_c`` counts.
- ``mp3d`` (``<stem>.mp3d.json``): the PanoAnnotator JSON of the MatterportLayout
  labels, which LGT-Net reads and writes: ``cameraHeight`` (camera to floor, metres),
  ``layoutHeight`` (floor to ceiling), ``cameraCeilingHeight`` (LGT-Net's addition),
  ``layoutPoints.points[k]`` with ``xyz`` (the corner at the camera's height, in
  PanoAnnotator's frame X = -y, Y = z, Z = -x of ncjax's frame, so that LGT-Net's
  ``atan2(X, -Z)`` is minus ncjax's azimuth) and ``coords`` ([u, v] in [0, 1],
  LGT-Net's convention ``u = (column + 0.5) / W``), ``layoutWalls.walls[k]`` with
  ``pointsIdx`` [k, k + 1], the unit ``normal`` pointing out of the room,
  ``planeEquation`` [normal, -normal . point] and ``width`` (the wall's length).
- ``zind`` (``<stem>.zind.json``): one panorama entry of ZInD's ``zind_data.json``:
  ``camera_height`` 1 (ZInD's normalisation), ``ceiling_height`` (floor to ceiling, in
  camera heights), ``layout_visible`` and ``layout_raw`` with the floor polygon's
  ``vertices`` (in camera heights), and ``scale_meters_per_coordinate`` (metres per
  unit, i.e. the camera height in metres). Axis convention: ZInD's, in which a vertex
  (x, y) at floor height z is seen at azimuth ``atan2(-x, y)`` increasing to the right
  (ZInD's ``TransformationSpherical``); it is ncjax's plan point with its axes swapped:
  ZInD (x, y) = ncjax (y, x) / camera height.

Every file the writers make holds the corners of one layout with the image's
corner pixels projected by ncjax's camera model (:func:`ncjax.geometry.project`), so the
pixels are exact for non-central panoramas too. The JSON files also carry an
``"ncjax"`` key (``rc``, ``image_size``, ``camera_height`` in metres) that the
other tools ignore and :func:`ncjax.io.formats_read.read_layout` uses to read the
layout back exactly. A tool that assumes a central camera and reads only the 3D corners
(``mp3d``, ``zind``) places the rows of a non-central layout's corners slightly off; the
pixel formats (``label_cor``, HorizonNet's ``uv``) hold the exact rows. Writes are
atomic (a temporary file, then a rename).
"""

from __future__ import annotations

import json
import math
import os
import pathlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import Float

from ..geometry.camera import NonCentralPanorama
from ..pipeline.types import Layout
from .export import PathLike, has_geometry, signed_area, valid_corners
from .files import write_atomic
from .layout_corners import leftmost_first, ncjax_to_panoannotator, project_points, swap_axes

FORMATS = ("label_cor", "horizonnet", "mp3d", "zind")
SUFFIXES = {
    "label_cor": ".label_cor.txt",
    "horizonnet": ".horizonnet.json",
    "mp3d": ".mp3d.json",
    "zind": ".zind.json",
}
EXTRA_KEY = "ncjax"  # the key of the ncjax-only camera data in the JSON formats
HORIZONNET_CEILING_PLANE = 50.0  # HorizonNet's inference.py fixes the ceiling plane at z0 = 50
LABEL_COR_DECIMALS = 3
JSON_DECIMALS = 8


# --- the layout to write -----------------------------------------------------------------------------


def layout_3d_corners(
    layout_or_record: Layout | Mapping[str, Any],
) -> tuple[Float[np.ndarray, "n 3"], Float[np.ndarray, "n 3"]]:
    """The valid (n, 3) ceiling and floor corners, metres, image order, of a Layout or its JSON record.

    Raises:
        ValueError: for a layout without geometry (see :func:`ncjax.io.export.has_geometry`),
            or a record without corners.
    """
    if isinstance(layout_or_record, Mapping):
        record = layout_or_record
        if "ceiling_corners" not in record or "floor_corners" not in record:
            raise ValueError("a layout record needs 'ceiling_corners' and 'floor_corners'")
        ceiling = np.asarray(record["ceiling_corners"], np.float64).reshape(-1, 3)
        floor = np.asarray(record["floor_corners"], np.float64).reshape(-1, 3)
        status = record.get("status", "no corners")
    else:
        if not has_geometry(layout_or_record):
            ceiling = floor = np.zeros((0, 3))
        else:
            ceiling, floor = valid_corners(layout_or_record)
        status = "no geometry"
    if len(ceiling) == 0:
        raise ValueError(f"the layout has no corners to write ({status})")
    if ceiling.shape != floor.shape or len(ceiling) < 3 or not np.all(np.isfinite(ceiling) & np.isfinite(floor)):
        raise ValueError(f"need at least 3 finite ceiling and floor corners, got {ceiling.shape} and {floor.shape}")
    if not (np.mean(floor[:, 2]) < 0.0 < np.mean(ceiling[:, 2])):
        raise ValueError("the ceiling must be above the camera and the floor below it")
    return ceiling, floor


# --- writers -------------------------------------------------------------------------------------------


def _round(array, decimals: int = JSON_DECIMALS):
    """Nested lists of floats rounded to ``decimals`` (a -0.0 becomes 0.0)."""
    return (np.round(np.asarray(array, np.float64), decimals) + 0.0).tolist()


def _extra(cam: NonCentralPanorama, floor: np.ndarray) -> dict:
    return {
        EXTRA_KEY: {
            "rc": round(float(np.asarray(cam.rc)), JSON_DECIMALS),
            "image_size": [cam.width, cam.height],
            "camera_height": round(-float(np.mean(floor[:, 2])), JSON_DECIMALS),
        }
    }


def label_cor_text(ceiling_pixels: Float[np.ndarray, "n 2"], floor_pixels: Float[np.ndarray, "n 2"]) -> str:
    """The ``label_cor`` lines of corner pixels: ``x y`` of the ceiling then the floor point of each corner."""
    points = np.stack([ceiling_pixels, floor_pixels], 1).reshape(-1, 2)
    return "".join(f"{x:.{LABEL_COR_DECIMALS}f} {y:.{LABEL_COR_DECIMALS}f}\n" for x, y in points + 0.0)


def horizonnet_record(
    ceiling_pixels: Float[np.ndarray, "n 2"], floor_pixels: Float[np.ndarray, "n 2"], width: int, height: int, ratio
) -> dict:
    """HorizonNet's inference JSON: ``z0`` 50, ``z1`` = 50 ``h_f / h_c`` (``ratio``) and ``uv`` = pixels / (W, H)."""
    points = np.stack([ceiling_pixels, floor_pixels], 1).reshape(-1, 2) / np.array([width, height], np.float64)
    return {
        "z0": HORIZONNET_CEILING_PLANE,
        "z1": round(HORIZONNET_CEILING_PLANE * float(ratio), JSON_DECIMALS),
        "uv": _round(points),
    }


def mp3d_record(
    floor_plan: Float[np.ndarray, "n 2"],
    ceiling_height: float,
    floor_height: float,
    columns: Float[np.ndarray, " n"],
    width: int,
    name: str,
) -> dict:
    """PanoAnnotator's layout JSON (MatterportLayout, LGT-Net) of a floor plan in ncjax's frame.

    Args:
        floor_plan: (n, 2) corners (x, y), metres, ncjax's camera frame, polygon order.
        ceiling_height: ``h_c`` > 0, metres above the camera.
        floor_height: ``h_f`` < 0.
        columns: (n,) image column of each corner (pixel centres at integers).
        width: image width.
        name: the ``panoId``.
    """
    plan = np.asarray(floor_plan, np.float64)
    xyz = ncjax_to_panoannotator(np.concatenate([plan, np.zeros((len(plan), 1))], 1))
    following = np.roll(plan, -1, axis=0)
    edge = following - plan
    length = np.linalg.norm(edge, axis=1)
    # Outward normals: right of each edge for a counter-clockwise polygon, left for a clockwise one.
    outward = np.stack([edge[:, 1], -edge[:, 0]], -1) / np.maximum(length, 1e-12)[:, None]
    if signed_area(plan) < 0:
        outward = -outward
    normal = ncjax_to_panoannotator(np.concatenate([outward, np.zeros((len(plan), 1))], 1))
    offset = -np.sum(outward * plan, axis=1)
    n = len(plan)
    camera_height = -float(floor_height)
    return {
        "cameraHeight": round(camera_height, JSON_DECIMALS),
        "layoutHeight": round(float(ceiling_height) - float(floor_height), JSON_DECIMALS),
        "cameraCeilingHeight": round(float(ceiling_height), JSON_DECIMALS),
        "layoutObj2ds": {"num": 0, "obj2ds": []},
        "layoutPoints": {
            "num": n,
            "points": [
                {"coords": _round([(column + 0.5) / width, 0.5]), "id": k, "xyz": _round(point)}
                for k, (column, point) in enumerate(zip(columns, xyz, strict=True))
            ],
        },
        "layoutWalls": {
            "num": n,
            "walls": [
                {
                    "id": k,
                    "normal": _round(normal[k]),
                    "planeEquation": _round([*normal[k], offset[k]]),
                    "pointsIdx": [k, (k + 1) % n],
                    "width": round(float(length[k]), JSON_DECIMALS),
                }
                for k in range(n)
            ],
        },
        "panoId": name,
    }


def zind_record(floor_plan: Float[np.ndarray, "n 2"], ceiling_height: float, floor_height: float) -> dict:
    """A ZInD panorama entry (``zind_data.json``'s ``merger`` leaves) of a floor plan in ncjax's frame.

    Lengths are in camera heights (``camera_height`` 1, ZInD's normalisation) with
    ``scale_meters_per_coordinate`` the camera height in metres; ``ceiling_height`` is
    measured from the floor; vertices are ZInD's (x, y) = ncjax's (y, x) / camera height.
    """
    camera_height = -float(floor_height)
    vertices = _round(swap_axes(floor_plan) / camera_height)
    return {
        "camera_height": 1.0,
        "ceiling_height": round((float(ceiling_height) - float(floor_height)) / camera_height, JSON_DECIMALS),
        "is_ceiling_flat": True,
        "is_inside": True,
        "layout_raw": {"vertices": vertices},
        "layout_visible": {"vertices": vertices},
        "scale_meters_per_coordinate": round(camera_height, JSON_DECIMALS),
    }


def check_formats(formats: str | Iterable[str]) -> tuple[str, ...]:
    """The format names of a comma list or an iterable, checked (duplicates dropped, order kept).

    Raises:
        ValueError: for an unknown name.
    """
    names = [name.strip() for name in formats.split(",")] if isinstance(formats, str) else list(formats)
    names = [name for name in names if name]
    unknown = [name for name in names if name not in FORMATS]
    if unknown:
        raise ValueError(f"unknown layout format {unknown[0]!r}: choose among {', '.join(FORMATS)}")
    return tuple(dict.fromkeys(names))


def format_path(stem: PathLike, format: str) -> pathlib.Path:
    """The file of one format beside ``stem``: ``<stem>.label_cor.txt``, ``<stem>.mp3d.json``, ..."""
    check_formats([format])
    return pathlib.Path(f"{os.fspath(stem)}{SUFFIXES[format]}")


def write_layout_formats(
    stem: PathLike,
    layout_or_record: Layout | Mapping[str, Any],
    cam: NonCentralPanorama,
    formats: str | Sequence[str],
    rotation: Float[np.ndarray, "3 3"] | None = None,
) -> list[pathlib.Path]:
    """Write a layout in some of the formats ``label_cor``, ``horizonnet``, ``mp3d`` and ``zind``.

    Args:
        stem: path without suffix: ``out/room`` writes ``out/room.label_cor.txt``, ...
        layout_or_record: one unbatched :class:`ncjax.Layout` or its JSON record
            (:func:`ncjax.io.export.layout_record`; only ``ceiling_corners`` and
            ``floor_corners`` are used).
        cam: the panorama's camera: its size and ``rc`` give the corner pixels.
        formats: format names (a list or a comma list).
        rotation: for a panorama levelled before the reconstruction (:mod:`ncjax.geometry.levelling`),
            the rotation from its input frame to the levelled one: the corner pixels are then those of
            the input image (the corners turned into the input camera's frame, then projected by ``cam``:
            exact for a tilted rig too); the 3D corners of mp3d and zind stay in the levelled frame (z up).

    Returns:
        The paths written, in the order of ``formats``.

    Raises:
        ValueError: for an unknown format, a layout without corners, or a corner no
            ray of the camera sees; nothing is written then.
    """
    formats = check_formats(formats)
    ceiling, floor = layout_3d_corners(layout_or_record)
    # p_input = R^T p_level, i.e. p @ R for row vectors
    seen = (lambda points: points) if rotation is None else (lambda points: points @ np.asarray(rotation, float))
    ceiling_pixels, floor_pixels = project_points(cam, seen(ceiling)), project_points(cam, seen(floor))
    ceiling, floor, ceiling_pixels, floor_pixels = leftmost_first(
        ceiling, floor, ceiling_pixels, floor_pixels, columns=ceiling_pixels[:, 0]
    )
    ceiling_height, floor_height = float(np.mean(ceiling[:, 2])), float(np.mean(floor[:, 2]))
    name = pathlib.Path(stem).name
    contents = {}
    for format in formats:
        if format == "label_cor":
            contents[format] = label_cor_text(ceiling_pixels, floor_pixels)
            continue
        if format == "horizonnet":
            record = horizonnet_record(
                ceiling_pixels, floor_pixels, cam.width, cam.height, floor_height / ceiling_height
            )
        elif format == "mp3d":
            record = mp3d_record(floor[:, :2], ceiling_height, floor_height, floor_pixels[:, 0], cam.width, name)
        else:
            record = zind_record(floor[:, :2], ceiling_height, floor_height)
        contents[format] = json.dumps(record | _extra(cam, floor), indent=1, allow_nan=False) + "\n"
    paths = []
    for format, text in contents.items():
        path = format_path(stem, format)
        write_atomic(path, text.encode("utf-8"))
        paths.append(path)
    return paths


def is_finite_number(value: Any) -> bool:
    """Whether a JSON value is a finite number (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
