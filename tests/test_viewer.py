"""The room in 3D: the panorama textured onto the layout (glTF), the viewer's page, the index of a folder of
results and ``ncjax view``. The pages in a real browser are tests/test_browser.py's."""

from __future__ import annotations

import io
import json
import math
import re
import threading
import urllib.request

import numpy as np
import PIL.Image
import pytest
import trimesh
from test_export import L_SHAPE, RECTANGLE, U_SHAPE, failed_layout, make_layout

from ncjax import cli
from ncjax.cli import view
from ncjax.cli.outputs import ReconstructedImage, write_outputs
from ncjax.geometry.camera import NonCentralPanorama, project
from ncjax.io.export import layout_record
from ncjax.io.mesh import texture_jpeg, write_mesh, z_up_to_y_up
from ncjax.pipeline.types import LayoutStatus
from ncjax.viz.gallery import index_html
from ncjax.viz.room_texture import UNSEEN_COLOUR, textured_room
from ncjax.viz.viewer import CHI2_95, viewer_html, viewer_scene

WIDTH, HEIGHT, RC = 512, 256, 0.3
CAM = NonCentralPanorama(WIDTH, HEIGHT, rc=RC)


def direction_panorama(width=WIDTH, height=HEIGHT):
    """A panorama whose colour changes smoothly with the direction of each pixel (JPEG keeps it nearly exact)."""
    azimuth = math.pi - 2 * math.pi * (np.arange(width) + 0.5) / width
    elevation = math.pi / 2 - math.pi * (np.arange(height) + 0.5) / height
    red = 128 + 100 * np.cos(azimuth)[None, :] * np.ones((height, 1))
    green = 128 + 100 * np.sin(azimuth)[None, :] * np.ones((height, 1))
    blue = 128 + 200 / math.pi * elevation[:, None] * np.ones((1, width))
    return np.round(np.stack([red, green, blue], axis=-1)).astype(np.uint8)


def panorama_colour(image, cam, points):
    """The panorama's colour (bilinear, the columns wrapping around) where each of ``points`` (..., 3) projects."""
    u, v = (np.asarray(x, np.float64) for x in project(cam, np.asarray(points, np.float32)))
    left, top = np.floor(u).astype(int), np.floor(v).astype(int)
    a, b = (u - left)[..., None], (v - top)[..., None]

    def pixel(row, column):
        return image[row, column % image.shape[1]].astype(float)

    upper = (1 - a) * pixel(top, left) + a * pixel(top, left + 1)
    lower = (1 - a) * pixel(top + 1, left) + a * pixel(top + 1, left + 1)
    return (1 - b) * upper + b * lower


def texel_at(texture, uv):
    """The texture's colour at texture coordinates ``uv`` (v up), nearest texel."""
    size = texture.shape[0]
    return texture[int((1 - uv[1]) * size), int(uv[0] * size)].astype(float)


def wall_centres(layout):
    """Each valid wall's centre, metres, camera frame."""
    mask = np.asarray(layout.mask)
    ceiling, floor = np.asarray(layout.ceiling_corners)[mask], np.asarray(layout.floor_corners)[mask]
    return [
        (ceiling[k] + floor[k] + ceiling[(k + 1) % len(floor)] + floor[(k + 1) % len(floor)]) / 4
        for k in range(len(floor))
    ]


# --- the texture ----------------------------------------------------------------------------------------


def test_each_wall_carries_the_panorama_at_its_own_direction():
    layout = make_layout(RECTANGLE)
    image = direction_panorama()
    room = textured_room(layout, image, CAM, texture_size=256)
    assert [surface.name for surface in room.surfaces] == ["wall 0", "wall 1", "wall 2", "wall 3", "floor", "ceiling"]
    for surface, centre in zip(room.surfaces, wall_centres(layout), strict=False):
        # a wall's vertices are the corners, its centre the mean of their texture coordinates
        np.testing.assert_allclose(surface.vertices.mean(axis=0), centre, atol=1e-6)
        difference = np.abs(texel_at(room.texture, surface.uv.mean(axis=0)) - panorama_colour(image, CAM, centre))
        assert difference.max() <= 3.0, (surface.name, difference)
    floor_centre = np.array([0.5, 0.3, -1.5])
    floor = room.surfaces[-2]
    weights = np.linalg.lstsq(np.c_[floor.vertices[:, :2], np.ones(len(floor.vertices))], floor.uv, rcond=None)[0]
    uv = np.r_[floor_centre[:2], 1.0] @ weights  # texture coordinates are affine in the plan
    # the floor is seen at a grazing angle: one texel of it spans several of the panorama's levels, and the float
    # rounding of the CPU's vector units moves the sampled point by up to a texel
    assert np.abs(texel_at(room.texture, uv) - panorama_colour(image, CAM, floor_centre)).max() <= 4.0


