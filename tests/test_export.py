"""Export of one layout: JSON record, room mesh (OBJ, PLY, GLB), overlay, floor plan, atomic writes."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import struct

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import ncjax
import ncjax.io.export
import ncjax.io.mesh
import ncjax.viz.overlay
import ncjax.viz.plan

H_C, H_F = 1.0, -1.5
# Floor plans in image order (decreasing azimuth, so clockwise seen from above), camera at the origin.
RECTANGLE = [(-1.5, 1.8), (2.5, 1.8), (2.5, -1.2), (-1.5, -1.2)]  # 4 x 3 m, walls 4, 3, 4, 3
L_SHAPE = [(-2.0, 3.0), (1.0, 3.0), (1.0, 1.0), (3.0, 1.0), (3.0, -2.0), (-2.0, -2.0)]  # 5 x 5 less 2 x 2: 21 m^2
U_SHAPE = [(-3, 3), (-1, 3), (-1, 0.5), (1, 0.5), (1, 3), (3, 3), (3, -2), (-3, -2)]  # 6 x 5 less 2 x 2.5: 25 m^2


def make_layout(plan, ceiling_height=H_C, floor_height=H_F, *, inserted=(), capacity=8, status=0, manhattan=True):
    """A Layout filled by hand like the pipeline fills it: canonical walls (camera on the left), padded slots."""
    plan = np.asarray(plan, np.float64)
    n = len(plan)
    delta = np.roll(plan, -1, axis=0) - plan
    direction = delta / np.linalg.norm(delta, axis=1, keepdims=True)
    distance = np.sum(plan * np.stack([-direction[:, 1], direction[:, 0]], -1), -1)
    sign = np.where(distance > 0, -1.0, 1.0)
    direction, distance = direction * sign[:, None], distance * sign

    def line(height):
        ux, uy = direction[:, 0], direction[:, 1]
        return np.stack([ux, uy, 0 * ux, -height * uy, height * ux, -distance], -1)

    def pad(x, value=0.0):
        x = np.asarray(x)
        return np.concatenate([x, np.full((capacity - n,) + x.shape[1:], value, x.dtype)])

    def at(height):
        return np.concatenate([plan, np.full((n, 1), height)], -1)

    columns = (math.pi - np.arctan2(plan[:, 1], plan[:, 0])) / (2 * math.pi) * 1024 - 0.5

    def f32(x):
        return jnp.asarray(x, jnp.float32)

    return ncjax.Layout(
        ceiling_corners=f32(pad(at(ceiling_height))),
        floor_corners=f32(pad(at(floor_height))),
        mask=jnp.asarray(pad(np.ones(n, bool), False)),
        ceiling_height=f32(ceiling_height),
        floor_height=f32(floor_height),
        wall_directions=f32(pad(direction)),
        wall_distances=f32(pad(distance)),
        ceiling_lines=f32(pad(line(ceiling_height))),
        floor_lines=f32(pad(line(floor_height))),
        inserted=jnp.asarray(pad(np.isin(np.arange(n), inserted), False)),
        corner_columns=f32(pad(columns)),
        manhattan=jnp.asarray(manhattan),
        plan=jnp.asarray(False),
        explained_fraction=f32(0.9),
        corner_covariance=f32(pad(np.tile(np.diag([4e-4, 1e-4]), (n, 1, 1)))),
        height_covariance=f32(np.diag([1e-4, 4e-4])),
        status=jnp.asarray(status, jnp.int32),
        ok=jnp.asarray(status == 0),
    )


def failed_layout():
    layout = make_layout(RECTANGLE, status=int(ncjax.LayoutStatus.DEGENERATE_LAYOUT))
    nan = jnp.full_like(layout.ceiling_corners, jnp.nan)  # meaningless corners must not leak into the JSON
    return ncjax.Layout(
        **{**vars(layout), "ceiling_corners": nan, "floor_corners": nan, "ceiling_height": jnp.float32(jnp.nan)}
    )


CAM = ncjax.NonCentralPanorama(1024, 512, rc=0.6)


# --- JSON record ------------------------------------------------------------------------------------


def test_record_of_a_rectangle(tmp_path):
    record = ncjax.io.export.layout_record(
        make_layout(RECTANGLE), CAM, name="room", world="auto", extra={"image": "room.png"}
    )
    assert record["schema_version"] == 1 and record["ok"] is True
    assert (record["status"], record["status_code"], record["world"], record["branch"]) == (
        "OK",
        0,
        "auto",
        "manhattan",
    )
    assert record["explained_fraction"] == pytest.approx(0.9)
    assert record["image_size"] == record["reconstructed_size"] == [1024, 512]
    assert record["units"] == "metres" and record["image"] == "room.png"
    assert record["rc"] == pytest.approx(0.6)
    assert (record["ceiling_height"], record["floor_height"], record["room_height"]) == (1.0, -1.5, 2.5)
    assert record["floor_area"] == 12.0 and record["perimeter"] == 14.0
    assert [wall["length"] for wall in record["walls"]] == [4.0, 3.0, 4.0, 3.0]
    assert record["ceiling_corners"] == [[x, y, 1.0] for x, y in RECTANGLE]
    assert record["floor_corners"] == [[x, y, -1.5] for x, y in RECTANGLE]
    assert len(record["corner_columns"]) == 4 and not any(wall["inserted"] for wall in record["walls"])
    assert record["corner_sigma"] == [round(math.sqrt(5e-4), 6)] * 4
    assert record["corner_covariance"] == [[[pytest.approx(4e-4), 0.0], [0.0, pytest.approx(1e-4)]]] * 4
    assert (record["ceiling_height_sigma"], record["floor_height_sigma"]) == (pytest.approx(0.01), pytest.approx(0.02))
    assert record["room_height_sigma"] == round(math.sqrt(5e-4), 6)
    # Canonical walls: camera on the left, distance <= 0; the far wall y = 1.8 runs towards -x.
    assert record["walls"][0]["direction"] == [-1.0, 0.0] and record["walls"][0]["distance"] == -1.8
    path = tmp_path / "room.json"
    ncjax.io.export.write_json(path, record)
    assert json.loads(path.read_text()) == record
    assert "-0.0," not in path.read_text() and "-0.0]" not in path.read_text()


def test_record_without_covariances():
    layout = make_layout(RECTANGLE)
    nan = jnp.full_like(layout.corner_covariance, jnp.nan)  # PipelineConfig(covariance=False)
    layout = ncjax.Layout(**{**vars(layout), "corner_covariance": nan, "height_covariance": nan[0]})
    record = ncjax.io.export.layout_record(layout, CAM, name="room", world="auto")
    assert record["corner_sigma"] == [None] * 4 and record["corner_covariance"] == [[[None, None]] * 2] * 4
    assert record["ceiling_height_sigma"] is record["room_height_sigma"] is None
    json.dumps(record, allow_nan=False)
    assert ncjax.viz.plan.draw_plan(layout).shape == (600, 600, 3)


def test_failed_layout_record_is_strict_json(tmp_path):
    record = ncjax.io.export.layout_record(failed_layout(), CAM, name="bad", world="manhattan")
    assert record["ok"] is False and record["status"] == "DEGENERATE_LAYOUT" and record["status_code"] == 8
    assert record["ceiling_corners"] == record["floor_corners"] == record["walls"] == []
    assert record["ceiling_height"] is None and record["floor_area"] is None
    assert record["corner_sigma"] == record["corner_covariance"] == [] and record["ceiling_height_sigma"] is None
    text = json.dumps(record, allow_nan=False)
    assert "NaN" not in text
    ncjax.io.export.write_json(tmp_path / "bad.json", record)
    assert json.loads((tmp_path / "bad.json").read_text()) == record


@pytest.mark.parametrize("status", list(ncjax.pipeline.types.FLAGGED_STATUSES))
def test_flagged_layout_keeps_its_geometry_marked_not_ok(tmp_path, status):
    """A flagged layout (scale or network unsure): record, mesh, overlay and plan keep it, marked."""
    uncertain = make_layout(RECTANGLE, status=int(status))
    assert ncjax.io.export.failure_label(uncertain) == ncjax.pipeline.types.FLAGGED_STATUSES[status].upper()
    record = ncjax.io.export.layout_record(uncertain, CAM, name="room", world="auto")
    assert record["ok"] is False and record["status"] == status.name
    assert record["floor_corners"] == [[x, y, -1.5] for x, y in RECTANGLE] and record["room_height"] == 2.5
    assert ncjax.io.export.has_geometry(uncertain) and not ncjax.io.export.has_geometry(failed_layout())
    obj, _, _ = ncjax.io.mesh.write_mesh(tmp_path / "room", uncertain)
    assert obj.is_file()
    cam = ncjax.NonCentralPanorama(512, 256, rc=0.6)
    image = np.full((256, 512, 3), 90, np.uint8)
    drawn = ncjax.viz.overlay.draw_overlay(image, make_layout(RECTANGLE), cam)
    marked = ncjax.viz.overlay.draw_overlay(image, uncertain, cam)
    assert (drawn != image).any() and (marked[:30] != drawn[:30]).any()  # the layout, then the label above it
    assert not np.array_equal(ncjax.viz.plan.draw_plan(uncertain), ncjax.viz.plan.draw_plan(make_layout(RECTANGLE)))


def test_a_record_of_a_resized_file_gives_the_file_s_size_and_columns():
    """Reconstructed at 1024 x 512 from a 2050 x 1025 file: image_size and corner_columns are the file's (the
    image's edges, not its first and last pixel centres, keep their places), reconstructed_size the camera's."""
    layout = make_layout(RECTANGLE)
    record = ncjax.io.export.layout_record(layout, CAM, name="room", world="auto", image_size=(2050, 1025))
    assert record["image_size"] == [2050, 1025] and record["reconstructed_size"] == [1024, 512]
    columns = np.asarray(layout.corner_columns, np.float64)[np.asarray(layout.mask)]
    np.testing.assert_allclose(record["corner_columns"], (columns + 0.5) * 2050 / 1024 - 0.5, atol=1e-5)
    same = ncjax.io.export.layout_record(layout, CAM, name="room", world="auto")
    changed = ("image_size", "corner_columns")
    assert {key: value for key, value in record.items() if key not in changed} == {
        key: value for key, value in same.items() if key not in changed
    }


def test_a_status_prints_as_its_name():
    status = ncjax.LayoutStatus.LOW_CONFIDENCE
    assert str(ncjax.LayoutStatus.OK) == "OK" and f"{status}" == "LOW_CONFIDENCE"
    assert int(status) == 10 and json.dumps({"status": status}) == '{"status": 10}'  # a number where one is read


def test_the_plan_is_framed_on_the_room_not_on_its_corner_ellipses():
    """A corner region far larger than the room (a flagged layout's) is cut at the frame: the walls stay in place."""
    layout = make_layout(L_SHAPE)
    vague = dataclasses.replace(layout, corner_covariance=1e4 * jnp.eye(2) * layout.mask[:, None, None])
    blue = np.array([31, 119, 180])  # the walls' colour, drawn above the ellipses

    def walls(plan):
        return np.all(plan == blue, axis=-1)

    sharp_plan, vague_plan = ncjax.viz.plan.draw_plan(layout), ncjax.viz.plan.draw_plan(vague)
    assert walls(sharp_plan).sum() > 500 and np.array_equal(walls(sharp_plan), walls(vague_plan))


def test_record_rejects_bad_arguments():
    layout = make_layout(RECTANGLE)
    with pytest.raises(ValueError, match="world"):
        ncjax.io.export.layout_record(layout, CAM, name="room", world="cuboid")
    with pytest.raises(ValueError, match="extra"):
        ncjax.io.export.layout_record(layout, CAM, name="room", world="auto", extra={"status": "fine"})
    with pytest.raises(ValueError):
        ncjax.io.export.write_json("unused.json", {"x": float("nan")})
    assert not os.path.exists("unused.json")


# --- mesh -----------------------------------------------------------------------------------------


def check_room_mesh(vertices, faces, plan, ceiling_height=H_C, floor_height=H_F):
    """Non-degenerate, outward-facing, watertight, and the floor and ceiling cover the plan exactly."""
    polygon = shapely.Polygon(plan)
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    normals = np.cross(b - a, c - a)
    areas = np.linalg.norm(normals, axis=1) / 2
    assert np.all(areas > 1e-6), "degenerate face"
    unit = normals / (2 * areas[:, None])
    z = vertices[faces][:, :, 2]
    floor, ceiling = np.all(z == floor_height, axis=1), np.all(z == ceiling_height, axis=1)
    walls = ~floor & ~ceiling
    np.testing.assert_allclose(unit[floor], np.tile([0, 0, -1], (floor.sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(unit[ceiling], np.tile([0, 0, 1], (ceiling.sum(), 1)), atol=1e-9)
    assert areas[floor].sum() == pytest.approx(polygon.area) and areas[ceiling].sum() == pytest.approx(polygon.area)
    assert np.sum(walls) == 2 * len(plan)
    np.testing.assert_allclose(unit[walls, 2], 0.0, atol=1e-9)
    centroids = (a + b + c)[walls, :2] / 3
    for centroid, normal in zip(centroids, unit[walls, :2], strict=True):
        assert not polygon.contains(shapely.Point(centroid + 1e-3 * normal)), "wall normal points into the room"
        assert polygon.contains(shapely.Point(centroid - 1e-3 * normal))
    # Watertight and consistently oriented: each directed edge once, its reverse once.
    directed = [(int(f[i]), int(f[(i + 1) % 3])) for f in faces for i in range(3)]
    assert len(set(directed)) == len(directed)
    assert all((j, i) in set(directed) for i, j in directed)
    # Outward normals: the divergence theorem gives the enclosed volume.
    signed_volume = np.sum(np.einsum("ij,ij->i", a, np.cross(b, c))) / 6
    assert signed_volume == pytest.approx(polygon.area * (ceiling_height - floor_height))


@pytest.mark.parametrize("plan,area", [(RECTANGLE, 12.0), (L_SHAPE, 21.0), (U_SHAPE, 25.0)])
def test_room_mesh_of_non_convex_rooms(plan, area):
    layout = make_layout(plan, inserted=(1,))
    vertices, faces = ncjax.io.mesh.room_mesh(layout)
    assert vertices.shape == (2 * len(plan), 3) and faces.shape == (4 * len(plan) - 4, 3)
    check_room_mesh(vertices.astype(np.float64), faces, plan)
    assert ncjax.io.export.layout_record(layout, CAM, name="r", world="manhattan")["floor_area"] == area
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent


def test_triangulation_of_star_and_collinear_polygons():
    angle = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    radius = np.where(np.arange(24) % 2 == 0, 3.0, 1.2)
    star = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    # A spurious corner in the middle of a wall: it may not be cut off alone.
    collinear = np.array([(0, 0), (2, 0), (4, 0), (4, 3), (0, 3)], float)
    for polygon in (star, star[::-1], collinear, collinear[::-1]):
        triangles = ncjax.io.mesh.triangulate_polygon(polygon)
        assert triangles.shape == (len(polygon) - 2, 3)
        area = np.array([ncjax.io.export.signed_area(polygon[triangle]) for triangle in triangles])
        assert np.all(area > 1e-9)  # counter-clockwise and non-degenerate
        assert area.sum() == pytest.approx(abs(ncjax.io.export.signed_area(polygon)))
    check_room_mesh(*ncjax.io.mesh.room_mesh(make_layout(collinear[::-1] - 1.5)), collinear[::-1] - 1.5)


def test_a_self_intersecting_plan_still_gives_a_closed_mesh():
    """Best effort: n - 2 triangles that use each edge of the plan once, so the room's mesh stays closed."""
    crossing = np.array([(-2.0, -2.0), (2.0, -2.0), (2.0, 1.0), (0.0, -3.0), (-2.0, 1.0)])
    triangles = ncjax.io.mesh.triangulate_polygon(crossing)
    assert triangles.shape == (3, 3) and sorted(np.unique(triangles)) == [0, 1, 2, 3, 4]
    vertices, faces = ncjax.io.mesh.room_mesh(make_layout(crossing))
    assert trimesh.Trimesh(vertices, faces, process=False).is_watertight


def test_no_mesh_for_a_failed_layout(tmp_path):
    with pytest.raises(ValueError, match="DEGENERATE_LAYOUT"):
        ncjax.io.mesh.write_mesh(tmp_path / "bad", failed_layout())
    assert list(tmp_path.iterdir()) == []


def read_obj(path):
    vertices, faces = [], []
    for line in path.read_text().splitlines():
        kind, *values = line.split() or [""]
        if kind == "v":
            vertices.append([float(x) for x in values])
        elif kind == "f":
            faces.append([int(x) - 1 for x in values])
    return np.array(vertices), np.array(faces)


def test_obj_and_ply_round_trip(tmp_path):
    vertices, faces = ncjax.io.mesh.room_mesh(make_layout(L_SHAPE))
    obj, ply, glb = ncjax.io.mesh.write_mesh(tmp_path / "room", make_layout(L_SHAPE))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.glb", "room.obj", "room.ply"]
    read_vertices, read_faces = read_obj(obj)
    np.testing.assert_allclose(read_vertices, vertices, atol=1e-6)
    np.testing.assert_array_equal(read_faces, faces)
    mesh = trimesh.load(ply, process=False)
    np.testing.assert_allclose(mesh.vertices, vertices, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, faces)


def test_glb_layout_and_axis_conversion(tmp_path):
    vertices, faces = ncjax.io.mesh.room_mesh(make_layout(U_SHAPE))
    path = tmp_path / "room.glb"
    ncjax.io.mesh.write_glb(path, vertices, faces)
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data)) and data[:4] == b"glTF"
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    gltf = json.loads(data[20 : 20 + json_length])
    bin_length, bin_type = struct.unpack_from("<II", data, 20 + json_length)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0 and 28 + json_length + bin_length == len(data)
    binary = data[28 + json_length :]
    primitive = gltf["meshes"][0]["primitives"][0]
    position, index = gltf["accessors"][primitive["attributes"]["POSITION"]], gltf["accessors"][primitive["indices"]]
    assert gltf["asset"]["version"] == "2.0" and primitive.get("mode", 4) == 4  # triangles
    view = gltf["bufferViews"][position["bufferView"]]
    offset = view["byteOffset"] + position.get("byteOffset", 0)
    positions = np.frombuffer(binary, "<f4", position["count"] * 3, offset).reshape(-1, 3)
    expected = np.stack([vertices[:, 0], vertices[:, 2], -vertices[:, 1]], -1)  # z up -> y up
    np.testing.assert_allclose(positions, expected, atol=1e-6)
    assert position["min"] == positions.min(0).tolist() and position["max"] == positions.max(0).tolist()
    view = gltf["bufferViews"][index["bufferView"]]
    assert index["componentType"] == 5125
    offset = view["byteOffset"] + index.get("byteOffset", 0)
    np.testing.assert_array_equal(np.frombuffer(binary, "<u4", index["count"], offset).reshape(-1, 3), faces)
    # An independent reader agrees.
    mesh = trimesh.load(path, force="mesh", process=False)
    np.testing.assert_allclose(mesh.vertices, expected, atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, faces)


# --- overlay ----------------------------------------------------------------------------------------


def weighted_row(column_pixels, channel, around, reach=6):
    """Intensity-weighted row of one colour channel within ``reach`` rows of ``around``."""
    rows = np.arange(round(around) - reach, round(around) + reach + 1)
    weights = column_pixels[rows, channel].astype(np.float64)
    assert weights.sum() > 100, "nothing drawn near the expected row"
    return float(np.sum(rows * weights) / weights.sum())


def test_overlay_passes_through_the_exact_boundaries():
    width, height = 512, 256
    corners = np.array(RECTANGLE[::-1])  # the room is counter-clockwise
    room = ncjax.synth.Room(
        corners=jnp.asarray(np.concatenate([corners, np.zeros((4, 2))]), jnp.float32),
        mask=jnp.arange(8) < 4,
        ceiling_height=jnp.float32(H_C),
        floor_height=jnp.float32(H_F),
        rc=jnp.float32(0.5),
        camera_position=jnp.array([1.5, 1.2, 1.5], jnp.float32),
        is_atlanta=jnp.array(False),
        status=jnp.array(0, jnp.int32),
    )
    cam = room.camera(width, height)
    labels = jax.jit(ncjax.synth.room_labels)(room, cam)  # compiled: faster than op by op
    ceiling_v, floor_v = np.asarray(labels.ceiling_v), np.asarray(labels.floor_v)
    corner_u = np.asarray(labels.corner_u)[np.asarray(labels.corner_mask)]
    image = np.zeros((height, width, 3), np.uint8)
    offset = 12.0  # network rows drawn apart from the layout, to tell them apart
    overlay = ncjax.viz.overlay.draw_overlay(
        image, make_layout(RECTANGLE), cam, ceiling_v + offset, floor_v - offset, labels.corner_target
    )
    assert overlay.dtype == np.uint8 and overlay.shape == image.shape and not image.any()
    columns = [u for u in range(8, width - 8, 23) if np.min(np.abs((u - corner_u + width / 2) % width - width / 2)) > 8]
    assert len(columns) > 10
    for u in columns:
        # LAYOUT_COLOUR has no red, NETWORK_COLOUR no blue: each channel sees one of them.
        assert weighted_row(overlay[:, u], 2, ceiling_v[u]) == pytest.approx(ceiling_v[u], abs=0.5)
        assert weighted_row(overlay[:, u], 2, floor_v[u]) == pytest.approx(floor_v[u], abs=0.5)
        assert weighted_row(overlay[:, u], 0, ceiling_v[u] + offset) == pytest.approx(ceiling_v[u] + offset, abs=0.5)
        assert not overlay[height // 2 - 5 : height // 2 + 5, u].any()  # nothing drawn at the horizon
    for u in np.round(corner_u).astype(int) % width:  # vertical edges at the corners
        assert overlay[height // 2, u - 1 : u + 2, 2].max() > 100
    strip = max(16, height // 8)
    u = int(np.round(corner_u[0])) % width
    assert overlay[height - strip : height - strip + 3, u].min(axis=1).max() > 100  # probability ~1 at a corner


def test_curves_break_at_the_seam_and_at_nan():
    canvas = np.zeros((32, 64, 3), np.uint8)
    ncjax.viz.overlay._draw_curve(canvas, np.array([60.0, 62.0, 63.0, 0.5, 2.0]), np.full(5, 10.0), (255, 255, 255), 1)
    assert canvas[10, 62].any() and canvas[10, 1].any() and not canvas[:, 5:58].any()
    ncjax.viz.overlay._draw_curve(
        canvas, np.array([10.0, 20.0, np.nan, 30.0, 40.0]), np.full(5, 20.0), (255, 255, 255), 1
    )
    assert canvas[20, 15].any() and canvas[20, 35].any() and not canvas[20, 22:28].any()


def test_overlay_checks_sizes_and_draws_failed_layouts():
    image = np.full((256, 512, 3), 90, np.uint8)
    with pytest.raises(ValueError, match="camera size"):
        ncjax.viz.overlay.draw_overlay(image, make_layout(RECTANGLE), CAM)
    cam = ncjax.NonCentralPanorama(512, 256, rc=0.6)
    with pytest.raises(ValueError, match="RGB"):
        ncjax.viz.overlay.draw_overlay(image[..., 0], make_layout(RECTANGLE), cam)
    overlay = ncjax.viz.overlay.draw_overlay(image, failed_layout(), cam, np.full(512, 40.0), np.full(512, 200.0))
    assert overlay.shape == image.shape and (overlay[:30] != image[:30]).any()  # the "no layout" label
    # Antialiased lines blend into the neighbouring rows; the line's own row is mostly NETWORK_COLOUR.
    assert overlay[40, 5:-5, 0].min() > 200 and overlay[40, 5:-5, 2].max() < 30 and overlay[200, 5:-5, 0].min() > 200


# --- floor plan ------------------------------------------------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(st.floats(-89.0, 89.0), st.floats(1e-4, 1.0), st.floats(1e-4, 1.0))
def test_corner_ellipses_hold_95_percent(angle, major, minor):
    major, minor = max(major, minor), min(major, minor)
    turn = np.radians(angle)
    rotation = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    covariance = rotation @ np.diag([major, minor]) @ rotation.T
    ((width, height, got),) = ncjax.viz.plan.corner_ellipses(covariance[None])
    np.testing.assert_allclose([width, height], 2 * np.sqrt(5.991464547107979 * np.array([major, minor])), rtol=1e-6)
    if major > 1.001 * minor:  # the orientation of a circle is arbitrary
        assert abs((got - angle + 90) % 180 - 90) < 1e-3
    samples = np.random.default_rng(0).multivariate_normal([0, 0], covariance, 20000)
    half_width, half_height = width / 2, height / 2
    along = samples @ np.array([np.cos(np.radians(got)), np.sin(np.radians(got))])
    across = samples @ np.array([-np.sin(np.radians(got)), np.cos(np.radians(got))])
    inside = (along / half_width) ** 2 + (across / half_height) ** 2 <= 1
    assert abs(np.mean(inside) - 0.95) < 0.01
    assert np.all(np.isnan(ncjax.viz.plan.corner_ellipses(np.full((1, 2, 2), np.inf))))


def test_plan_images():
    plan = ncjax.viz.plan.draw_plan(make_layout(L_SHAPE, inserted=(2,)), title="room", rc=0.6)
    assert plan.dtype == np.uint8 and plan.shape == (600, 600, 3)
    assert plan.std() > 10  # something drawn on the white figure
    failed = ncjax.viz.plan.draw_plan(failed_layout(), title="bad")
    assert failed.shape == (600, 600, 3) and failed.dtype == np.uint8 and (failed != 255).any()
    assert not np.array_equal(failed, plan)


# --- atomic writes --------------------------------------------------------------------------------------


def test_png_round_trip(tmp_path):
    image = np.random.default_rng(0).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    ncjax.io.export.write_png(tmp_path / "image.png", image)
    np.testing.assert_array_equal(cv2.cvtColor(cv2.imread(str(tmp_path / "image.png")), cv2.COLOR_BGR2RGB), image)
    assert os.listdir(tmp_path) == ["image.png"]


@pytest.mark.parametrize("failing", ["fsync", "replace"])
def test_interrupted_write_keeps_the_old_file(tmp_path, monkeypatch, failing):
    path = tmp_path / "room.json"
    ncjax.io.export.write_json(path, {"version": "old"})

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, failing, fail)
    with pytest.raises(OSError, match="disk full"):
        ncjax.io.export.write_json(path, {"version": "new"})
    monkeypatch.undo()
    assert json.loads(path.read_text()) == {"version": "old"}
    assert os.listdir(tmp_path) == ["room.json"]  # no temporary file left behind
    ncjax.io.export.write_json(path, {"version": "new"})
    assert json.loads(path.read_text()) == {"version": "new"} and os.listdir(tmp_path) == ["room.json"]
