"""The room as a closed triangle mesh: OBJ, PLY and binary glTF (GLB), written atomically."""

from __future__ import annotations

import io
import json
import os
import pathlib
import struct

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from ..pipeline.types import Layout
from .export import PathLike, has_geometry, signed_area, status_name, valid_corners
from .files import write_atomic

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
    order) point OUT of the room, as mesh tools expect of a closed solid: the
    signed volume is positive (floor area times room height). A renderer that
    culls back faces shows the room as a closed box from outside; to look
    around from within, turn culling off or flip the faces. The floor and ceiling are
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
        raise ValueError(f"no mesh for a failed layout (status {status_name(layout)})")
    ceiling, floor = valid_corners(layout)
    n = len(floor)
    if n < 3:
        raise ValueError(f"a room needs at least 3 corners, got {n}")
    counter_clockwise = signed_area(floor[:, :2]) > 0
    faces = []
    for k in range(n):
        # Going from corner i to corner j the room is on the left: floor_i, floor_j, ceiling_j turns
        # counter-clockwise seen from the right, outside the room.
        i, j = (k, (k + 1) % n) if counter_clockwise else ((k + 1) % n, k)
        ceiling_i, ceiling_j, floor_i, floor_j = i, j, n + i, n + j
        faces += [[floor_i, floor_j, ceiling_j], [floor_i, ceiling_j, ceiling_i]]
    plan = triangulate_polygon(floor[:, :2])  # counter-clockwise seen from above: normal +z
    faces += (n + plan[:, ::-1]).tolist()  # floor, normal down
    faces += plan.tolist()  # ceiling, normal up
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
    lines = ["# ncjax room layout: metres, camera frame, z up; normals point out of the room"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    write_atomic(path, ("\n".join(lines) + "\n").encode("ascii"))


def write_ply(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as ASCII PLY (metres, z up, camera frame), atomically."""
    vertices, faces = _check_mesh(vertices, faces)
    header = [
        "ply",
        "format ascii 1.0",
        "comment ncjax room layout: metres, camera frame, z up; normals point out of the room",
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
    glTF's counter-clockwise front faces then face out of the room.
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
            {
                "buffer": 0,
                "byteOffset": len(position_bytes),
                "byteLength": len(index_bytes),
                "target": _ELEMENT_ARRAY_BUFFER,
            },
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
    for path, writer in zip(paths, (write_obj, write_ply, write_glb), strict=True):
        writer(path, vertices, faces)
    return paths
