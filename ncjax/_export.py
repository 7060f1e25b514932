"""Everything a user gets on disk for one reconstructed panorama.

- :func:`layout_record` / :func:`write_json`: the layout as a versioned JSON
  record (schema below), strict JSON (no NaN).
- :func:`room_mesh` and :func:`write_obj` / :func:`write_ply` /
  :func:`write_glb` / :func:`write_mesh`: the room as a closed triangle mesh.
- :func:`draw_overlay`: the layout reprojected onto the panorama.
- :func:`draw_plan`: the top-down floor plan in metres.
- :func:`write_png`: an RGB image.

Everything here is numpy on one unbatched :class:`ncjax.Layout` (fields may be
JAX arrays). Every writer is atomic: it writes a temporary file in the target
folder and renames it over the target, so an existing file is replaced only by
a complete one and nothing is left half-written.

JSON schema, version 1 (lengths in metres, camera frame of DESIGN.md section 1,
floats rounded to 6 decimals, covariances to 6 significant digits; quantities of a
failed layout are ``null`` and its lists empty, except for an ``UNCERTAIN_SCALE`` layout,
which keeps them with ``ok`` false: see :func:`has_geometry`)::

    name, schema_version, ok, status (LayoutStatus name), status_code, world
    (requested: manhattan/atlanta/auto), branch (manhattan/atlanta),
    explained_fraction (share of the boundary pixels the layout reprojects within
    the inlier threshold, a quality indicator; added in ncjax 0.1.0, same schema version), rc,
    image_size [W, H], units, frame, ceiling_height, floor_height, room_height,
    floor_area (m^2), perimeter, ceiling_corners / floor_corners [[x, y, z], ...]
    (valid corners, image order), corner_columns (image column of each corner),
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
(DESIGN.md section 3) in the canonical sign of :class:`ncjax.Layout`: the
camera on the wall's left, so d <= 0 along (-uy, ux); ``ceiling_line`` and
``floor_line`` its two Plücker lines (6 numbers each); ``inserted`` marks a
wall inserted for an occlusion (not seen in the image).
"""

from __future__ import annotations

import io
import json
import math
import os
import pathlib
import struct

import cv2
import numpy as np
from jaxtyping import ArrayLike, Float, Int, UInt8
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from matplotlib.ticker import MultipleLocator

from . import _adjust
from ._camera import NonCentralPanorama, project
from ._files import write_atomic
from ._pipeline import WORLDS, Layout, LayoutStatus

SCHEMA_VERSION = 1
DECIMALS = 6
FRAME = (
    "camera frame: right-handed, metres, z up (gravity), origin at the centre of the circle of optical centres "
    "(plane z = 0); column u looks at azimuth pi - 2 pi (u + 0.5) / W"
)

# Overlay colours (RGB).
NETWORK_COLOUR = (255, 190, 0)  # the network's per-column boundaries
LAYOUT_COLOUR = (0, 230, 255)  # the reprojected layout
INSERTED_COLOUR = (255, 40, 200)  # walls inserted for an occlusion (not seen in the image)
CORNER_COLOUR = (255, 255, 255)  # the corner probability strip

PathLike = str | os.PathLike


# --- the layout as numpy ---------------------------------------------------------------------------


def _status_name(layout: Layout) -> str:
    return LayoutStatus(int(np.asarray(layout.status))).name


def _failure_label(layout: Layout) -> str:
    return "UNCERTAIN SCALE" if has_geometry(layout) else f"no layout: {_status_name(layout)}"


def has_geometry(layout: Layout) -> bool:
    """Whether the layout's walls and corners are complete: it is ok, or failed only the scale test.

    An ``UNCERTAIN_SCALE`` layout keeps its geometry in every output (record,
    mesh, overlay, plan), marked as such: its shape may serve up to scale.
    """
    return status_has_geometry(np.asarray(layout.ok), np.asarray(layout.status))


