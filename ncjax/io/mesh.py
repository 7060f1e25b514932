"""The room as triangle meshes: the closed solid as OBJ, PLY and binary glTF (GLB), and the textured room as
GLB; written with trimesh, atomically."""

from __future__ import annotations

import io
import os
import pathlib
from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Int, UInt8

from ..pipeline.types import Layout
from .export import PathLike, has_geometry, signed_area, status_name, valid_corners
from .files import write_atomic

# trimesh takes seconds to import (it loads scipy): the functions that write or triangulate import it, so that
# this module's types and the commands that do not write meshes stay quick to import.

HEADER = "ncjax room layout: metres, camera frame, z up; normals point out of the room"

# --- mesh ------------------------------------------------------------------------------------------------


def triangulate_polygon(xy: Float[np.ndarray, "n 2"]) -> Int[np.ndarray, "n_minus_2 3"]:
    """Triangulation of a simple polygon, convex or not, by trimesh's Manifold engine.

    Manifold keeps every vertex (a corner in the middle of a wall included), unlike earcut, which
    drops the vertices of a self-intersecting polygon and so leaves a hole in the room's mesh.

    Args:
        xy: the polygon's vertices in order, either orientation, no repeated
            closing vertex.

    Returns:
        ``(n - 2, 3)`` vertex indices, every triangle counter-clockwise. For a
        self-intersecting polygon the result is best effort: still n - 2
        triangles using each polygon edge once, but they may overlap.

    Raises:
        ValueError: for fewer than 3 vertices.
    """
    import shapely
    import trimesh

    xy = np.asarray(xy, np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or len(xy) < 3:
        raise ValueError(f"a polygon needs (n >= 3, 2) vertices, got shape {xy.shape}")
    vertices, triangles = trimesh.creation.triangulate_polygon(shapely.Polygon(xy), engine="manifold")
    # The engine returns the ring counter-clockwise, reversed when it was not: name its vertices by their index in xy.
    index = np.argmax(np.all(np.asarray(vertices)[:, None] == xy[None], axis=-1), axis=1)
    return index[np.asarray(triangles, np.int64)]


def room_mesh(layout: Layout) -> tuple[Float[np.ndarray, "V 3"], Int[np.ndarray, "F 3"]]:
    """The room as a closed triangle mesh: walls, floor and ceiling.

    Faces are oriented so that their normals (right-hand rule over the vertex
    order) point OUT of the room, as mesh tools expect of a closed solid: the
    signed volume is positive (floor area times room height). A renderer that
    culls back faces shows the room as a closed box from outside; to look
    around from within, turn culling off or flip the faces. The floor and ceiling are
    triangulated as polygons (:func:`triangulate_polygon`), so non-convex (L-, U-shaped) plans are exact.
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


def _trimesh(vertices, faces, visual=None):
    """trimesh's mesh of our arrays as they are (no merging or reordering of vertices or faces)."""
    import trimesh

    return trimesh.Trimesh(*_check_mesh(vertices, faces), visual=visual, process=False, validate=False)


def write_obj(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as Wavefront OBJ (1-based indices; metres, z up, camera frame), atomically."""
    import trimesh

    text = trimesh.exchange.obj.export_obj(
        _trimesh(vertices, faces), include_normals=False, include_color=False, include_texture=False, header=HEADER
    )
    write_atomic(path, text.encode("ascii"))


def write_ply(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as ASCII PLY (metres, z up, camera frame), atomically."""
    import trimesh

    write_atomic(path, trimesh.exchange.ply.export_ply(_trimesh(vertices, faces), encoding="ascii"))


def z_up_to_y_up(xyz: Float[ArrayLike, "*batch 3"]) -> Float[np.ndarray, "*batch 3"]:
    """Our z-up frame to glTF's y-up one: (x, y, z) -> (x, z, -y), a proper rotation (keeps the winding)."""
    xyz = np.asarray(xyz)
    return np.stack([xyz[..., 0], xyz[..., 2], -xyz[..., 1]], axis=-1)


def write_glb(path: PathLike, vertices: Float[ArrayLike, "V 3"], faces: Int[ArrayLike, "F 3"]) -> None:
    """Write a triangle mesh as binary glTF 2.0 (GLB), atomically.

    glTF is y-up, so the vertices are rotated from our z-up frame by (x, y, z) -> (x, z, -y)
    (:func:`z_up_to_y_up`); glTF's counter-clockwise front faces then face out of the room.
    """
    import trimesh

    vertices, faces = _check_mesh(vertices, faces)
    write_atomic(path, trimesh.exchange.gltf.export_glb(_trimesh(z_up_to_y_up(vertices), faces)))


class SurfaceMesh(NamedTuple):
    """One textured surface of the room (a wall, the floor or the ceiling).

    Attributes:
        name: what it is, e.g. ``wall 3`` (the node's name in the GLB).
        vertices: (V, 3) metres, camera frame, z up.
        faces: (F, 3) vertex indices, normals out of the room.
        uv: (V, 2) texture coordinates, (0, 0) at the texture's bottom-left corner and (1, 1) at its top-right.
    """

    name: str
    vertices: Float[np.ndarray, "V 3"]
    faces: Int[np.ndarray, "F 3"]
    uv: Float[np.ndarray, "V 2"]


class TexturedRoom(NamedTuple):
    """The room's surfaces and the texture they share (:func:`ncjax.viz.room_texture.textured_room`).

    Attributes:
        surfaces: the walls in image order, then the floor and the ceiling.
        texture: (N, N, 3) RGB, the panorama resampled onto every surface.
        unseen: (N, N) the texels that no ray of the panorama sees, in the texture's marker colour.
    """

    surfaces: tuple[SurfaceMesh, ...]
    texture: UInt8[np.ndarray, "N N 3"]
    unseen: Bool[np.ndarray, "N N"]


def texture_jpeg(texture: UInt8[np.ndarray, "H W 3"]) -> bytes:
    """The texture as the JPEG that :func:`write_textured_glb` stores (PIL's encoder at its default quality)."""
    import PIL.Image

    with io.BytesIO() as buffer:
        PIL.Image.fromarray(texture).save(buffer, format="JPEG")
        return buffer.getvalue()


def write_textured_glb(path: PathLike, room: TexturedRoom) -> None:
    """Write the textured room as binary glTF 2.0 (GLB), a node per surface, atomically.

    Every surface shares one material (no metal, full roughness), double-sided so that the
    room is seen from inside too, whose base colour is the room's texture, stored as the
    JPEG of :func:`texture_jpeg`. The vertices are rotated to glTF's y-up frame (:func:`z_up_to_y_up`).
    """
    import PIL.Image
    import trimesh

    image = PIL.Image.fromarray(room.texture)
    # trimesh stores an image whose format is JPEG as JPEG (any other as PNG, several times larger)
    image.format = "JPEG"
    material = trimesh.visual.material.PBRMaterial(
        name="panorama", baseColorTexture=image, metallicFactor=0.0, roughnessFactor=1.0, doubleSided=True
    )
    scene = trimesh.Scene()
    for surface in room.surfaces:
        visual = trimesh.visual.TextureVisuals(uv=surface.uv, material=material)
        mesh = _trimesh(z_up_to_y_up(surface.vertices), surface.faces, visual=visual)
        scene.add_geometry(mesh, node_name=surface.name, geom_name=surface.name)
    write_atomic(path, trimesh.exchange.gltf.export_glb(scene))


def write_mesh(
    stem: PathLike, layout: Layout, textured: TexturedRoom | None = None
) -> tuple[pathlib.Path, pathlib.Path, pathlib.Path]:
    """Write the room as ``stem.obj``, ``stem.ply`` and ``stem.glb``.

    The OBJ and PLY are the closed solid of :func:`room_mesh`; the GLB is the ``textured`` room
    (:func:`write_textured_glb`) where it is given, the solid otherwise.

    Returns:
        The three paths written.

    Raises:
        ValueError: for a failed layout (nothing is written).
    """
    vertices, faces = room_mesh(layout)
    obj, ply, glb = (pathlib.Path(f"{os.fspath(stem)}.{suffix}") for suffix in ("obj", "ply", "glb"))
    write_obj(obj, vertices, faces)
    write_ply(ply, vertices, faces)
    if textured is None:
        write_glb(glb, vertices, faces)
    else:
        write_textured_glb(glb, textured)
    return obj, ply, glb
