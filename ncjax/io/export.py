"""A reconstructed layout as a JSON record, and the PNG writer.

- :func:`layout_record` / :func:`write_json`: the layout as a versioned JSON
  record (schema below), strict JSON (no NaN).
- :func:`write_png`: an RGB image (the pictures of :mod:`ncjax.viz`).
- The meshes are :mod:`ncjax.io.mesh`'s.

Everything here is numpy on one unbatched :class:`ncjax.Layout` (fields may be
JAX arrays). Every writer is atomic: it writes a temporary file in the target
folder and renames it over the target, so an existing file is replaced only by
a complete one and nothing is left half-written.

JSON schema, version 1 (lengths in metres, camera frame of docs/design.md section 1,
floats rounded to 6 decimals, covariances to 6 significant digits; quantities of a
failed layout are ``null`` and its lists empty, except for a flagged layout (``UNCERTAIN_SCALE``,
``LOW_CONFIDENCE``, ``SCALE_CONFLICT``), which keeps them with ``ok`` false: see :func:`has_geometry`)::

    name, schema_version, ok, status (LayoutStatus name), status_code, world
    (requested: manhattan/atlanta/auto), branch (manhattan/atlanta, or plan: :mod:`ncjax.pipeline.plan`),
    explained_fraction (share of the boundary pixels the layout reprojects within
    the inlier threshold, a quality indicator; added in ncjax 0.1.0, same schema version), rc,
    image_size [W, H] (the image file as given, or a photo sphere's full panorama at the file's scale,
    :mod:`ncjax.io.photo_sphere`: the record's pixels are its pixels),
    reconstructed_size [W, H] (the size the panorama was reconstructed at, the rows' and the
    overlay's: image_size unless the file was resized, :mod:`ncjax.io.images`; added in ncjax
    0.1.0, same schema version), units, frame, ceiling_height, floor_height, room_height,
    floor_area (m^2), perimeter, ceiling_corners / floor_corners [[x, y, z], ...]
    (valid corners, image order), corner_columns (image column of each corner, pixels of image_size),
    walls [{direction, distance, length, inserted, ceiling_line, floor_line}, ...],
    then the caller's extra keys.

Uncertainty (added in ncjax 0.1.0, same schema version; ``null`` where the fit does
not determine it): corner_sigma (per corner, the RMS radius of its plan-position
error, sqrt of the trace of its covariance), corner_covariance (per corner
[[xx, xy], [xy, yy]], m^2), ceiling_height_sigma, floor_height_sigma and room_height_sigma. They are
the first-order covariance of the final adjustment under the boundary rows' noise,
estimated from its residuals and their correlation along the columns
(:attr:`ncjax.Layout.corner_covariance`); a wrong wall structure (a missed or extra
corner) is not part of them.

Wall k runs from corner k to corner k + 1 (cyclic); ``length`` is that
distance. ``direction`` [ux, uy] and ``distance`` d are the wall's line
(docs/design.md section 3) in the canonical sign of :class:`ncjax.Layout`: the
camera on the wall's left, so d <= 0 along (-uy, ux); ``ceiling_line`` and
``floor_line`` its two Plücker lines (6 numbers each); ``inserted`` marks a
wall inserted for an occlusion (not seen in the image).
"""

from __future__ import annotations

import json
import math
import os

import cv2
import jax
import numpy as np
from jaxtyping import Float, UInt8

from ..geometry.camera import NonCentralPanorama
from ..pipeline.config import WORLDS
from ..pipeline.types import FLAGGED_STATUSES, Layout, LayoutStatus
from ..pipeline.uncertainty import room_height_sigma
from .files import write_atomic
from .images import check_rgb
from .layout_corners import resized_pixels

SCHEMA_VERSION = 1
DECIMALS = 6
FRAME = (
    "camera frame: right-handed, metres, z up (gravity), origin at the centre of the circle of optical centres "
    "(plane z = 0); column u looks at azimuth pi - 2 pi (u + 0.5) / W"
)

PathLike = str | os.PathLike


# --- the layout as numpy ---------------------------------------------------------------------------


def status_name(layout: Layout) -> str:
    return LayoutStatus(int(np.asarray(layout.status))).name


def failure_label(layout: Layout) -> str:
    if has_geometry(layout):
        return FLAGGED_STATUSES[LayoutStatus(int(np.asarray(layout.status)))].upper()
    return f"no layout: {status_name(layout)}"


