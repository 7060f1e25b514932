"""Labelled real panoramas: their label_cor and side json read and checked, and the room each label describes.

A label_cor file (HorizonNet's format) holds one ``x y`` line per point, the ceiling then the floor point of each
corner, corners in polygon order, pixels of its image with pixel centres at integers. The label's room is seen by a
central camera at height 1: the floor at z = -1, each floor corner placed in plan from its row, the flat ceiling at
the median height its corners' ceiling rows give, and every column's ray cast to the nearest wall of that polygon
(a straight wall is a curve in the panorama, not a line between its corners' pixels). ``benchmarks/real_panoramas.py``
describes the folder layout and the side json's ``tags`` and per-corner flags.

Input that cannot be scored (an unreadable image, a malformed label or json, a model that does not load:
:func:`load_network`) raises :class:`InputError`, whose message is one line.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import warnings

import numpy as np

from ..geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles
from ..geometry.gravity import panorama_size_error
from ..io.images import PANORAMA_SUFFIXES, PanoramaError, photo_sphere_crop, read_image_file
from ..io.photo_sphere import pad_to_sphere
from ..network.checkpoint import load_model
from ..network.model import HorizonNet
from ..network.predict import default_model
from .network_metrics import REFERENCE_WIDTH

FLAT_CEILING_EXCLUSION_TAG = "ceiling_not_flat"
SAME_CORNER_COLUMNS = 1.0  # label corners closer than this (columns of a 1024-wide image) are one corner
MAX_FLOOR_DISTANCE = 50.0  # camera heights: a predicted floor row at or above the horizon is put this far


class InputError(Exception):
    """Input that cannot be benchmarked; the message is the one line printed."""


@dataclasses.dataclass(frozen=True)
class LabelledPanorama:
    """One panorama and what its label says, at the image's own size.

    Attributes:
        name: the file stem.
        image_path: the image file.
        width, height: the image size in pixels.
        tags: the json's tags (empty without a json).
        score_ceiling: False where the json marks the ceiling as not flat.
        plan: (N, 2) the label's floor corners at camera height 1, polygon order.
        ceiling_height: the flat ceiling's height above the camera, camera heights.
        ceiling_v, floor_v: (W,) the label's boundary rows; NaN where no wall is seen.
        corner_columns: the label's corners a peak must find.
        occluded_columns: label corners on which a peak counts neither way.
    """

    name: str
    image_path: pathlib.Path
    width: int
    height: int
    tags: tuple[str, ...]
    score_ceiling: bool
    plan: np.ndarray
    ceiling_height: float
    ceiling_v: np.ndarray
    floor_v: np.ndarray
    corner_columns: np.ndarray
    occluded_columns: np.ndarray


def central_camera(width: int, height: int) -> NonCentralPanorama:
    """The equirectangular (rc = 0) camera of a ``width x height`` panorama."""
    return NonCentralPanorama(width, height, rc=0.0)


def pixel_angles(cam: NonCentralPanorama, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth and elevation (radians, float64) of pixels, with the project's conventions."""
    azimuth, elevation = pixel_to_angles(cam, np.asarray(u, np.float32), np.asarray(v, np.float32))
    return np.asarray(azimuth, np.float64), np.asarray(elevation, np.float64)


def elevation_rows(cam: NonCentralPanorama, elevation: np.ndarray) -> np.ndarray:
    """Image rows of elevations (the row does not depend on the azimuth)."""
    _, rows = angles_to_pixel(cam, 0.0, np.asarray(elevation, np.float32))
    return np.asarray(rows, np.float64)