def test_what_no_ray_sees_is_marked_not_smeared():
    # U_SHAPE's first wall, at the back of the left arm, hides behind the arm's inner wall from the camera
    layout = make_layout(U_SHAPE, inserted=(5,))
    room = textured_room(layout, direction_panorama(), CAM, texture_size=512)

    def unseen_at(surface, uv):
        size = room.texture.shape[0]
        row, column = int((1 - uv[1]) * size), int(uv[0] * size)
        if room.unseen[row, column]:
            assert tuple(room.texture[row, column]) == UNSEEN_COLOUR
        return bool(room.unseen[row, column])

    centres = {surface.name: surface.uv.mean(axis=0) for surface in room.surfaces[:8]}
    assert unseen_at("wall 0", centres["wall 0"])  # hidden by wall 1
    assert not unseen_at("wall 2", centres["wall 2"]) and not unseen_at("wall 6", centres["wall 6"])
    assert unseen_at("wall 5", centres["wall 5"])  # inserted: the panorama shows what stands in front of it
    wall = room.surfaces[5]
    corners = [wall.uv.min(axis=0) + 0.1 * np.ptp(wall.uv, axis=0), wall.uv.max(axis=0) - 0.1 * np.ptp(wall.uv, axis=0)]
    assert all(unseen_at("wall 5", uv) for uv in corners)
    # the floor right below the camera lies inside the circle of optical centres: no ray reaches it
    floor = room.surfaces[-2]
    weights = np.linalg.lstsq(np.c_[floor.vertices[:, :2], np.ones(len(floor.vertices))], floor.uv, rcond=None)[0]
    assert unseen_at("floor", np.array([0.1, -0.1, 1.0]) @ weights)
    assert not unseen_at("floor", np.array([0.0, -1.0, 1.0]) @ weights)
    assert 0.02 < room.unseen.mean() < 0.6


