"""Readers of the layout formats of :mod:`ncjax.io.formats`, and of ncjax's own JSON record.

:func:`read_layout` recognises a file by its content (``.txt``: ``label_cor``; JSON:
its keys) and returns a :class:`~ncjax.io.layout_corners.LayoutCorners`: the corner
pixels (ceiling and floor of each corner, polygon order) plus, where the format holds
them, the 3D corners in ncjax's camera frame. Formats that hold only 3D corners
(``mp3d``, ``zind``, ncjax's JSON) get their pixels from ncjax's camera model, with
the ``rc`` given, else the one the file carries (the ``"ncjax"`` key), else 0
(central). :func:`layout_files` finds the layout file of each image in a folder.

Besides the four formats it reads ZInD-derived labels that store the floor
``polygon`` at camera height 1 (x = ncjax's x, y = -ncjax's y: the azimuth is
``-atan2(y, x)``) with ``ceiling_height`` above the camera and ``image_size``
(format "polygon"), and any ZInD panorama entry or layout (``vertices``,
``camera_height``, ``ceiling_height``).
"""

from __future__ import annotations

import json
import os
import pathlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from ..geometry.camera import NonCentralPanorama
from .export import PathLike
from .formats import EXTRA_KEY, SUFFIXES, is_finite_number
from .layout_corners import (
    LayoutCorners,
    back_project,
    corners_at,
    corners_from_3d,
    panoannotator_to_ncjax_plan,
    swap_axes,
)

DEFAULT_SIZE = (1024, 512)  # (W, H) of the panoramas of HorizonNet's, LGT-Net's and the authors' datasets
ZIND_LAYOUTS = ("layout_visible", "layout_raw", "layout_complete")
# Suffixes of layout files in the order a folder's file is chosen when an image has several:
# ncjax's own JSON (metric) first, the pixel-only formats last.
FOLDER_SUFFIXES = (
    SUFFIXES["mp3d"],
    SUFFIXES["zind"],
    SUFFIXES["horizonnet"],
    SUFFIXES["label_cor"],
    ".json",
    ".txt",
)
FOLDER_PRIORITY = (".json", SUFFIXES["mp3d"], SUFFIXES["zind"], SUFFIXES["horizonnet"], SUFFIXES["label_cor"], ".txt")


def _stored_size(data: Any) -> Any:
    """The image size a parsed JSON layout records (``image_size``, or in the ncjax key), or None."""
    if not isinstance(data, Mapping):
        return None
    extra = data.get(EXTRA_KEY)
    return data.get("image_size") or (extra.get("image_size") if isinstance(extra, Mapping) else None)


def _size(data: Mapping[str, Any] | None, width: int | None, height: int | None) -> tuple[int, int]:
    """The image size: the caller's, else the file's (``image_size`` or the ncjax key), else 1024 x 512."""
    stored = None if data is None else _stored_size(data)
    stored_width, stored_height = stored if stored else DEFAULT_SIZE
    size = (int(width or stored_width), int(height or stored_height))
    if min(size) <= 0:
        raise ValueError(f"the image size must be positive, got {size[0]} x {size[1]}")
    return size


def _rc(data: Mapping[str, Any], rc: float | None) -> float:
    """The radius: the caller's, else the file's (``rc`` or the ncjax key), else 0 (central)."""
    if rc is not None:
        return float(rc)
    stored = data.get("rc", (data.get(EXTRA_KEY) or {}).get("rc", 0.0))
    return float(stored) if is_finite_number(stored) and stored >= 0 else 0.0


def _points(value: Any, columns: int, what: str) -> np.ndarray:
    """A (n, columns) float64 array of finite numbers, or a one-line ValueError."""
    try:
        array = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a list of {columns}-number points") from None
    if array.ndim != 2 or array.shape[1] != columns or not np.all(np.isfinite(array)):
        raise ValueError(f"{what} must be a list of {columns}-number points, got shape {array.shape}")
    if len(array) < 3:
        raise ValueError(f"{what} needs at least 3 corners, got {len(array)}")
    return array


def _number(data: Mapping[str, Any], key: str, what: str) -> float:
    value = data.get(key)
    if not is_finite_number(value):
        raise ValueError(f"{what} needs a finite number {key!r}, got {value!r}")
    return float(value)


