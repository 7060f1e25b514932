"""The 3D viewer in a real browser: headless Chromium with software WebGL opens the page from the file
system (no network), which must show the textured room without a console error, look like the panorama from
the camera, measure the walls' lengths and react to its toggles. Without a Chromium-based browser these
tests are skipped (``apt-get install chromium``), never passed. The demo's own viewer and textured glTF are
checked last (slow: the demo reconstructs its panorama)."""

from __future__ import annotations

import io
import json
import math
import threading

import numpy as np
import PIL.Image
import pytest
import shapely
import trimesh
from _browser import Browser
from test_export import RECTANGLE, failed_layout, make_layout
from test_viewer import panorama_colour, texel_at, write_result

from ncjax import cli
from ncjax.cli.demo import DEMO_DIR
from ncjax.cli.view import results_server
from ncjax.geometry.camera import NonCentralPanorama, project
from ncjax.io.images import read_panorama
from ncjax.pipeline.types import LayoutStatus

TRUTH = json.loads((DEMO_DIR / "ground_truth.json").read_text())
WIDTH, HEIGHT = 1280, 800
EDGE_MARGIN = 0.05  # metres: pixels this close to a wall's edge (a seam of the texture) are not compared
UNSEEN = np.array([255, 0, 255])


@pytest.fixture(scope="module")
def browser():
    executable = Browser.find()
    if executable is None:
        pytest.skip("no Chromium-based browser on this machine (apt-get install chromium)")
    with Browser(executable, WIDTH, HEIGHT) as opened:
        yield opened


def true_layout(status=LayoutStatus.OK):
    """The demo room's true layout (its ground truth), the panorama's own room."""
    floor, ceiling = np.array(TRUTH["floor_corners"]), np.array(TRUTH["ceiling_corners"])
    return make_layout(floor[:, :2], ceiling[0, 2], floor[0, 2], capacity=16, status=int(status))


@pytest.fixture(scope="module")
def demo_room(tmp_path_factory):
    """The demo panorama and its true layout written as a result: (folder, record, panorama, camera)."""
    folder = tmp_path_factory.mktemp("room")
    image = read_panorama(DEMO_DIR / TRUTH["image"])
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc=TRUTH["rc"])
    record = write_result(folder, "room", true_layout(), image=image, rc=TRUTH["rc"], texture_size=None)
    return folder, record, image, cam


def open_viewer(browser, path, url=None):
    """Open the viewer's page ``path`` (or ``url``) and wait until it has drawn the textured room."""
    browser.errors.clear()
    browser.open(path.as_uri() if url is None else url)
    browser.wait_for(lambda: browser.evaluate("window.ncjaxViewer !== undefined && window.ncjaxViewer.ready"))


def screenshot(browser) -> np.ndarray:
    return np.asarray(PIL.Image.open(io.BytesIO(browser.screenshot())).convert("RGB"))


# --- the page ---------------------------------------------------------------------------------------------