def test_what_the_photograph_does_not_hold_is_unseen():
    # a photo sphere padded to the full sphere: rows above 45 degrees were never photographed
    layout = make_layout(RECTANGLE)
    photographed = np.zeros((HEIGHT, WIDTH), bool)
    photographed[HEIGHT // 4 :] = True
    whole = textured_room(layout, direction_panorama(), CAM, texture_size=256)
    padded = textured_room(layout, direction_panorama(), CAM, texture_size=256, photographed=photographed)
    ceiling = padded.surfaces[-1]
    weights = np.linalg.lstsq(np.c_[ceiling.vertices[:, :2], np.ones(len(ceiling.vertices))], ceiling.uv, rcond=None)
    uv = np.r_[0.5, 0.3, 1.0] @ weights[0]  # the ceiling above the camera's side: elevation over 45 degrees
    size = padded.texture.shape[0]
    row, column = int((1 - uv[1]) * size), int(uv[0] * size)
    assert padded.unseen[row, column] and not whole.unseen[row, column]
    assert tuple(padded.texture[row, column]) == UNSEEN_COLOUR
    # the walls' lower parts and the floor stay as they were; only texels the padding takes become unseen
    assert not (whole.unseen & ~padded.unseen).any()
    changed = padded.unseen & ~whole.unseen
    assert changed.any() and np.array_equal(padded.texture[~padded.unseen], whole.texture[~padded.unseen])
    everywhere = textured_room(layout, direction_panorama(), CAM, 256, np.ones((HEIGHT, WIDTH), bool))
    assert np.array_equal(everywhere.texture, whole.texture) and np.array_equal(everywhere.unseen, whole.unseen)


def test_texture_size_is_a_setting():
    layout = make_layout(L_SHAPE)
    for size in (64, 300):
        room = textured_room(layout, direction_panorama(), CAM, texture_size=size)
        assert room.texture.shape == (size, size, 3) and room.unseen.shape == (size, size)
        for surface in room.surfaces:
            assert np.all((surface.uv >= 0) & (surface.uv <= 1))
    with pytest.raises(ValueError, match="at least 64"):
        textured_room(layout, direction_panorama(), CAM, texture_size=32)


# --- the glTF ---------------------------------------------------------------------------------------------


def test_the_textured_gltf_loads_in_trimesh(tmp_path):
    layout = make_layout(L_SHAPE, inserted=(2,))
    image = direction_panorama()
    room = textured_room(layout, image, CAM, texture_size=256)
    _, _, glb = write_mesh(tmp_path / "room", layout, room)
    scene = trimesh.load(glb)
    assert sorted(scene.geometry) == sorted(surface.name for surface in room.surfaces)
    stored = None
    for surface, centre in zip(room.surfaces, [*wall_centres(layout), None, None], strict=True):
        mesh = scene.geometry[surface.name]
        np.testing.assert_allclose(mesh.vertices, z_up_to_y_up(surface.vertices), atol=1e-6)
        np.testing.assert_array_equal(mesh.faces, surface.faces)
        np.testing.assert_allclose(mesh.visual.uv, surface.uv, atol=1e-6)
        texture = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
        assert texture.shape == (256, 256, 3) and mesh.visual.material.doubleSided
        if centre is not None and surface.name != "wall 2":
            colour = texel_at(texture, mesh.visual.uv.mean(axis=0))
            assert np.abs(colour - panorama_colour(image, CAM, centre)).max() <= 4.0, surface.name
        stored = texture
    # the texture is stored as the JPEG the viewer embeds
    assert np.array_equal(stored, np.asarray(PIL.Image.open(io.BytesIO(texture_jpeg(room.texture)))))
    assert texture_jpeg(room.texture) in glb.read_bytes()


# --- the viewer's page ------------------------------------------------------------------------------------


def page_scene(page: str) -> dict:
    return json.loads(re.search(r'<script type="application/json" id="scene">(.*?)</script>', page, re.S).group(1))


def test_the_viewer_page_is_self_contained():
    layout = make_layout(L_SHAPE, inserted=(2,))
    room = textured_room(layout, direction_panorama(), CAM, texture_size=128)
    record = layout_record(layout, CAM, name="room", world="auto")
    page = viewer_html(room, record)
    # nothing loads from elsewhere: no script or style files, every module a data: URL
    assert not re.search(r'<(script|link|img|iframe)[^>]*\b(src|href)="(?!data:)', page)
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', page, re.S).group(1))["imports"]
    assert sorted(imports) == ["three", "three/addons/controls/OrbitControls.js"]
    assert all(url.startswith("data:text/javascript;base64,") for url in imports.values())
    assert page.count("</script>") == 3  # the scene, the import map and the viewer: nothing closes them early
    scene = page_scene(page)
    assert scene == json.loads(json.dumps(viewer_scene(room, record)))
    assert scene["room_height"] == 2.5 and scene["floor_area"] == 21.0 and scene["status"] == "OK"
    assert [surface["inserted"] for surface in scene["surfaces"]] == [False, False, True] + [False] * 5
    np.testing.assert_allclose(scene["corners"]["floor"], z_up_to_y_up(np.asarray(record["floor_corners"])))
    assert scene["texture"].startswith("data:image/jpeg;base64,")


def test_the_viewer_draws_each_corners_95_percent_ellipse():
    layout = make_layout(RECTANGLE)  # corner covariance diag(4e-4, 1e-4) m^2
    record = layout_record(layout, CAM, name="room", world="auto")
    room = textured_room(layout, direction_panorama(), CAM, texture_size=64)
    ellipses = viewer_scene(room, record)["ellipses"]
    assert len(ellipses) == 4
    for outline, corner in zip(ellipses, record["floor_corners"], strict=True):
        plan = np.asarray(outline)[:, [0, 2]] * [1, -1] - corner[:2]  # back from y up
        # on the ellipse x^2 / (k 4e-4) + y^2 / (k 1e-4) = 1 with k the chi-square 95% quantile
        np.testing.assert_allclose(plan[:, 0] ** 2 / (CHI2_95 * 4e-4) + plan[:, 1] ** 2 / (CHI2_95 * 1e-4), 1.0)
        np.testing.assert_allclose(np.asarray(outline)[:, 1], corner[2] + 0.01)
    record["corner_covariance"][1] = None  # not determined: no ellipse
    assert len(viewer_scene(room, record)["ellipses"]) == 3


@pytest.mark.parametrize("status", [LayoutStatus.UNCERTAIN_SCALE, LayoutStatus.LOW_CONFIDENCE])
def test_a_flagged_layout_says_so_in_its_viewer(status):
    layout = make_layout(RECTANGLE, status=int(status))
    record = layout_record(layout, CAM, name="room", world="auto")
    scene = page_scene(viewer_html(textured_room(layout, direction_panorama(), CAM, 64), record))
    assert scene["ok"] is False and scene["status"] == f"{status.name} (flagged)"
    assert scene["flag"] == status.name.replace("_", " ") and scene["reason"] == status.reason


# --- the files of a result --------------------------------------------------------------------------------


def write_result(folder, name, layout, image=None, rc=RC, texture_size=128):
    """Every output of one image whose reconstruction gave ``layout``; returns its record."""
    image = direction_panorama() if image is None else image
    height, width = image.shape[:2]
    rows = np.full(width, 0.25 * height), np.full(width, 0.75 * height), np.zeros(width), 0, None
    reconstructed = ReconstructedImage(name, image, (layout, *rows), rc)
    return write_outputs(str(folder), reconstructed, "auto", texture_size=texture_size)


def test_the_glb_and_the_viewer_are_outputs_like_the_others(tmp_path):
    write_result(tmp_path, "room", make_layout(L_SHAPE))
    assert sorted(path.name for path in tmp_path.iterdir()) == sorted(
        ["room.json", "room.obj", "room.ply", "room.glb", "room.html", "room_overlay.png", "room_plan.png"]
    )
    assert page_scene((tmp_path / "room.html").read_text())["name"] == "room"
    write_result(tmp_path, "room", failed_layout())  # a rerun without a layout removes them
    assert sorted(path.name for path in tmp_path.iterdir()) == ["room.json", "room_overlay.png", "room_plan.png"]


def test_the_texture_size_is_an_option(tmp_path, monkeypatch, capsys):
    from test_cli_files import FakeReconstruction, panoramas, reconstruct_cli

    import ncjax.reconstruction

    monkeypatch.setattr(ncjax.reconstruction, "reconstruct_batch", FakeReconstruction(make_layout(L_SHAPE)))
    images = panoramas(tmp_path / "in", "room")
    for size, texels in ((None, 128), ("96", 96)):  # the stand-in panoramas are 128 pixels wide
        options = [] if size is None else ["--texture-size", size]
        assert reconstruct_cli(images, tmp_path / "out", *options) == 0
        mesh = trimesh.load(tmp_path / "out" / "room.glb").geometry["floor"]
        assert mesh.visual.material.baseColorTexture.size == (texels, texels)
    with pytest.raises(SystemExit):
        cli.main(["demo", "--texture-size", "32"])
    assert "the texture size must be a whole number of texels >= 64, got '32'" in capsys.readouterr().err


@pytest.fixture
def results(tmp_path):
    """A folder of three results: one ok, one flagged, one failed."""
    write_result(tmp_path, "ok_room", make_layout(L_SHAPE))
    write_result(tmp_path, "flagged_room", make_layout(RECTANGLE, status=int(LayoutStatus.UNCERTAIN_SCALE)))
    write_result(tmp_path, "failed_room", failed_layout())
    (tmp_path / "summary.csv").write_text("not a record\n")
    (tmp_path / "other.json").write_text("[1, 2]")
    return tmp_path


def test_the_index_lists_every_result(results):
    page = index_html(results)
    rows = re.findall(r"<tr><td>.*?</tr>", page, re.S)
    assert len(rows) == 3 and "3 results, 1 ok" in page
    failed, flagged, ok = rows  # by name
    assert '<img src="ok_room_overlay.png"' in ok and '<a href="ok_room.html"><img' in ok
    assert ">ok<" in ok and "2.500 m" in ok and "21.00 m²" in ok and '<a href="ok_room.glb">glb</a>' in ok
    assert "flagged: uncertain scale" in flagged and "12.00 m²" in flagged and "flagged_room.html" in flagged
    assert (
        "failed: DEGENERATE_LAYOUT" in failed
        and ".html" not in failed
        and '<img src="failed_room_overlay.png"' in failed
    )


@pytest.mark.parametrize("browser", [True, False])
def test_view_serves_the_folder_and_opens_the_browser(results, monkeypatch, capsys, browser):
    servers, opened = [], []
    ready = threading.Event()
    results_server = view.results_server

    def serve(folder, port=0):
        servers.append(results_server(folder, port))
        ready.set()
        return servers[-1]

    monkeypatch.setattr(view, "results_server", serve)
    monkeypatch.setattr(view.webbrowser, "open", lambda url: opened.append(url) or True)
    codes = []
    options = [] if browser else ["--no-browser"]
    thread = threading.Thread(target=lambda: codes.append(cli.main(["view", str(results), *options])))
    thread.start()
    try:
        assert ready.wait(30)
        url = f"http://127.0.0.1:{servers[0].server_address[1]}/"
        index = urllib.request.urlopen(url, timeout=30).read().decode()
        assert len(re.findall(r"<tr><td>", index)) == 3
        viewer = urllib.request.urlopen(url + "ok_room.html", timeout=30).read().decode()
        assert page_scene(viewer)["name"] == "ok_room"
        assert urllib.request.urlopen(url + "ok_room_overlay.png", timeout=30).read()[:4] == b"\x89PNG"
    finally:
        servers[0].shutdown()
        thread.join(30)
    assert codes == [0] and opened == ([url] if browser else [])
    assert f"at {url}" in capsys.readouterr().out


def test_view_needs_a_folder(tmp_path, capsys):
    assert cli.main(["view", str(tmp_path / "missing"), "--no-browser"]) == 2
    assert "no such folder" in capsys.readouterr().err