def _pixel_corners(points: np.ndarray, width: int, height: int, format: str, what: str) -> LayoutCorners:
    """:class:`LayoutCorners` of (2n, 2) ``label_cor``-ordered pixels."""
    if len(points) % 2:
        raise ValueError(f"{what} has an odd number of points ({len(points)}): ceiling and floor come in pairs")
    return LayoutCorners(ceiling=points[0::2], floor=points[1::2], width=width, height=height, format=format)


def read_label_cor(path: PathLike, width: int | None = None, height: int | None = None) -> LayoutCorners:
    """A ``label_cor`` file: ``x y`` per line, ceiling then floor point of each corner (pixels).

    Blank lines are skipped and only the first two numbers of a line are read.
    """
    try:
        with open(path, encoding="utf-8") as file:
            lines = file.readlines()
    except UnicodeDecodeError:
        raise ValueError(
            f"{path}: not a layout file: a label_cor is text ('x y' lines) and this file is not (an image?)"
        ) from None
    rows = []
    for number, line in enumerate(lines, 1):
        fields = line.split()
        if not fields:
            continue
        try:
            rows.append((float(fields[0]), float(fields[1])))
        except (ValueError, IndexError):
            raise ValueError(f"{path}:{number}: expected 'x y' pixel coordinates, got {line.strip()!r}") from None
    if len(rows) < 6:
        raise ValueError(f"{path}: a label_cor needs at least 3 corners (6 lines), got {len(rows)} lines")
    points = np.asarray(rows, np.float64)
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{path}: the pixel coordinates must be finite")
    return _pixel_corners(points, *_size(None, width, height), format="label_cor", what=str(path))


def read_horizonnet(
    data: Mapping[str, Any], width: int | None = None, height: int | None = None, rc: float | None = None
) -> LayoutCorners:
    """HorizonNet's inference JSON: ``uv`` in [0, 1] (pixels / (W, H)), ``z0`` and ``z1``.

    With the ``"ncjax"`` key (files of :func:`ncjax.io.formats.write_layout_formats`) the
    3D corners are rebuilt exactly from the floor pixels, the camera height and ``rc``.
    """
    size = _size(data, width, height)
    points = _points(data.get("uv"), 2, "'uv'") * np.array(size, np.float64)
    corners = _pixel_corners(points, *size, format="horizonnet", what="'uv'")
    extra = data.get(EXTRA_KEY) or {}
    camera_height = extra.get("camera_height")
    z0, z1 = data.get("z0"), data.get("z1")
    if not (is_finite_number(camera_height) and is_finite_number(z0) and is_finite_number(z1) and z1 < 0 < z0):
        return corners
    rc = _rc(data, rc)
    cam = NonCentralPanorama(*size, rc=rc)
    floor_height = -float(camera_height)
    plan = back_project(corners.floor, size, floor_height, rc)
    ceiling, floor = corners_at(plan, floor_height * z0 / z1, floor_height)
    return corners_from_3d(ceiling, floor, cam, format="horizonnet", units="metres")


def read_mp3d(
    data: Mapping[str, Any], width: int | None = None, height: int | None = None, rc: float | None = None
) -> LayoutCorners:
    """PanoAnnotator's JSON (MatterportLayout labels, LGT-Net's inputs and outputs).

    The corners are the ``layoutPoints`` in the order of the walls' first points
    (as LGT-Net reads them; the points' order without walls). Only each point's
    X and Z are read (the floor plan); the heights are ``cameraHeight`` and
    ``layoutHeight`` (metres).
    """
    points = data.get("layoutPoints")
    points = points.get("points") if isinstance(points, Mapping) else None
    if not isinstance(points, list) or not all(isinstance(point, Mapping) and "xyz" in point for point in points):
        raise ValueError("'layoutPoints' must hold 'points' with 'xyz'")
    xyz = _points([point["xyz"] for point in points], 3, "'layoutPoints'")
    walls = data.get("layoutWalls")
    walls = walls.get("walls") if isinstance(walls, Mapping) else None
    if walls:
        try:
            order = [int(wall["pointsIdx"][0]) for wall in walls]
        except (KeyError, TypeError, ValueError, IndexError):
            raise ValueError("each of 'layoutWalls' needs 'pointsIdx' [first, second]") from None
        if sorted(order) != list(range(len(xyz))):
            raise ValueError(f"the walls' first points {order} are not each of the {len(xyz)} points once")
        xyz = xyz[order]
    camera_height = _number(data, "cameraHeight", "a PanoAnnotator layout")
    layout_height = _number(data, "layoutHeight", "a PanoAnnotator layout")
    if not 0.0 < camera_height < layout_height:
        raise ValueError(f"need 0 < cameraHeight < layoutHeight, got {camera_height} and {layout_height}")
    cam = NonCentralPanorama(*_size(data, width, height), rc=_rc(data, rc))
    ceiling, floor = corners_at(panoannotator_to_ncjax_plan(xyz), layout_height - camera_height, -camera_height)
    return corners_from_3d(ceiling, floor, cam, format="mp3d", units="metres")