def label_room(corners: np.ndarray, cam: NonCentralPanorama) -> tuple[np.ndarray, float]:
    """The label's room at camera height 1: floor corners in plan and the flat ceiling's height.

    Args:
        corners: (N, 2, 2) label points, ``[k, 0]`` the ceiling and ``[k, 1]`` the floor point of corner k.
        cam: the central camera of the image.

    Returns:
        ``(plan, ceiling_height)``: (N, 2) floor corners (the floor at z = -1) and the median over the
        corners of the height their ceiling rows give at their floor corners' distances.
    """
    azimuth, floor_elevation = pixel_angles(cam, corners[:, 1, 0], corners[:, 1, 1])
    distance = 1.0 / np.tan(-floor_elevation)
    plan = distance[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    _, ceiling_elevation = pixel_angles(cam, corners[:, 0, 0], corners[:, 0, 1])
    return plan, float(np.median(distance * np.tan(ceiling_elevation)))


def wall_distances(plan: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Horizontal distance from the camera to the first wall of a polygon along each azimuth (inf: none).

    Wall k runs from ``plan[k]`` to ``plan[k + 1]`` (closed polygon); a ray from the origin along
    ``(cos a, sin a)`` meets it at ``t`` with ``t d = p_k + s (p_k+1 - p_k)``, ``0 <= s <= 1``.
    """
    start = plan[None, :, :]
    edge = (np.roll(plan, -1, axis=0) - plan)[None, :, :]
    direction = np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)[:, None, :]
    cross = lambda a, b: a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # noqa: E731
    denominator = cross(direction, edge)
    usable = np.abs(denominator) > 1e-12
    safe = np.where(usable, denominator, 1.0)
    t = cross(start, edge) / safe
    s = cross(start, direction) / safe
    hit = usable & (t > 1e-9) & (s >= -1e-9) & (s <= 1 + 1e-9)
    return np.min(np.where(hit, t, np.inf), axis=1)


def boundary_rows(
    distance: np.ndarray, ceiling_height: float, cam: NonCentralPanorama
) -> tuple[np.ndarray, np.ndarray]:
    """Ceiling and floor rows of walls at horizontal ``distance`` (camera height 1); NaN where inf."""
    seen = np.isfinite(distance)
    safe = np.where(seen, distance, 1.0)
    ceiling_v = elevation_rows(cam, np.arctan2(ceiling_height, safe))
    floor_v = elevation_rows(cam, np.arctan2(-1.0, safe))
    return np.where(seen, ceiling_v, np.nan), np.where(seen, floor_v, np.nan)


def label_boundaries(corners: np.ndarray, width: int, height: int) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """The label's room and its boundary row in every column of a ``width x height`` central panorama.

    Returns:
        ``(plan, ceiling_height, ceiling_v, floor_v)``, see :func:`label_room` and :func:`boundary_rows`.
    """
    cam = central_camera(width, height)
    plan, ceiling_height = label_room(corners, cam)
    azimuth, _ = pixel_angles(cam, np.arange(width), np.zeros(width))
    ceiling_v, floor_v = boundary_rows(wall_distances(plan, azimuth), ceiling_height, cam)
    return plan, ceiling_height, ceiling_v, floor_v


def raw_prediction_room(ceiling_v: np.ndarray, floor_v: np.ndarray, cam: NonCentralPanorama) -> dict:
    """The predicted rows as a prism at camera height 1: one floor corner per column, one ceiling height.

    A floor row at or above the horizon is put at :data:`MAX_FLOOR_DISTANCE`; the ceiling height is the
    median over the columns whose ceiling row is above and floor row below the horizon.
    """
    width = len(floor_v)
    azimuth, floor_elevation = pixel_angles(cam, np.arange(width), floor_v)
    _, ceiling_elevation = pixel_angles(cam, np.arange(width), ceiling_v)
    distance = 1.0 / np.tan(np.maximum(-floor_elevation, math.atan(1.0 / MAX_FLOOR_DISTANCE)))
    usable = (ceiling_elevation > 1e-3) & (floor_elevation < -1e-3)
    ceiling_height = (
        float(np.median(distance[usable] * np.tan(ceiling_elevation[usable]))) if usable.any() else math.nan
    )
    plan = distance[:, None] * np.stack([np.cos(azimuth), np.sin(azimuth)], axis=-1)
    return prism(plan, ceiling_height)


def prism(plan: np.ndarray, ceiling_height: float) -> dict:
    """A layout for :mod:`.layout_metrics`: vertical walls on ``plan`` from z = -1 to ``ceiling_height``."""
    ones = np.ones((len(plan), 1))
    return {
        "ceiling_corners": np.concatenate([plan, ceiling_height * ones], axis=1),
        "floor_corners": np.concatenate([plan, -ones], axis=1),
    }


def labelled_image_paths(directory: pathlib.Path) -> list[tuple[pathlib.Path, pathlib.Path]]:
    """(image, label_cor) path pairs of a folder: ``<stem>.txt`` beside the image or ``label_cor/<stem>.txt``."""
    pairs = []
    for folder, label_folder in ((directory, directory), (directory / "img", directory / "label_cor")):
        if not folder.is_dir():
            continue
        for image_path in sorted(folder.iterdir()):
            label_path = label_folder / f"{image_path.stem}.txt"
            if image_path.suffix.lower() in PANORAMA_SUFFIXES and image_path.is_file() and label_path.is_file():
                pairs.append((image_path, label_path))
    return pairs


def read_labelled_image(path: pathlib.Path) -> np.ndarray:
    """A full panorama file as RGB uint8 (H, W, 3), W = 2 H, at its own size (its label's pixels); a photo sphere
    padded to its full panorama at the file's scale (:mod:`ncjax.io.photo_sphere`), whose pixels its label gives."""
    try:
        image, data = read_image_file(path)
        crop = photo_sphere_crop(path, data, image.shape[1], image.shape[0])
    except PanoramaError as error:
        raise InputError(str(error)) from None
    if crop is not None:
        image = pad_to_sphere(image, crop, crop.full_width)
    size_error = panorama_size_error(image.shape[1], image.shape[0])
    if size_error:
        raise InputError(f"{path}: {size_error}")
    return image


def read_label_cor(path: pathlib.Path, width: int, height: int) -> np.ndarray:
    """A label_cor file as (N, 2, 2) points: ``[k, 0]`` the ceiling (upper) and ``[k, 1]`` the floor point."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # an empty file: refused below
            points = np.loadtxt(path, dtype=np.float64, ndmin=2)
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise InputError(f"{path}: malformed label_cor ({error})") from None
    if points.ndim != 2 or points.shape[1] != 2 or len(points) % 2 or len(points) < 6:
        raise InputError(f"{path}: malformed label_cor: expected an even number (>= 6) of 'x y' lines")
    if not np.all(np.isfinite(points)):
        raise InputError(f"{path}: malformed label_cor: a coordinate is not a finite number")
    inside = (points[:, 0] >= -1) & (points[:, 0] <= width) & (points[:, 1] >= -1) & (points[:, 1] <= height)
    if not inside.all():
        raise InputError(f"{path}: malformed label_cor: a point lies outside the {width} x {height} image")
    corners = points.reshape(-1, 2, 2)
    upper_first = np.argsort(corners[:, :, 1], axis=1)
    corners = np.take_along_axis(corners, upper_first[:, :, None], axis=1)
    horizon = height / 2 - 0.5
    if np.any(corners[:, 1, 1] <= horizon) or np.any(corners[:, 0, 1] >= horizon):
        raise InputError(
            f"{path}: malformed label_cor: a ceiling point is not above or a floor point not below the horizon"
        )
    return corners


def read_side_metadata(path: pathlib.Path, corner_count: int) -> dict:
    """The json beside an image: ``tags`` and the per-corner ``counted`` / ``occluded`` flags ({} without one)."""
    if not path.is_file():
        return {}
    try:
        metadata = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise InputError(f"{path}: unreadable json ({error})") from None
    tags = metadata.get("tags", []) if isinstance(metadata, dict) else None
    if not isinstance(tags, list) or not all(isinstance(tag, str) for tag in tags):
        raise InputError(f"{path}: expected a json object whose 'tags' is a list of strings")
    for key in ("counted", "occluded"):
        flags = metadata.get(key)
        malformed = not isinstance(flags, list) or len(flags) != corner_count
        if flags is not None and (malformed or not all(isinstance(flag, bool) for flag in flags)):
            raise InputError(f"{path}: '{key}' must hold one true/false per label corner ({corner_count})")
    return metadata


def circular_distance(a: np.ndarray, b: np.ndarray, width: int) -> np.ndarray:
    """Wrap-around distance in columns between column positions (broadcast)."""
    gap = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)) % width
    return np.minimum(gap, width - gap)


def distinct_corners(columns: np.ndarray, width: int) -> np.ndarray:
    """Which label corners to score when the json has no flags: one per column.

    A corner within :data:`SAME_CORNER_COLUMNS` (of a 1024-wide image) of the previous one's column, as an
    occlusion's far point is of its near point, is the same corner.
    """
    gap = circular_distance(columns, np.roll(columns, 1), width)
    distinct = gap > SAME_CORNER_COLUMNS * width / REFERENCE_WIDTH
    if not distinct.any():
        distinct[0] = True
    return distinct


def load_panorama(image_path: pathlib.Path, label_path: pathlib.Path) -> LabelledPanorama:
    """Read and check one labelled panorama (the image is decoded to check it, not kept)."""
    height, width = read_labelled_image(image_path).shape[:2]
    corners = read_label_cor(label_path, width, height)
    metadata = read_side_metadata(image_path.with_suffix(".json"), len(corners))
    tags = tuple(metadata.get("tags", ()))
    columns = corners[:, 1, 0]
    counted = np.asarray(metadata.get("counted", distinct_corners(columns, width)), bool)
    occluded = np.asarray(metadata.get("occluded", np.zeros(len(corners), bool)), bool)
    plan, ceiling_height, ceiling_v, floor_v = label_boundaries(corners, width, height)
    return LabelledPanorama(
        name=image_path.stem,
        image_path=image_path,
        width=width,
        height=height,
        tags=tags,
        score_ceiling=FLAT_CEILING_EXCLUSION_TAG not in tags and metadata.get("ceiling_flat", True) is not False,
        plan=plan,
        ceiling_height=ceiling_height,
        ceiling_v=ceiling_v,
        floor_v=floor_v,
        corner_columns=columns[counted],
        occluded_columns=columns[occluded],
    )


def load_panoramas(directory: pathlib.Path, limit: int | None) -> list[LabelledPanorama]:
    """Every labelled panorama of a folder (the first ``limit`` by name), all checked before any is scored."""
    if not directory.is_dir():
        raise InputError(f"{directory}: no such folder")
    pairs = labelled_image_paths(directory)
    if not pairs:
        raise InputError(f"{directory}: no labelled panorama (an image with <stem>.txt beside it or in label_cor/)")
    return [load_panorama(*pair) for pair in pairs[:limit]]


def load_network(path: pathlib.Path | None) -> HorizonNet:
    """The model in ``path``, or the shipped one."""
    try:
        return default_model() if path is None else load_model(path)
    except Exception as error:  # safetensors and the checkpoint reader raise several kinds
        raise InputError(f"cannot load the model: {error}") from None