def branch_name(layout: Layout) -> str:
    """Which walls the layout holds: ``"plan"`` (:mod:`ncjax.pipeline.plan`), ``"manhattan"`` or ``"atlanta"``."""
    if bool(np.asarray(layout.plan)):
        return "plan"
    return "manhattan" if bool(np.asarray(layout.manhattan)) else "atlanta"


def has_geometry(layout: Layout) -> bool:
    """Whether the layout's walls and corners are complete: it is ok, or only flagged.

    A layout with one of the :data:`~ncjax.pipeline.types.FLAGGED_STATUSES`
    (``UNCERTAIN_SCALE``, ``LOW_CONFIDENCE``, ``SCALE_CONFLICT``) keeps its geometry in every output
    (record, mesh, overlay, plan), marked as such: it may serve with care.
    """
    return status_has_geometry(np.asarray(layout.ok), np.asarray(layout.status))


def status_has_geometry(ok: bool, status: int) -> bool:
    """:func:`has_geometry` from a layout's ``ok`` and ``status`` alone (e.g. stored results)."""
    return bool(ok) or int(status) in FLAGGED_STATUSES


def valid_corners(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """The valid ceiling and floor corners (n, 3), float64, image order.

    Raises:
        ValueError: for a batched layout.
    """
    mask = np.asarray(layout.mask, bool)
    if mask.ndim != 1:
        raise ValueError(f"expected one unbatched layout (mask of shape (K,)), got mask of shape {mask.shape}")
    # The valid slots come first, so boolean indexing keeps the image order.
    ceiling = np.asarray(layout.ceiling_corners, np.float64)[mask]
    floor = np.asarray(layout.floor_corners, np.float64)[mask]
    return ceiling, floor


def signed_area(xy: Float[np.ndarray, "n 2"]) -> float:
    """Shoelace area of a simple polygon: positive counter-clockwise, negative clockwise."""
    x, y = xy[:, 0], xy[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def wall_lengths(xy: Float[np.ndarray, "n 2"]) -> Float[np.ndarray, " n"]:
    """Length of each wall k, from corner k to corner k + 1 (cyclic)."""
    return np.linalg.norm(np.roll(xy, -1, axis=0) - xy, axis=1)


# --- JSON ---------------------------------------------------------------------------------------------


def _number(x) -> float | None:
    """A JSON number rounded to DECIMALS, ``None`` (JSON null) where not finite: strict JSON never holds NaN."""
    x = float(x)
    # Adding 0.0 turns -0.0 (and tiny negatives rounded to it) into 0.0, which reads better.
    return round(x, DECIMALS) + 0.0 if math.isfinite(x) else None


def _numbers(array, number=_number) -> list:
    """Nested lists of ``number`` (default :func:`_number`) of an array."""
    array = np.asarray(array, np.float64)
    if array.ndim == 0:
        return number(array)
    return [_numbers(row, number) for row in array]


def layout_height_sigma(layout: Layout) -> float:
    """Standard deviation (m) of ``h_c - h_f`` under :attr:`ncjax.Layout.height_covariance` (inf if unknown)."""
    return float(_room_height_sigma(np.asarray(layout.height_covariance, np.float64)))


# one compiled program (kept in the CLI's compilation cache) instead of a compilation per operation
_room_height_sigma = jax.jit(room_height_sigma)


def _significant(x) -> float | None:
    """A JSON number to DECIMALS significant digits (small variances keep their precision), ``None`` if not finite."""
    x = float(x)
    return float(f"{x:.{DECIMALS}g}") + 0.0 if math.isfinite(x) else None


def layout_record(
    layout: Layout,
    cam: NonCentralPanorama,
    *,
    name: str,
    world: str,
    extra: dict | None = None,
    image_size: tuple[int, int] | None = None,
) -> dict:
    """The JSON record of a layout (schema version 1, see the module docstring).

    A failed layout (``ok`` False) still gets a record: ``ok`` false, its
    status, empty corner and wall lists and ``null`` heights, area and perimeter
    (a flagged layout keeps them all, see :func:`has_geometry`).

    Args:
        layout: one unbatched layout.
        cam: the camera the panorama was reconstructed with (its ``rc`` and image size are recorded).
        name: the panorama's name (e.g. the image file stem).
        world: the world model that was requested: "manhattan", "atlanta" or "auto".
        extra: more JSON-serialisable keys to add (e.g. the image path); they
            may not replace the schema's keys.
        image_size: (W, H) of the image file as given (or of a photo sphere's full panorama at the file's scale),
            when it was resized or padded to ``cam``'s size before the reconstruction: ``image_size`` and
            ``corner_columns`` are then in its pixels (None: ``cam``'s size).

    Returns:
        A dict that ``json.dumps(..., allow_nan=False)`` accepts.

    Raises:
        ValueError: for an unknown ``world``, a batched layout or ``extra`` keys clashing with the schema.
    """
    if world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {world!r}")
    ceiling, floor = valid_corners(layout)
    ok = bool(np.asarray(layout.ok))
    file_width, file_height = (cam.width, cam.height) if image_size is None else image_size
    record = {
        "name": name,
        "schema_version": SCHEMA_VERSION,
        "ok": ok,
        "status": status_name(layout),
        "status_code": int(np.asarray(layout.status)),
        "world": world,
        "branch": branch_name(layout),
        "explained_fraction": _number(np.asarray(layout.explained_fraction)),
        "rc": _number(np.asarray(cam.rc)),
        "image_size": [file_width, file_height],
        "reconstructed_size": [cam.width, cam.height],
        "units": "metres",
        "frame": FRAME,
        "ceiling_height": None,
        "floor_height": None,
        "room_height": None,
        "floor_area": None,
        "perimeter": None,
        "ceiling_corners": [],
        "floor_corners": [],
        "corner_columns": [],
        "corner_sigma": [],
        "corner_covariance": [],
        "ceiling_height_sigma": None,
        "floor_height_sigma": None,
        "room_height_sigma": None,
        "walls": [],
    }
    if has_geometry(layout):
        mask = np.asarray(layout.mask, bool)
        ceiling_height = float(np.asarray(layout.ceiling_height))
        floor_height = float(np.asarray(layout.floor_height))
        lengths = wall_lengths(floor[:, :2])
        covariance = np.asarray(layout.corner_covariance, np.float64)[mask]
        height_variance = np.diagonal(np.asarray(layout.height_covariance, np.float64))
        walls = [
            {
                "direction": _numbers(direction),
                "distance": _number(distance),
                "length": _number(length),
                "inserted": bool(inserted),
                "ceiling_line": _numbers(ceiling_line),
                "floor_line": _numbers(floor_line),
            }
            for direction, distance, length, inserted, ceiling_line, floor_line in zip(
                np.asarray(layout.wall_directions)[mask],
                np.asarray(layout.wall_distances)[mask],
                lengths,
                np.asarray(layout.inserted, bool)[mask],
                np.asarray(layout.ceiling_lines)[mask],
                np.asarray(layout.floor_lines)[mask],
                strict=True,
            )
        ]
        record.update(
            ceiling_height=_number(ceiling_height),
            floor_height=_number(floor_height),
            room_height=_number(ceiling_height - floor_height),
            floor_area=_number(abs(signed_area(floor[:, :2]))),
            perimeter=_number(np.sum(lengths)),
            ceiling_corners=_numbers(ceiling),
            floor_corners=_numbers(floor),
            corner_columns=_numbers(resized_pixels(np.asarray(layout.corner_columns)[mask], cam.width, file_width)),
            corner_sigma=_numbers(np.sqrt(np.trace(covariance, axis1=-2, axis2=-1))),
            corner_covariance=_numbers(covariance, _significant),
            ceiling_height_sigma=_number(np.sqrt(height_variance[0])),
            floor_height_sigma=_number(np.sqrt(height_variance[1])),
            room_height_sigma=_number(layout_height_sigma(layout)),
            walls=walls,
        )
    extra = {} if extra is None else extra
    clashes = sorted(set(extra) & set(record))
    if clashes:
        raise ValueError(f"extra keys {clashes} would replace keys of the layout record")
    record.update(extra)
    return record


# --- atomic writes -------------------------------------------------------------------------------------


def write_json(path: PathLike, record: dict) -> None:
    """Write a record as strict, indented JSON, atomically.

    Raises:
        ValueError: if the record holds NaN or infinity (``allow_nan=False``).
    """
    text = json.dumps(record, indent=2, allow_nan=False) + "\n"
    write_atomic(path, text.encode("utf-8"))


def write_png(path: PathLike, image: UInt8[np.ndarray, "H W 3"]) -> None:
    """Write an RGB uint8 image as PNG, atomically."""
    image = check_rgb(image)
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"could not encode an image of shape {image.shape} as PNG")
    write_atomic(path, encoded.tobytes())