def test_the_viewer_opens_offline_and_shows_the_textured_room(browser, demo_room):
    folder, record, _, _ = demo_room
    open_viewer(browser, folder / "room.html")
    shot = screenshot(browser)
    assert browser.errors == []
    background = np.all(shot == [32, 35, 42], axis=-1)
    assert 0.2 < 1 - background.mean() < 0.9  # the room fills part of the window
    room = shot[~background]
    assert len(np.unique(room // 8, axis=0)) > 300  # textured: many colours, not flat faces
    assert browser.evaluate("document.getElementById('status').textContent") == "OK"
    assert browser.evaluate("document.getElementById('height').textContent").startswith(f"{record['room_height']:.3f}")
    assert browser.evaluate("document.getElementById('area').textContent") == f"{record['floor_area']:.2f} m²"
    assert not browser.evaluate("document.getElementById('flag').offsetParent")  # ok: no flag shown


def look_from_camera(browser, azimuth_degrees: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The view from the camera towards ``azimuth_degrees`` (the panel and the edges hidden), the viewer's
    camera-to-world matrix and its inverse projection matrix (y up)."""
    angle = math.radians(azimuth_degrees)
    matrices = browser.evaluate(
        f"""(() => {{
            const v = window.ncjaxViewer;
            document.getElementById("panel").style.display = "none";
            if (document.getElementById("show-edges").checked) document.getElementById("show-edges").click();
            v.eyeAtCamera();
            v.controls.target.set({0.001 * math.cos(angle)}, 0, {-0.001 * math.sin(angle)});
            v.controls.update();
            v.render();
            return [Array.from(v.camera.matrixWorld.elements), Array.from(v.camera.projectionMatrixInverse.elements)];
        }})()"""
    )
    world, inverse_projection = (np.array(m).reshape(4, 4).T for m in matrices)  # three.js stores columns
    return screenshot(browser), world, inverse_projection


def first_hits(origin, directions, plan, top, bottom):
    """Where rays from ``origin`` inside the room first meet its walls, floor or ceiling, and whether that is
    at least EDGE_MARGIN from every edge of the room."""
    following = np.roll(plan, -1, axis=0)
    start, wall = plan[None], (following - plan)[None]
    offset, ray = start - origin[None, None, :2], directions[:, None, :2]
    denominator = ray[..., 0] * wall[..., 1] - ray[..., 1] * wall[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (offset[..., 0] * wall[..., 1] - offset[..., 1] * wall[..., 0]) / denominator
        along = (offset[..., 0] * ray[..., 1] - offset[..., 1] * ray[..., 0]) / denominator
    t = np.where((t > 0) & (along >= 0) & (along <= 1), t, np.inf)
    nearest = np.argmin(t, axis=1)
    t_wall = t[np.arange(len(t)), nearest]
    z = origin[2] + t_wall * directions[:, 2]
    on_wall = (z > bottom) & (z < top)
    t_plane = np.where(directions[:, 2] > 0, top - origin[2], bottom - origin[2]) / directions[:, 2]
    hits = origin + np.where(on_wall, t_wall, t_plane)[:, None] * directions
    lengths = np.linalg.norm(wall[0], axis=1)[nearest]
    along_wall = along[np.arange(len(t)), nearest] * lengths
    wall_margin = np.minimum.reduce([z - bottom, top - z, along_wall, lengths - along_wall])
    plane_margin = shapely.distance(shapely.Polygon(plan).exterior, shapely.points(hits[:, :2]))
    return hits, np.where(on_wall, wall_margin, plane_margin) > EDGE_MARGIN


@pytest.mark.slow
def test_the_walls_look_like_the_panorama_from_the_camera(browser, demo_room):
    """Each pixel of the view from the camera against the panorama's colour where the room point it shows
    projects: the texture puts every point's own colour on it."""
    folder, record, image, cam = demo_room
    open_viewer(browser, folder / "room.html")
    floor = np.array(record["floor_corners"])
    top, bottom = record["ceiling_height"], record["floor_height"]
    step = 8
    rows, columns = np.mgrid[step // 2 : HEIGHT : step, step // 2 : WIDTH : step]
    differences = []
    for azimuth in (0, 90, 180, 270):
        shot, world, inverse_projection = look_from_camera(browser, azimuth)
        ndc = np.stack([2 * (columns + 0.5) / WIDTH - 1, 1 - 2 * (rows + 0.5) / HEIGHT], -1).reshape(-1, 2)
        near = np.c_[ndc, np.full(len(ndc), 0.5), np.ones(len(ndc))] @ inverse_projection.T
        points = (near / near[:, 3:]) @ world.T
        origin_y_up, directions_y_up = world[:3, 3], points[:, :3] - world[:3, 3]
        to_z_up = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])  # y up (x, y, z) -> (x, -z, y)
        hits, clear = first_hits(to_z_up @ origin_y_up, directions_y_up @ to_z_up.T, floor[:, :2], top, bottom)
        rendered = shot[rows.ravel(), columns.ravel()].astype(float)
        seen = np.abs(rendered - UNSEEN).sum(axis=1) > 150
        u, _ = project(cam, hits.astype(np.float32))
        keep = clear & seen & np.isfinite(np.asarray(u))
        expected = panorama_colour(image, cam, hits[keep])
        differences.append(np.abs(rendered[keep] - expected).mean(axis=1))
        assert keep.mean() > 0.5, azimuth
    difference = np.concatenate(differences)
    print(
        f"view from the camera against the panorama: {len(difference)} pixels, mean |difference| "
        f"{difference.mean():.2f}, median {np.median(difference):.2f}, 90% {np.percentile(difference, 90):.2f} (0-255)"
    )
    assert np.median(difference) < 6 and np.percentile(difference, 90) < 20
    assert browser.errors == []


def measured(browser, first, second, snap=True) -> float:
    """The distance tool's reading after clicking two points of the room (in the camera frame, z up)."""
    for point in (first, second):
        x, y = browser.evaluate(f"window.ncjaxViewer.screenOf([{point[0]}, {point[2]}, {-point[1]}])")
        browser.click(x, y, modifiers=0 if snap else 1)
    text = browser.evaluate("document.getElementById('distance').textContent")
    distance = browser.evaluate("window.ncjaxViewer.distance")
    assert text == f"distance {distance:.3f} m"
    return distance


def test_the_distance_tool_reads_each_walls_length(browser, demo_room):
    folder, record, _, _ = demo_room
    open_viewer(browser, folder / "room.html")
    browser.evaluate("window.ncjaxViewer.overview()")
    floor = record["floor_corners"]
    errors = []
    for k, wall in enumerate(record["walls"]):
        errors.append(abs(measured(browser, floor[k], floor[(k + 1) % len(floor)]) - wall["length"]))
    print(f"distance tool, corner to corner: largest error {max(errors) * 1000:.3f} mm over {len(errors)} walls")
    assert max(errors) < 0.01
    # a click away from the corners measures the point under the cursor: across the room's floor
    centre = np.mean(floor, axis=0)
    first, second = centre + [-1.0, -0.5, 0.0], centre + [1.0, 0.5, 0.0]
    raw = abs(measured(browser, first, second, snap=False) - np.linalg.norm(second - first))
    print(f"distance tool, two floor points under the cursor: error {raw * 1000:.1f} mm")
    assert raw < 0.02
    assert browser.errors == []


def test_the_toggles_show_and_hide_edges_ellipses_and_inserted_walls(browser, tmp_path):
    record = write_result(tmp_path, "room", make_layout(RECTANGLE, inserted=(1,)))
    open_viewer(browser, tmp_path / "room.html")
    browser.evaluate("window.ncjaxViewer.overview()")
    before = screenshot(browser)
    changed = {}
    for toggle in ("show-edges", "show-ellipses", "show-inserted"):
        browser.evaluate(f"document.getElementById('{toggle}').click()")
        after = screenshot(browser)
        changed[toggle] = int(np.any(after != before, axis=-1).sum())
        before = after
    print(f"pixels changed by each toggle: {changed}")
    assert all(count > 50 for count in changed.values()) and record["walls"][1]["inserted"]
    assert browser.errors == []


def test_a_flagged_layout_says_so_in_the_viewer(browser, tmp_path):
    write_result(tmp_path, "room", make_layout(RECTANGLE, status=int(LayoutStatus.LOW_CONFIDENCE)))
    open_viewer(browser, tmp_path / "room.html")
    shown, text = browser.evaluate("(f => [f.offsetParent !== null, f.textContent])(document.getElementById('flag'))")
    assert shown and text.startswith("LOW CONFIDENCE: ")
    assert browser.evaluate("document.getElementById('status').textContent") == "LOW_CONFIDENCE (flagged)"
    assert browser.errors == []


def test_the_index_of_a_served_folder_shows_every_result(browser, demo_room):
    folder, _, _, _ = demo_room
    write_result(folder, "flagged", make_layout(RECTANGLE, status=int(LayoutStatus.UNCERTAIN_SCALE)))
    write_result(folder, "failed", failed_layout())
    server = results_server(str(folder))
    thread = threading.Thread(target=server.serve_forever)
    thread.start()
    try:
        url = f"http://127.0.0.1:{server.server_address[1]}/"
        browser.errors.clear()
        browser.open(url)
        browser.wait_for(lambda: browser.evaluate("Array.from(document.images).every(image => image.complete)"))
        assert browser.evaluate("document.querySelectorAll('tr').length") == 4  # the header and 3 results
        widths = browser.evaluate("Array.from(document.images).map(image => image.naturalWidth)")
        assert len(widths) == 3 and min(widths) > 0  # every thumbnail loaded
        open_viewer(browser, None, url=url + "room.html")
    finally:
        server.shutdown()
        thread.join()
    assert browser.errors == []


# --- the demo ---------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    assert cli.main(["demo", "--out", str(out)]) == 0
    name = TRUTH["image"].removesuffix(".png")
    return out, name, json.loads((out / f"{name}.json").read_text())


@pytest.mark.slow
def test_the_demo_writes_a_textured_gltf_that_matches_its_panorama(demo):
    out, name, record = demo
    glb = out / f"{name}.glb"
    assert glb.stat().st_size <= 3e6
    scene = trimesh.load(glb)
    image = read_panorama(DEMO_DIR / TRUTH["image"])
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc=record["rc"])
    ceiling, floor = np.array(record["ceiling_corners"]), np.array(record["floor_corners"])
    following = np.roll(np.arange(len(floor)), -1)
    differences = []
    for k, centre in enumerate((ceiling + floor + ceiling[following] + floor[following]) / 4):
        if record["walls"][k]["inserted"]:
            continue
        mesh = scene.geometry[f"wall {k}"]
        texture = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
        differences.append(np.abs(texel_at(texture, mesh.visual.uv.mean(axis=0)) - panorama_colour(image, cam, centre)))
    differences = np.array(differences)
    print(
        f"demo glTF: texture at {len(differences)} wall centres against the panorama, mean |difference| "
        f"{differences.mean():.2f}, largest {differences.max():.1f} (0-255)"
    )
    assert differences.mean() < 6


@pytest.mark.slow
def test_the_demo_viewer_measures_its_walls(browser, demo):
    out, name, record = demo
    open_viewer(browser, out / f"{name}.html")
    browser.evaluate("window.ncjaxViewer.overview()")
    floor = record["floor_corners"]
    errors = [
        abs(measured(browser, floor[k], floor[(k + 1) % len(floor)]) - wall["length"])
        for k, wall in enumerate(record["walls"])
    ]
    assert max(errors) < 0.01 and browser.errors == []