def read_zind(
    data: Mapping[str, Any], width: int | None = None, height: int | None = None, rc: float | None = None
) -> LayoutCorners:
    """A ZInD panorama entry (``layout_visible``, else ``layout_raw``, else ``layout_complete``) or layout.

    ``camera_height`` and ``ceiling_height`` (from the floor) are in ZInD's unit (camera
    height 1); with a numeric ``scale_meters_per_coordinate`` the corners are in metres.
    """
    layout = next((data[key] for key in ZIND_LAYOUTS if isinstance(data.get(key), Mapping)), data)
    vertices = _points(layout.get("vertices"), 2, "ZInD 'vertices'")
    camera_height = _number(data, "camera_height", "a ZInD layout")
    ceiling_height = _number(data, "ceiling_height", "a ZInD layout")
    if not 0.0 < camera_height < ceiling_height:
        raise ValueError(f"need 0 < camera_height < ceiling_height, got {camera_height} and {ceiling_height}")
    scale = data.get("scale_meters_per_coordinate")
    metres = is_finite_number(scale) and scale > 0
    scale = float(scale) if metres else 1.0
    ceiling, floor = corners_at(
        swap_axes(vertices) * scale, (ceiling_height - camera_height) * scale, -camera_height * scale
    )
    cam = NonCentralPanorama(*_size(data, width, height), rc=_rc(data, rc))
    return corners_from_3d(ceiling, floor, cam, format="zind", units="metres" if metres else "camera heights")


def read_polygon(
    data: Mapping[str, Any], width: int | None = None, height: int | None = None, rc: float | None = None
) -> LayoutCorners:
    """ZInD-derived labels: the floor ``polygon`` at ``camera_height``, ``ceiling_height`` above the camera.

    The polygon's (x, y) is ncjax's (x, -y) (its azimuth ``-atan2(y, x)`` increases to the right).
    """
    polygon = _points(data.get("polygon"), 2, "'polygon'")
    camera_height = _number(data, "camera_height", "a floor polygon")
    ceiling_height = _number(data, "ceiling_height", "a floor polygon")
    if camera_height <= 0 or ceiling_height <= 0:
        raise ValueError(f"need camera_height > 0 and ceiling_height > 0, got {camera_height} and {ceiling_height}")
    plan = polygon * np.array([1.0, -1.0])
    ceiling, floor = corners_at(plan, ceiling_height, -camera_height)
    cam = NonCentralPanorama(*_size(data, width, height), rc=_rc(data, rc))
    return corners_from_3d(ceiling, floor, cam, format="polygon", units="camera heights")


def read_record(
    data: Mapping[str, Any], width: int | None = None, height: int | None = None, rc: float | None = None
) -> LayoutCorners:
    """ncjax's JSON record (:func:`ncjax.io.export.layout_record`): corners in metres, camera frame.

    Raises:
        ValueError: for a record without a layout (its status says why).
    """
    ceiling = np.asarray(data.get("ceiling_corners") or [], np.float64)
    if len(ceiling) == 0:
        raise ValueError(f"no layout in the record (status {data.get('status', 'unknown')})")
    ceiling = _points(ceiling, 3, "'ceiling_corners'")
    floor = _points(data.get("floor_corners"), 3, "'floor_corners'")
    if floor.shape != ceiling.shape:
        raise ValueError(f"'ceiling_corners' {ceiling.shape} and 'floor_corners' {floor.shape} differ in shape")
    cam = NonCentralPanorama(*_size(data, width, height), rc=_rc(data, rc))
    return corners_from_3d(ceiling, floor, cam, format="ncjax", units="metres")


