// The textured room of one ncjax result: orbit, the eye at the camera, toggles and a distance tool.
// Every coordinate of the scene is in metres in the viewer's frame (y up: ncjax's (x, y, z) is (x, z, -y)).
import * as THREE from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

const room = JSON.parse(document.getElementById("scene").textContent);
const SNAP_PIXELS = 12; // a click this close to a corner on the screen measures from the corner
const CLICK_PIXELS = 4; // a press and release farther apart than this is a drag, not a click

const canvas = document.getElementById("view");
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(window.devicePixelRatio);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x20232a);
const camera = new THREE.PerspectiveCamera(60, 1, 0.01, 500);
const controls = new OrbitControls(camera, canvas);
// what a script driving the page (a test) reads and calls
const viewer = { ready: false, camera, controls, distance: null };
window.ncjaxViewer = viewer;

// --- the room ---------------------------------------------------------------------------------------------
const texture = new THREE.TextureLoader().load(room.texture, () => {
  viewer.ready = true;
  render();
});
texture.colorSpace = THREE.SRGBColorSpace;
texture.anisotropy = renderer.capabilities.getMaxAnisotropy();
// The faces' normals point out of the room: drawing their back sides shows the room from inside, and from
// outside the walls nearest the eye step aside.
const material = new THREE.MeshBasicMaterial({ map: texture, side: THREE.BackSide });
const insertedWalls = new THREE.Group();
const surfaces = [];
for (const surface of room.surfaces) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.Float32BufferAttribute(surface.positions, 3));
  geometry.setAttribute("uv", new THREE.Float32BufferAttribute(surface.uv, 2));
  geometry.setIndex(surface.indices);
  const mesh = new THREE.Mesh(geometry, material);
  mesh.name = surface.name;
  surfaces.push(mesh);
  (surface.inserted ? insertedWalls : scene).add(mesh);
}
scene.add(insertedWalls);

function lineSegments(points, colour) {
  const geometry = new THREE.BufferGeometry().setFromPoints(points.map((p) => new THREE.Vector3(...p)));
  return new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: colour }));
}

const floorCorners = room.corners.floor;
const ceilingCorners = room.corners.ceiling;
const edgePoints = [];
floorCorners.forEach((corner, k) => {
  const next = (k + 1) % floorCorners.length;
  edgePoints.push(corner, floorCorners[next], ceilingCorners[k], ceilingCorners[next], corner, ceilingCorners[k]);
});
const edges = lineSegments(edgePoints, 0xffd400);
scene.add(edges);

const ellipses = new THREE.Group();
for (const outline of room.ellipses) {
  const points = outline.flatMap((p, i) => [p, outline[(i + 1) % outline.length]]);
  ellipses.add(lineSegments(points, 0xff3b30));
}
ellipses.visible = false;
scene.add(ellipses);

// --- the panel --------------------------------------------------------------------------------------------
const metres = (x, digits = 2) => (x === null ? "unknown" : `${x.toFixed(digits)} m`);
document.getElementById("name").textContent = room.name;
document.getElementById("status").textContent = room.status;
const sigma = room.room_height_sigma === null ? "" : ` ± ${room.room_height_sigma.toFixed(3)}`;
document.getElementById("height").textContent = `${room.room_height.toFixed(3)}${sigma} m`;
document.getElementById("area").textContent = `${room.floor_area.toFixed(2)} m²`;
document.getElementById("perimeter").textContent = metres(room.perimeter);
const inserted = room.walls.filter((wall) => wall.inserted).length;
document.getElementById("walls").textContent = `${room.walls.length}, ${inserted} inserted`;
if (!room.ok) {
  const flag = document.getElementById("flag");
  flag.style.display = "block";
  flag.textContent = `${room.flag}: ${room.reason}`;
}

function toggle(id, object) {
  const box = document.getElementById(id);
  const apply = () => {
    object.visible = box.checked;
    render();
  };
  box.addEventListener("change", apply);
  object.visible = box.checked;
}
toggle("show-edges", edges);
toggle("show-ellipses", ellipses);
toggle("show-inserted", insertedWalls);

// --- the eye ----------------------------------------------------------------------------------------------
const box = new THREE.Box3().setFromPoints([...floorCorners, ...ceilingCorners].map((p) => new THREE.Vector3(...p)));
const centre = box.getCenter(new THREE.Vector3());
const size = box.getSize(new THREE.Vector3()).length();