def status_has_geometry(ok: bool, status: int) -> bool:
    """:func:`has_geometry` from a layout's ``ok`` and ``status`` alone (e.g. stored results)."""
    return bool(ok) or int(status) == LayoutStatus.UNCERTAIN_SCALE


def _valid_corners(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
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


def room_height_sigma(layout: Layout) -> float:
    """Standard deviation (m) of ``h_c - h_f`` under :attr:`ncjax.Layout.height_covariance` (inf if unknown)."""
    return float(_adjust.room_height_sigma(np.asarray(layout.height_covariance, np.float64)))


def _significant(x) -> float | None:
    """A JSON number to DECIMALS significant digits (small variances keep their precision), ``None`` where not finite."""
    x = float(x)
    return float(f"{x:.{DECIMALS}g}") + 0.0 if math.isfinite(x) else None


def layout_record(layout: Layout, cam: NonCentralPanorama, *, name: str, world: str, extra: dict | None = None) -> dict:
    """The JSON record of a layout (schema version 1, see the module docstring).

    A failed layout (``ok`` False) still gets a record: ``ok`` false, its
    status, empty corner and wall lists and ``null`` heights, area and perimeter
    (an ``UNCERTAIN_SCALE`` layout keeps them all, see :func:`has_geometry`).

    Args:
        layout: one unbatched layout.
        cam: the camera of the panorama (its ``rc`` and image size are recorded).
        name: the panorama's name (e.g. the image file stem).
        world: the world model that was requested: "manhattan", "atlanta" or "auto".
        extra: more JSON-serialisable keys to add (e.g. the image path); they
            may not replace the schema's keys.

    Returns:
        A dict that ``json.dumps(..., allow_nan=False)`` accepts.

    Raises:
        ValueError: for an unknown ``world``, a batched layout or ``extra`` keys clashing with the schema.
    """
    if world not in WORLDS:
        raise ValueError(f"world must be one of {WORLDS}, got {world!r}")
    ceiling, floor = _valid_corners(layout)
    ok = bool(np.asarray(layout.ok))
    record = {
        "name": name,
        "schema_version": SCHEMA_VERSION,
        "ok": ok,
        "status": _status_name(layout),
        "status_code": int(np.asarray(layout.status)),
        "world": world,
        "branch": "manhattan" if bool(np.asarray(layout.manhattan)) else "atlanta",
        "explained_fraction": _number(np.asarray(layout.explained_fraction)),
        "rc": _number(np.asarray(cam.rc)),
        "image_size": [cam.width, cam.height],
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
            corner_columns=_numbers(np.asarray(layout.corner_columns)[mask]),
            corner_sigma=_numbers(np.sqrt(np.trace(covariance, axis1=-2, axis2=-1))),
            corner_covariance=_numbers(covariance, _significant),
            ceiling_height_sigma=_number(np.sqrt(height_variance[0])),
            floor_height_sigma=_number(np.sqrt(height_variance[1])),
            room_height_sigma=_number(room_height_sigma(layout)),
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
    image = _check_rgb(image)
    ok, encoded = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    if not ok:
        raise ValueError(f"could not encode an image of shape {image.shape} as PNG")
    write_atomic(path, encoded.tobytes())


# --- mesh ------------------------------------------------------------------------------------------------


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z of (a - o) x (b - o); broadcasts over leading axes."""
    return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])


def triangulate_polygon(xy: Float[np.ndarray, "n 2"]) -> Int[np.ndarray, "n_minus_2 3"]:
    """Ear-clipping triangulation of a simple polygon, convex or not (O(n^2) ears, n small).

    Args:
        xy: the polygon's vertices in order, either orientation, no repeated
            closing vertex.

    Returns:
        ``(n - 2, 3)`` vertex indices, every triangle counter-clockwise. A
        vertex collinear with its neighbours is never cut off alone (that
        triangle would be degenerate). For a self-intersecting polygon the
        result is best effort: still n - 2 triangles using each polygon edge
        once, but they may overlap.

    Raises:
        ValueError: for fewer than 3 vertices.
    """
    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 3:
        raise ValueError(f"a polygon needs (n >= 3, 2) vertices, got shape {xy.shape}")
    # Work counter-clockwise: then an ear tip is a vertex with a left turn.
    order = list(range(len(xy))) if signed_area(xy) >= 0 else list(range(len(xy)))[::-1]
    scale = float(np.max(np.ptp(xy, axis=0))) or 1.0
    tolerance = 1e-12 * scale**2
    triangles = []
    while len(order) > 3:
        points = xy[order]
        previous, following = np.roll(points, 1, axis=0), np.roll(points, -1, axis=0)
        turn = _cross(previous, points, following)
        ear = None
        for i in np.argsort(-turn):  # most convex first: better shaped triangles
            if turn[i] <= tolerance:
                break
            a, b, c = previous[i], points[i], following[i]
            others = np.delete(points, [(i - 1) % len(order), i, (i + 1) % len(order)], axis=0)
            # A vertex on the triangle's boundary blocks the ear too (it would leave a T-junction).
            inside = (
                (_cross(a, b, others) >= -tolerance)
                & (_cross(b, c, others) >= -tolerance)
                & (_cross(c, a, others) >= -tolerance)
            )
            if not np.any(inside):
                ear = i
                break
        if ear is None:  # self-intersecting or degenerate input: cut the most convex vertex
            ear = int(np.argmax(turn))
        triangles.append([order[(ear - 1) % len(order)], order[ear], order[(ear + 1) % len(order)]])
        del order[ear]
    triangles.append(order)
    return np.asarray(triangles, np.int64)


def room_mesh(layout: Layout) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]:
    """The room as a closed triangle mesh: walls, floor and ceiling.

    Faces are oriented so that their normals (right-hand rule over the vertex
    order) point INTO the room: the viewer stands inside, and a renderer that
    culls back faces shows the room from within (from outside it shows a
    doll's house: the near walls are culled). The floor and ceiling are
    triangulated by ear clipping, so non-convex (L-, U-shaped) plans are exact.
    Inserted walls are walls like the others. The mesh is watertight: every
    edge is shared by exactly two faces, in opposite directions.

    Args:
        layout: one unbatched layout with its geometry (:func:`has_geometry`).

    Returns:
        ``vertices`` (2n, 3) metres, camera frame: the n ceiling corners then
        the n floor corners, image order; ``faces`` (4n - 4, 3) vertex indices:
        two triangles per wall (wall k first), then the n - 2 floor and the
        n - 2 ceiling triangles.

    Raises:
        ValueError: for a failed layout or one with fewer than 3 corners.
    """
    if not has_geometry(layout):
        raise ValueError(f"no mesh for a failed layout (status {_status_name(layout)})")
    ceiling, floor = _valid_corners(layout)
    n = len(floor)
    if n < 3:
        raise ValueError(f"a room needs at least 3 corners, got {n}")
    counter_clockwise = signed_area(floor[:, :2]) > 0
    faces = []
    for k in range(n):
        # Going from corner i to corner j the room is on the left.
        i, j = (k, (k + 1) % n) if counter_clockwise else ((k + 1) % n, k)
        ceiling_i, ceiling_j, floor_i, floor_j = i, j, n + i, n + j
        faces += [[floor_i, ceiling_j, floor_j], [floor_i, ceiling_i, ceiling_j]]
    plan = triangulate_polygon(floor[:, :2])  # counter-clockwise seen from above: normal +z
    faces += (n + plan).tolist()  # floor, normal up
    faces += plan[:, ::-1].tolist()  # ceiling, normal down
    return np.concatenate([ceiling, floor]), np.asarray(faces, np.int64)


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"expected vertices (V, 3) and faces (F, 3), got {vertices.shape} and {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"face indices must lie in [0, {len(vertices)})")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("vertices must be finite")
    return vertices, faces.astype(np.int64)


def write_obj(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as Wavefront OBJ (1-based indices; metres, z up, camera frame), atomically."""
    vertices, faces = _check_mesh(vertices, faces)
    lines = ["# ncjax room layout: metres, camera frame, z up; normals point into the room"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    write_atomic(path, ("\n".join(lines) + "\n").encode("ascii"))


def write_ply(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as ASCII PLY (metres, z up, camera frame), atomically."""
    vertices, faces = _check_mesh(vertices, faces)
    header = [
        "ply",
        "format ascii 1.0",
        "comment ncjax room layout: metres, camera frame, z up; normals point into the room",
        f"element vertex {len(vertices)}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    lines = header + [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices] + [f"3 {a} {b} {c}" for a, b, c in faces]
    write_atomic(path, ("\n".join(lines) + "\n").encode("ascii"))


# glTF 2.0 constants (Khronos specification).
_GLB_MAGIC = 0x46546C67  # "glTF"
_CHUNK_JSON = 0x4E4F534A  # "JSON"
_CHUNK_BIN = 0x004E4942  # "BIN\0"
_FLOAT = 5126
_UNSIGNED_INT = 5125
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_TRIANGLES = 4


def z_up_to_y_up(xyz: Float[ArrayLike, "*batch 3"]) -> Float[np.ndarray, "*batch 3"]:
    """Our z-up frame to glTF's y-up one: (x, y, z) -> (x, z, -y), a proper rotation (keeps the winding)."""
    xyz = np.asarray(xyz)
    return np.stack([xyz[..., 0], xyz[..., 2], -xyz[..., 1]], axis=-1)


def _pad(payload: bytes, fill: bytes) -> bytes:
    """Pad a GLB chunk to a multiple of 4 bytes (JSON with spaces, binary with zeros)."""
    return payload + fill * (-len(payload) % 4)


def write_glb(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as binary glTF 2.0 (GLB), atomically.

    One mesh of one triangle primitive: float32 POSITION (with the min/max the
    specification requires) and uint32 indices. glTF is y-up, so the vertices
    are rotated from our z-up frame by (x, y, z) -> (x, z, -y) (:func:`z_up_to_y_up`);
    glTF's counter-clockwise front faces then face into the room.
    """
    vertices, faces = _check_mesh(vertices, faces)
    positions = z_up_to_y_up(vertices).astype("<f4")
    indices = faces.astype("<u4")
    position_bytes, index_bytes = positions.tobytes(), indices.tobytes()  # both multiples of 4 bytes
    gltf = {
        "asset": {"version": "2.0", "generator": "ncjax"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "room"}],
        "meshes": [{"name": "room", "primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": _TRIANGLES}]}],
        "buffers": [{"byteLength": len(position_bytes) + len(index_bytes)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(position_bytes), "target": _ARRAY_BUFFER},
            {"buffer": 0, "byteOffset": len(position_bytes), "byteLength": len(index_bytes), "target": _ELEMENT_ARRAY_BUFFER},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": _FLOAT,
                "count": len(positions),
                "type": "VEC3",
                # Bounds of the float32 values actually stored, as validators compare them.
                "min": positions.min(axis=0).astype(float).tolist(),
                "max": positions.max(axis=0).astype(float).tolist(),
            },
            {"bufferView": 1, "componentType": _UNSIGNED_INT, "count": indices.size, "type": "SCALAR"},
        ],
    }
    json_chunk = _pad(json.dumps(gltf, separators=(",", ":")).encode("utf-8"), b" ")
    bin_chunk = _pad(position_bytes + index_bytes, b"\x00")
    total = 12 + 8 + len(json_chunk) + 8 + len(bin_chunk)
    glb = io.BytesIO()
    glb.write(struct.pack("<III", _GLB_MAGIC, 2, total))
    glb.write(struct.pack("<II", len(json_chunk), _CHUNK_JSON) + json_chunk)
    glb.write(struct.pack("<II", len(bin_chunk), _CHUNK_BIN) + bin_chunk)
    write_atomic(path, glb.getvalue())


def write_mesh(stem: PathLike, layout: Layout) -> tuple[pathlib.Path, pathlib.Path, pathlib.Path]:
    """Write the room mesh (:func:`room_mesh`) as ``stem.obj``, ``stem.ply`` and ``stem.glb``.

    Returns:
        The three paths written.

    Raises:
        ValueError: for a failed layout (nothing is written).
    """
    vertices, faces = room_mesh(layout)
    paths = tuple(pathlib.Path(f"{os.fspath(stem)}.{suffix}") for suffix in ("obj", "ply", "glb"))
    for path, writer in zip(paths, (write_obj, write_ply, write_glb)):
        writer(path, vertices, faces)
    return paths


# --- overlay on the panorama --------------------------------------------------------------------------


def _check_rgb(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    return image


def _draw_curve(canvas: np.ndarray, u: np.ndarray, v: np.ndarray, colour: tuple[int, int, int], thickness: int) -> None:
    """Draw sampled image points as antialiased polylines, broken at NaNs and where u wraps at the seam."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    finite = np.isfinite(u) & np.isfinite(v)
    breaks = ~finite[1:] | ~finite[:-1] | (np.abs(np.diff(u)) > canvas.shape[1] / 2)
    shift = 4  # cv2 draws at 1/16-pixel precision from fixed-point coordinates
    for run in np.split(np.arange(len(u)), np.flatnonzero(breaks) + 1):
        if len(run) < 2 or not finite[run[0]]:
            continue
        points = np.round(np.stack([u[run], v[run]], axis=-1) * 2**shift).astype(np.int32)
        cv2.polylines(canvas, [points], False, colour, thickness, cv2.LINE_AA, shift)


def draw_overlay(
    image: UInt8[np.ndarray, "H W 3"],
    layout: Layout,
    cam: NonCentralPanorama,
    ceiling_v: Float[ArrayLike, " W"] | None = None,
    floor_v: Float[ArrayLike, " W"] | None = None,
    corner_prob: Float[ArrayLike, " W"] | None = None,
) -> UInt8[np.ndarray, "H W 3"]:
    """The panorama with the network's boundaries and the recovered layout drawn on it.

    - the network's ceiling and floor rows per column, if given, in
      ``NETWORK_COLOUR``;
    - the layout's ceiling and floor edges, sampled densely in 3D and
      projected with :func:`ncjax.project` (the curves of a non-central
      camera), and the vertical edges at the corners, in ``LAYOUT_COLOUR``;
      inserted walls (occluded, not seen) in ``INSERTED_COLOUR``. Curves break
      at the image seam and where points are not visible;
    - the corner probability, if given, as a plot strip along the bottom.

    A failed layout draws only the network's outputs and a "no layout" label;
    an ``UNCERTAIN_SCALE`` one is drawn with an "uncertain scale" label.

    Args:
        image: the panorama, RGB uint8 (H, W, 3).
        layout: one unbatched layout.
        cam: the camera; its size must be the image's.
        ceiling_v, floor_v, corner_prob: optional network outputs, (W,) each.

    Returns:
        A new RGB uint8 image; ``image`` is not modified.

    Raises:
        ValueError: for an image that is not RGB uint8, a camera of another
            size than the image, or network outputs not of shape (W,).
    """
    canvas = _check_rgb(image).copy()
    height, width = canvas.shape[:2]
    if (cam.width, cam.height) != (width, height):
        raise ValueError(f"camera size {cam.width} x {cam.height} differs from the image's {width} x {height}")
    outputs = {"ceiling_v": ceiling_v, "floor_v": floor_v, "corner_prob": corner_prob}
    for key, value in outputs.items():
        if value is not None and np.shape(value) != (width,):
            raise ValueError(f"{key} must have shape ({width},), got {np.shape(value)}")
    thickness = max(1, round(width / 512))
    columns = np.arange(width, dtype=np.float64)

    for rows in (ceiling_v, floor_v):
        if rows is not None:
            _draw_curve(canvas, columns, np.asarray(rows, np.float64), NETWORK_COLOUR, thickness)

    if has_geometry(layout):
        ceiling, floor = _valid_corners(layout)
        inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
        n = len(ceiling)
        # Edges are sampled densely because a non-central camera images them as curves. A vertical
        # edge has one azimuth (a straight column) but is sampled too, so invisible parts break it.
        along = np.linspace(0.0, 1.0, max(64, width // 2))[None, :, None]
        up = np.linspace(0.0, 1.0, 16)[None, :, None]
        following = np.roll(np.arange(n), -1)
        ceiling_edges = ceiling[:, None] + along * (ceiling[following] - ceiling)[:, None]
        floor_edges = floor[:, None] + along * (floor[following] - floor)[:, None]
        vertical_edges = floor[:, None] + up * (ceiling - floor)[:, None]
        samples = np.concatenate([ceiling_edges.reshape(-1, 3), floor_edges.reshape(-1, 3), vertical_edges.reshape(-1, 3)])
        u, v = project(cam, samples.astype(np.float32))  # one call for everything: one dispatch
        u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
        horizontal = 2 * n * along.shape[1]
        u_edges, v_edges = u[:horizontal].reshape(2, n, -1), v[:horizontal].reshape(2, n, -1)
        u_vertical, v_vertical = u[horizontal:].reshape(n, -1), v[horizontal:].reshape(n, -1)
        for k in range(n):
            colour = INSERTED_COLOUR if inserted[k] else LAYOUT_COLOUR
            for edge in range(2):  # ceiling, floor
                _draw_curve(canvas, u_edges[edge, k], v_edges[edge, k], colour, thickness)
            _draw_curve(canvas, u_vertical[k], v_vertical[k], LAYOUT_COLOUR, thickness)
    if not bool(np.asarray(layout.ok)):
        scale = height / 512
        cv2.putText(
            canvas,
            _failure_label(layout),
            (round(8 * scale), round(32 * scale)),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            INSERTED_COLOUR,
            thickness,
            cv2.LINE_AA,
        )

    if corner_prob is not None:
        strip = max(16, height // 8)
        canvas[height - strip :] //= 2  # darken the strip so the plot reads on any image
        probability = np.clip(np.asarray(corner_prob, np.float64), 0.0, 1.0)
        _draw_curve(canvas, columns, height - 1 - probability * (strip - 1), CORNER_COLOUR, thickness)
    return canvas


# --- floor plan ------------------------------------------------------------------------------------------


def _figure_to_rgb(figure: Figure) -> np.ndarray:
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


CHI2_2D_95 = 5.991464547107979  # 95% quantile of the chi-square distribution with 2 degrees of freedom


def corner_ellipses(covariance: Float[ArrayLike, "n 2 2"]) -> Float[np.ndarray, "n 3"]:
    """Full width, full height and angle (degrees) of each corner's 95% ellipse (matplotlib's ``Ellipse``).

    The ellipse ``e^T C^-1 e <= chi2_2(0.95)`` of a 2D Gaussian error with
    covariance ``C``: semi-axes ``sqrt(chi2 lambda)`` along ``C``'s
    eigenvectors. NaN for a covariance that is not finite.
    """
    covariance = np.asarray(covariance, np.float64).reshape(-1, 2, 2)
    finite = np.all(np.isfinite(covariance), axis=(1, 2))
    values, vectors = np.linalg.eigh(np.where(finite[:, None, None], covariance, np.eye(2)))
    axes = 2 * np.sqrt(CHI2_2D_95 * np.maximum(values, 0.0))
    angle = np.degrees(np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1]))
    ellipses = np.stack([axes[:, 1], axes[:, 0], angle], -1)
    return np.where(finite[:, None], ellipses, np.nan)


def draw_plan(layout: Layout, *, title: str = "", rc: float | None = None) -> UInt8[np.ndarray, "H W 3"]:
    """The top-down floor plan: x right, y up, metres, camera at the origin.

    Walls are lines with their length written at their middle (inserted walls
    dashed), each corner carries the ellipse that holds its true position with
    95% probability under :attr:`ncjax.Layout.corner_covariance`, the origin
    is marked, and the circle of optical centres is drawn if ``rc`` is given.
    The title gives the ceiling and floor heights, the room height (with its
    standard deviation) and the floor area. A failed layout gives a figure saying
    "no layout: <status>". Matplotlib's Agg canvas is used directly: no
    pyplot state is left behind.

    Args:
        layout: one unbatched layout.
        title: first line of the title (e.g. the panorama's name).
        rc: radius of the circle of optical centres, metres.

    Returns:
        An RGB uint8 image (600 x 600 pixels).
    """
    figure = Figure(figsize=(6, 6), dpi=100)
    axes = figure.add_subplot()
    if not has_geometry(layout):
        axes.set_axis_off()
        axes.text(0.5, 0.5, _failure_label(layout), ha="center", va="center", fontsize=16)
        if title:
            axes.set_title(title)
        return _figure_to_rgb(figure)

    _, floor = _valid_corners(layout)
    inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
    plan = floor[:, :2]
    n = len(plan)
    lengths = wall_lengths(plan)
    axes.fill(plan[:, 0], plan[:, 1], color="0.92", zorder=0)
    for k in range(n):
        start, end = plan[k], plan[(k + 1) % n]
        axes.plot(
            [start[0], end[0]],
            [start[1], end[1]],
            color="tab:red" if inserted[k] else "tab:blue",
            linestyle="--" if inserted[k] else "-",
            linewidth=2,
            label=("inserted wall" if inserted[k] else "wall"),
        )
        middle = (start + end) / 2
        axes.annotate(f"{lengths[k]:.2f} m", middle, ha="center", va="center", fontsize=8, bbox={"fc": "white", "ec": "none", "alpha": 0.8})
    covariance = np.asarray(layout.corner_covariance, np.float64)[np.asarray(layout.mask, bool)]
    for centre, (width, height, angle) in zip(plan, corner_ellipses(covariance)):
        if np.isfinite(width):
            axes.add_patch(
                Ellipse(centre, width, height, angle=angle, facecolor="tab:orange", alpha=0.35, edgecolor="tab:orange",
                        label="95% corner region")
            )
    axes.plot([0.0], [0.0], marker="+", color="black", markersize=10, linestyle="none", label="origin")
    if rc is not None:
        angle = np.linspace(0.0, 2 * np.pi, 90)
        axes.plot(rc * np.cos(angle), rc * np.sin(angle), color="black", linewidth=1, label=f"camera (rc = {rc:.2f} m)")
    handles, labels = axes.get_legend_handles_labels()
    axes.autoscale_view()
    unique = dict(zip(labels, handles))  # one legend entry per kind of line
    axes.legend(unique.values(), unique.keys(), loc="best", fontsize=8)

    axes.set_aspect("equal", adjustable="datalim")
    axes.xaxis.set_major_locator(MultipleLocator(1.0))
    axes.yaxis.set_major_locator(MultipleLocator(1.0))
    axes.grid(True, color="0.8", linewidth=0.5)
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    ceiling_height = float(np.asarray(layout.ceiling_height))
    floor_height = float(np.asarray(layout.floor_height))
    height_sigma = room_height_sigma(layout)
    spread = f" ± {height_sigma:.2f}" if math.isfinite(height_sigma) else ""
    summary = (
        f"ceiling {ceiling_height:.2f} m, floor {floor_height:.2f} m, height {ceiling_height - floor_height:.2f}{spread} m, "
        f"area {abs(signed_area(plan)):.2f} m²"
    )
    if not bool(np.asarray(layout.ok)):
        summary = f"{_failure_label(layout)}: {summary}"
    axes.set_title(f"{title}\n{summary}" if title else summary, fontsize=10)
    figure.tight_layout()
    return _figure_to_rgb(figure)