JSON_READERS = {
    "horizonnet": read_horizonnet,
    "mp3d": read_mp3d,
    "zind": read_zind,
    "polygon": read_polygon,
    "ncjax": read_record,
}


def json_format(data: Any) -> str:
    """The format of a parsed JSON layout file, from its keys.

    Raises:
        ValueError: for JSON that is none of the formats.
    """
    if isinstance(data, Mapping):
        if "uv" in data:
            return "horizonnet"
        if "layoutPoints" in data:
            return "mp3d"
        if "ceiling_corners" in data and "floor_corners" in data:
            return "ncjax"
        if any(key in data for key in ZIND_LAYOUTS) or ("vertices" in data and "ceiling_height" in data):
            return "zind"
        if "polygon" in data and "ceiling_height" in data:
            return "polygon"
    raise ValueError(
        "not a layout file: expected HorizonNet's 'uv', PanoAnnotator's 'layoutPoints', ZInD's layouts, "
        "a floor 'polygon' or ncjax's 'ceiling_corners'"
    )


def read_layout(
    path: PathLike, width: int | None = None, height: int | None = None, *, rc: float | None = None
) -> LayoutCorners:
    """Read one image's layout from any of the formats (recognised by content).

    Args:
        path: a ``.txt`` (``label_cor``) or ``.json`` file (HorizonNet, PanoAnnotator /
            MatterportLayout / LGT-Net, ZInD, a ZInD-derived floor polygon, or ncjax's record).
        width, height: the image size; default the file's, else 1024 x 512.
        rc: the camera's radius (metres) for the pixels of formats that store 3D corners;
            default the file's, else 0.

    Raises:
        ValueError: for a file of no known format or with bad content (one line).
        FileNotFoundError: for a missing file.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    try:
        if path.suffix.lower() != ".json":
            return read_label_cor(path, width, height)
        try:
            with open(path, encoding="utf-8") as file:
                data = json.load(file)
        except (json.JSONDecodeError, UnicodeDecodeError) as error:
            raise ValueError(f"not valid JSON ({error})") from None
        return JSON_READERS[json_format(data)](data, width, height, rc)
    except ValueError as error:
        message = str(error)
        raise ValueError(message if message.startswith(str(path)) else f"{path}: {message}") from None


def recorded_size(path: PathLike) -> tuple[int, int] | None:
    """The (W, H) of the image that a layout file records (the JSON formats' ``image_size``, ncjax's key), or None:
    a ``label_cor`` file records none, and neither does a file that cannot be read (:func:`read_layout` says why)."""
    path = pathlib.Path(path)
    if path.suffix.lower() != ".json":
        return None
    try:
        with open(path, encoding="utf-8") as file:
            stored = _stored_size(json.load(file))
        width, height = (int(value) for value in stored)
    except (OSError, ValueError, TypeError):
        return None
    return (width, height) if width > 0 and height > 0 else None


def split_layout_name(name: str) -> tuple[str, str] | None:
    """``(stem, suffix)`` of a layout file name (``room.mp3d.json`` -> ``("room", ".mp3d.json")``), else None."""
    lower = name.lower()
    for suffix in FOLDER_SUFFIXES:
        if lower.endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)], suffix
    return None


def layout_files(folder: PathLike) -> dict[str, pathlib.Path]:
    """The layout file of each image stem in a folder (not recursive).

    An image with several files gets ncjax's JSON first, then ``.mp3d.json``,
    ``.zind.json``, ``.horizonnet.json``, ``.label_cor.txt`` and a plain ``.txt``.
    Other files (images, meshes, ``summary.csv``) are left out; files are not read here.
    """
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    found: dict[str, tuple[int, pathlib.Path]] = {}
    for entry in sorted(os.scandir(folder), key=lambda entry: entry.name):
        parts = split_layout_name(entry.name) if entry.is_file() and not entry.name.startswith(".") else None
        if parts is None:
            continue
        stem, suffix = parts
        rank = FOLDER_PRIORITY.index(suffix)
        if stem not in found or rank < found[stem][0]:
            found[stem] = (rank, pathlib.Path(entry.path))
    return {stem: path for stem, (_, path) in sorted(found.items())}