function overview() {
  controls.enableZoom = controls.enablePan = true;
  controls.rotateSpeed = 1.0;
  camera.fov = 60;
  camera.position.set(centre.x + 0.25 * size, centre.y + 0.7 * size, centre.z + 0.6 * size);
  controls.target.copy(centre);
  update();
}

function eyeAtCamera() {
  // The camera's centre (the centre of its circle of optical centres), looking along the panorama's middle
  // column (azimuth 0, +x); turning around a target a millimetre ahead is looking around.
  controls.enableZoom = controls.enablePan = false;
  controls.rotateSpeed = -0.4;
  camera.fov = 75;
  camera.position.set(0, 0, 0);
  controls.target.set(0.001, 0, 0);
  update();
}

function update() {
  camera.updateProjectionMatrix();
  controls.update();
  render();
}

canvas.addEventListener("wheel", (event) => {
  if (controls.enableZoom) return;
  camera.fov = THREE.MathUtils.clamp(camera.fov + 0.05 * event.deltaY, 20, 110);
  update();
});
document.getElementById("eye").addEventListener("click", eyeAtCamera);
document.getElementById("overview").addEventListener("click", overview);

// --- the distance tool ------------------------------------------------------------------------------------
const raycaster = new THREE.Raycaster();
const ends = [];
const marks = new THREE.Group();
scene.add(marks);

function screenOf(point) {
  const projected = new THREE.Vector3(...point).project(camera);
  const rect = canvas.getBoundingClientRect();
  return [rect.left + ((projected.x + 1) / 2) * rect.width, rect.top + ((1 - projected.y) / 2) * rect.height];
}
viewer.screenOf = screenOf;

function pick(x, y, snap) {
  const rect = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((x - rect.left) / rect.width) * 2 - 1, -((y - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  const shown = surfaces.filter((mesh) => mesh.visible && mesh.parent.visible);
  const hit = raycaster.intersectObjects(shown, false)[0];
  if (snap) {
    // the nearest corner on the screen, unless a surface hides it
    let best = null;
    for (const corner of [...floorCorners, ...ceilingCorners]) {
      const [cx, cy] = screenOf(corner);
      const pixels = Math.hypot(cx - x, cy - y);
      const depth = camera.position.distanceTo(new THREE.Vector3(...corner));
      const hidden = hit !== undefined && hit.distance < depth - 0.05;
      if (pixels <= SNAP_PIXELS && !hidden && (best === null || pixels < best.pixels)) best = { corner, pixels };
    }
    if (best !== null) return new THREE.Vector3(...best.corner);
  }
  return hit === undefined ? null : hit.point;
}

function mark(point) {
  // a dot of the same size on the screen at any distance, drawn over the room
  const dot = new THREE.Points(
    new THREE.BufferGeometry().setFromPoints([point]),
    new THREE.PointsMaterial({ color: 0x00e5ff, size: 9, sizeAttenuation: false, depthTest: false }),
  );
  dot.renderOrder = 2;
  marks.add(dot);
}

function measure(point) {
  if (ends.length === 2) {
    ends.length = 0;
    marks.clear();
  }
  ends.push(point);
  mark(point);
  const readout = document.getElementById("distance");
  if (ends.length === 1) {
    viewer.distance = null;
    readout.textContent = "click a second point";
  } else {
    const line = lineSegments([ends[0].toArray(), ends[1].toArray()], 0x00e5ff);
    line.material.depthTest = false;
    line.renderOrder = 2;
    marks.add(line);
    viewer.distance = ends[0].distanceTo(ends[1]);
    readout.textContent = `distance ${viewer.distance.toFixed(3)} m`;
  }
  render();
}

let pressed = null;
canvas.addEventListener("pointerdown", (event) => {
  pressed = [event.clientX, event.clientY];
});
canvas.addEventListener("pointerup", (event) => {
  if (pressed === null || event.button !== 0) return;
  const moved = Math.hypot(event.clientX - pressed[0], event.clientY - pressed[1]);
  pressed = null;
  if (moved > CLICK_PIXELS) return;
  const point = pick(event.clientX, event.clientY, !event.altKey);
  if (point !== null) measure(point);
});

// --- drawing ----------------------------------------------------------------------------------------------
function render() {
  renderer.render(scene, camera);
}

function resize() {
  renderer.setSize(window.innerWidth, window.innerHeight, false);
  camera.aspect = window.innerWidth / window.innerHeight;
  update();
}

controls.addEventListener("change", render);
window.addEventListener("resize", resize);
viewer.overview = overview;
viewer.eyeAtCamera = eyeAtCamera;
viewer.render = render;
overview();
resize();
