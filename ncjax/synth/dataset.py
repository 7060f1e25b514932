"""Writer and reader of the Non-Central Indoor Dataset layout (docs/design.md section 6).

A dataset directory holds, per sample ``<name>``:

- ``img/<name>.png``: the RGB panorama (8 bits);
- ``label_cor/<name>.txt``: the layout corners, one ``x y`` integer pixel pair
  per line, ceiling then floor of each corner, sorted by x (HorizonNet's format;
  an occlusion corner appears twice, near and far point);
- ``3D_gt/<name>.npy``: (2N, 3) float64, the N ceiling corners then the N floor
  corners of ``label_cor``, world frame (floor at z = 0), metres;
- ``cam_pose/<name>.npy``: (1, 3) float64, the camera (centre of the circle of
  optical centres) in the world frame; subtract it to get the camera frame.

The authors' release has only these. Ours adds, written last:

- ``depth/<name>.png``: 16-bit depth along each pixel's ray, millimetres;
- ``semantic/<name>.png``: 8-bit :class:`~ncjax.synth.Semantic` classes;
- ``json/<name>.json``: ``rc`` (metres; also in the name, ``..._R06101`` being
  0.6101 m, as the authors name their real images), heights, world type,
  per-column boundary rows, corner columns and 3D corners, the full room.

``split.json`` lists the names of the train/valid/test splits. Every sample is
its own random room, and its layout id (the sample index) decides its split, so
no layout appears in two splits. Files are written atomically (temporary file
and rename); the same seed and settings give identical bytes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
from collections.abc import Callable, Iterable, Iterator

import cv2
import jax
import jax.numpy as jnp
import numpy as np

from ..geometry.camera import NonCentralPanorama, project
from ..io.files import write_atomic
from ..io.images import rc_from_name
from .labels import RoomLabels, room_labels
from .render import Rendering, SynthConfig, synthesize_batch
from .rooms import Room, RoomStatus
from .scene import Scene

SCHEMA_VERSION = 1
FOLDERS = ("img", "label_cor", "3D_gt", "cam_pose", "depth", "semantic", "json")
SPLITS = {"train": 0.65, "valid": 0.15, "test": 0.20}  # about the paper's 1677 / 399 / 499


def sample_name(world: str, index: int, rc: float) -> str:
    """``<world>_<index>_R<rc in 1e-4 m>``, e.g. ``atlanta_000012_R06101``."""
    return f"{world}_{index:06d}_R{int(round(rc * 1e4)):05d}"


def split_of(layout_id: int, seed: int) -> str:
    """The split of a layout: a hash of (seed, layout id), so it does not depend
    on how many samples are written."""
    digest = hashlib.sha256(f"{seed}:{layout_id}".encode()).digest()
    fraction = int.from_bytes(digest[:8], "little") / 2**64
    edge = 0.0
    for split, share in SPLITS.items():
        edge += share
        if fraction < edge:
            return split
    return "test"


def _write_png(path: str, image: np.ndarray) -> None:
    ok, encoded = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise OSError(f"could not encode {path}")
    write_atomic(path, encoded.tobytes())


def _write_npy(path: str, array: np.ndarray) -> None:
    buffer = io.BytesIO()
    np.save(buffer, array)
    write_atomic(path, buffer.getvalue())


def label_cor_rows(labels: RoomLabels, cam: NonCentralPanorama) -> np.ndarray:
    """The ``label_cor`` integer pairs (2N, 2) of valid corners: x the corner
    column, y the rows of its ceiling and floor points (projected), rounded."""
    mask = np.asarray(labels.corner_mask)
    points = np.stack([np.asarray(labels.ceiling_corners)[mask], np.asarray(labels.floor_corners)[mask]], 1)
    _, rows = project(cam, points)
    columns = np.clip(np.round(np.asarray(labels.corner_u)[mask]), 0, cam.width - 1)
    rows = np.clip(np.round(np.asarray(rows)), 0, cam.height - 1)
    pairs = np.stack([np.repeat(columns, 2), rows.reshape(-1)], -1)
    return pairs.astype(np.int64)


def _floats(array, digits: int = 6) -> list:
    return np.round(np.asarray(array, np.float64), digits).tolist()


def sample_metadata(
    name: str, scene: Scene, labels: RoomLabels, cam: NonCentralPanorama, index: int, seed: int
) -> dict:
    """The ``json/<name>.json`` record of one sample (camera frame, metres, pixels)."""
    room = scene.room
    mask = np.asarray(labels.corner_mask)
    return {
        "schema_version": SCHEMA_VERSION,
        "name": name,
        "layout_id": index,
        "seed": seed,
        "split": split_of(index, seed),
        "rc": round(float(room.rc), 6),
        "width": cam.width,
        "height": cam.height,
        "world": "atlanta" if bool(room.is_atlanta) else "manhattan",
        "num_walls": int(room.num_walls),
        "ceiling_height": round(float(room.ceiling_height), 6),
        "floor_height": round(float(room.floor_height), 6),
        "camera_height": round(float(room.camera_position[2]), 6),
        "room_height": round(float(room.ceiling_height - room.floor_height), 6),
        "camera_position": _floats(room.camera_position),
        "room_corners": _floats(np.asarray(room.corners)[np.asarray(room.mask)]),
        "ceiling_v": _floats(labels.ceiling_v, 4),
        "floor_v": _floats(labels.floor_v, 4),
        "corner_u": _floats(np.asarray(labels.corner_u)[mask], 4),
        "corner_is_occlusion": np.asarray(labels.corner_is_occlusion)[mask].tolist(),
        "ceiling_corners": _floats(np.asarray(labels.ceiling_corners)[mask]),
        "floor_corners": _floats(np.asarray(labels.floor_corners)[mask]),
        "furniture_boxes": int(np.sum(np.asarray(scene.boxes.mask))),
        "depth_png_scale": 1000,
        "semantic_classes": ["ceiling", "floor", "wall", "object", "opening"],
    }


def write_sample(directory: str, name: str, rendering: Rendering, labels: RoomLabels, metadata: dict) -> None:
    """Write one sample's files (one instance, unbatched), each atomically; the json last."""
    room_camera = NonCentralPanorama(metadata["width"], metadata["height"], rc=metadata["rc"])
    camera_position = np.asarray(metadata["camera_position"], np.float64)
    rgb = rendering_rgb8(rendering)
    _write_png(os.path.join(directory, "img", f"{name}.png"), rgb[..., ::-1])
    depth = np.clip(np.round(np.asarray(rendering.depth, np.float64) * 1000), 0, 65535).astype(np.uint16)
    _write_png(os.path.join(directory, "depth", f"{name}.png"), depth)
    _write_png(os.path.join(directory, "semantic", f"{name}.png"), np.asarray(rendering.semantic).astype(np.uint8))
    rows = label_cor_rows(labels, room_camera)
    write_atomic(os.path.join(directory, "label_cor", f"{name}.txt"), "".join(f"{x} {y}\n" for x, y in rows).encode())
    corners = np.concatenate([np.asarray(metadata["ceiling_corners"]), np.asarray(metadata["floor_corners"])])
    _write_npy(os.path.join(directory, "3D_gt", f"{name}.npy"), (corners + camera_position).astype(np.float64))
    _write_npy(os.path.join(directory, "cam_pose", f"{name}.npy"), camera_position[None].astype(np.float64))
    write_atomic(
        os.path.join(directory, "json", f"{name}.json"),
        (json.dumps(metadata, sort_keys=True, indent=1) + "\n").encode(),
    )


def _check_output_directory(directory: str, overwrite: bool) -> None:
    if os.path.exists(directory) and not os.path.isdir(directory):
        raise ValueError(f"--out {directory!r} exists and is not a directory")
    if os.path.isdir(directory) and os.listdir(directory) and not overwrite:
        raise ValueError(f"--out {directory!r} is not empty; choose a new directory or pass --overwrite")


def _check_counts(n: int, batch_size: int) -> None:
    if int(n) != n or n < 1:
        raise ValueError(f"--n must be a positive integer, got {n!r}")
    if int(batch_size) != batch_size or batch_size < 1:
        raise ValueError(f"batch size must be a positive integer, got {batch_size!r}")


def rendered_samples(
    n: int,
    seed: int,
    config: SynthConfig = SynthConfig(),
    batch_size: int = 8,
    progress: Callable[[int], None] | None = None,
    first: int = 0,
) -> Iterator[tuple[int, Scene, Rendering, RoomLabels]]:
    """The samples of :func:`write_dataset` in index order, rendered but not written.

    Sample ``i`` is made from ``fold_in(key(seed), i)`` in batches of a fixed
    size (the last one padded), so a sample does not depend on ``n`` or on
    ``batch_size``. Yields ``(index, scene, rendering, labels)`` as numpy
    pytrees, for indices ``first`` to ``n - 1``; ``progress`` is called with the
    number of samples after each batch.

    Raises:
        RuntimeError: a sample's labels are invalid.
    """
    _check_counts(n, batch_size)
    if not 0 <= first < n:
        raise ValueError(f"first sample {first} not in [0, {n})")
    base = jax.random.key(seed)
    for start in range(first, n, batch_size):
        indices = np.arange(start, start + batch_size)
        keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.asarray(indices, jnp.uint32))
        scenes, renderings, labels = jax.device_get(synthesize_batch(keys, config))
        for offset, index in enumerate(indices[: n - start]):
            scene, rendering, label = jax.tree.map(lambda x: x[offset], (scenes, renderings, labels))
            if not bool(label.ok):
                status = RoomStatus(int(scene.room.status)).name
                raise RuntimeError(f"sample {index} has invalid labels (room status {status}); try another seed")
            yield int(index), scene, rendering, label
        if progress is not None:
            progress(min(batch_size, n - start))


def rendering_rgb8(rendering: Rendering) -> np.ndarray:
    """The (H, W, 3) uint8 RGB image that the dataset stores for a rendering."""
    return np.round(np.clip(np.asarray(rendering.rgb), 0, 1) * 255).astype(np.uint8)


def write_dataset(
    directory: str,
    n: int,
    seed: int,
    config: SynthConfig = SynthConfig(),
    batch_size: int = 8,
    overwrite: bool = False,
    progress: Callable[[int], None] | None = None,
) -> list[str]:
    """Generate and write ``n`` samples (see the module docstring for the layout).

    Sample ``i`` is made from ``fold_in(key(seed), i)`` in batches of a fixed
    size (the last one padded), so a sample does not depend on ``n``.

    Args:
        directory: output folder (created; must be empty unless ``overwrite``).
        n: number of samples, >= 1.
        seed: integer seed.
        config: room, scene and render settings and the image size.
        batch_size: samples rendered per jitted call.
        overwrite: allow a non-empty ``directory``.
        progress: called with the number of samples written after each batch.

    Returns:
        The sample names, in index order.
    """
    _check_counts(n, batch_size)
    _check_output_directory(directory, overwrite)
    for folder in FOLDERS:
        os.makedirs(os.path.join(directory, folder), exist_ok=True)
    names: list[str] = []
    splits: dict[str, list[str]] = {split: [] for split in SPLITS}
    for index, scene, rendering, label in rendered_samples(n, seed, config, batch_size, progress):
        world = "atlanta" if bool(scene.room.is_atlanta) else "manhattan"
        name = sample_name(world, index, float(scene.room.rc))
        cam = NonCentralPanorama(config.width, config.height, rc=scene.room.rc)
        write_sample(directory, name, rendering, label, sample_metadata(name, scene, label, cam, index, seed))
        names.append(name)
        splits[split_of(index, seed)].append(name)
    write_atomic(os.path.join(directory, "split.json"), (json.dumps(splits, indent=1) + "\n").encode())
    return names


# --------------------------------------------------------------------- reader


@dataclasses.dataclass
class DatasetSample:
    """One sample read back (numpy arrays; camera frame unless said otherwise).

    Attributes:
        name: file name without extension.
        image: (H, W, 3) uint8 RGB.
        rc: radius of the circle of optical centres, metres.
        label_cor: (2N, 2) integer (x, y) pairs, ceiling then floor of each corner.
        camera_position: (3,) world frame.
        ceiling_corners, floor_corners: (N, 3) the corners of ``label_cor``.
        ceiling_v, floor_v: (W,) boundary rows (ours: exact from the json; the
            authors': computed from the corners with :func:`labels_from_corners`).
        depth: (H, W) metres, or None; semantic: (H, W) classes, or None.
        metadata: the json record, or None.
    """

    name: str
    image: np.ndarray
    rc: float
    label_cor: np.ndarray
    camera_position: np.ndarray
    ceiling_corners: np.ndarray
    floor_corners: np.ndarray
    ceiling_v: np.ndarray
    floor_v: np.ndarray
    depth: np.ndarray | None
    semantic: np.ndarray | None
    metadata: dict | None


def list_samples(directory: str) -> list[str]:
    """Names of the complete samples of a dataset folder (ours or the authors'), sorted."""
    required = ["img", "label_cor", "3D_gt", "cam_pose"]
    if not all(os.path.isdir(os.path.join(directory, folder)) for folder in required):
        raise ValueError(f"{directory!r} is not a dataset folder: it needs the sub-folders {', '.join(required)}")
    names = {os.path.splitext(f)[0] for f in os.listdir(os.path.join(directory, "img")) if f.endswith(".png")}
    has_json = os.path.isdir(os.path.join(directory, "json"))
    complete = []
    for name in names:
        files = [f"label_cor/{name}.txt", f"3D_gt/{name}.npy", f"cam_pose/{name}.npy"]
        files += [f"json/{name}.json"] if has_json else []
        if all(os.path.exists(os.path.join(directory, f)) for f in files):
            complete.append(name)
    return sorted(complete)


def read_split(directory: str) -> dict[str, list[str]]:
    """The ``split.json`` of a dataset folder."""
    with open(os.path.join(directory, "split.json")) as file:
        return json.load(file)


_room_labels = jax.jit(room_labels, static_argnames="corner_capacity")


def labels_from_corners(
    ceiling_corners: np.ndarray, floor_corners: np.ndarray, cam: NonCentralPanorama, capacity: int = 32
) -> RoomLabels:
    """Exact labels of the layout whose visible corners are given in image order.

    The corners (camera frame) in image order turn clockwise seen from +z;
    reversed they are the counter-clockwise floor plan of the visible room (an
    occlusion's near and far points are joined by a segment along the corner's
    column ray, which no other column's ray meets), so
    :func:`~ncjax.synth.room_labels` gives the boundary rows of every column.
    """
    n = len(ceiling_corners)
    if n < 3 or n > capacity or len(floor_corners) != n:
        raise ValueError(f"need 3 to {capacity} ceiling and as many floor corners, got {n} and {len(floor_corners)}")
    corners = np.zeros((capacity, 2), np.float32)
    corners[:n] = np.asarray(ceiling_corners)[::-1, :2]
    room = Room(
        corners=jnp.asarray(corners),
        mask=jnp.arange(capacity) < n,
        ceiling_height=jnp.asarray(np.mean(np.asarray(ceiling_corners)[:, 2]), jnp.float32),
        floor_height=jnp.asarray(np.mean(np.asarray(floor_corners)[:, 2]), jnp.float32),
        rc=jnp.asarray(cam.rc, jnp.float32),
        camera_position=jnp.zeros(3),
        is_atlanta=jnp.array(False),
        status=jnp.array(RoomStatus.OK, jnp.int32),
    )
    return _room_labels(room, cam)


def read_sample(directory: str, name: str, rc: float | None = None) -> DatasetSample:
    """Read one sample of our folders or the authors'.

    Args:
        directory: the dataset folder.
        name: the sample name (file name without extension).
        rc: the radius in metres, for samples with neither a json nor ``_R<rc>``
            in their name; ignored otherwise.

    Raises:
        ValueError: a file is missing or malformed, or rc cannot be known.
    """

    def path(folder, ext):
        return os.path.join(directory, folder, f"{name}{ext}")

    image = cv2.imread(path("img", ".png"), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"cannot read the image {path('img', '.png')!r}")
    image = image[..., ::-1].copy()
    metadata = None
    if os.path.exists(path("json", ".json")):
        with open(path("json", ".json")) as file:
            metadata = json.load(file)
    rc_value = metadata["rc"] if metadata else rc_from_name(name)
    rc_value = rc if rc_value is None else rc_value
    if rc_value is None:
        raise ValueError(f"sample {name!r}: no json, no _R<rc> in the name and no rc given")
    label_cor = np.loadtxt(path("label_cor", ".txt"), dtype=np.int64, ndmin=2)
    points = np.load(path("3D_gt", ".npy"))
    camera_position = np.load(path("cam_pose", ".npy")).reshape(3)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) % 2:
        raise ValueError(f"{path('3D_gt', '.npy')!r}: expected (2N, 3) corners, got shape {points.shape}")
    local = points - camera_position
    ceiling, floor = local[: len(local) // 2], local[len(local) // 2 :]
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc=rc_value)
    if metadata:
        ceiling_v, floor_v = np.asarray(metadata["ceiling_v"]), np.asarray(metadata["floor_v"])
    else:
        labels = labels_from_corners(ceiling, floor, cam)
        ceiling_v, floor_v = np.asarray(labels.ceiling_v), np.asarray(labels.floor_v)
    depth = cv2.imread(path("depth", ".png"), cv2.IMREAD_UNCHANGED) if os.path.exists(path("depth", ".png")) else None
    semantic = (
        cv2.imread(path("semantic", ".png"), cv2.IMREAD_UNCHANGED) if os.path.exists(path("semantic", ".png")) else None
    )
    return DatasetSample(
        name=name,
        image=image,
        rc=float(rc_value),
        label_cor=label_cor,
        camera_position=camera_position,
        ceiling_corners=ceiling,
        floor_corners=floor,
        ceiling_v=ceiling_v,
        floor_v=floor_v,
        depth=None if depth is None else depth.astype(np.float64) / 1000.0,
        semantic=semantic,
        metadata=metadata,
    )


def read_dataset(directory: str, names: Iterable[str] | None = None, rc: float | None = None) -> list[DatasetSample]:
    """Read several samples (all complete ones by default)."""
    return [read_sample(directory, name, rc) for name in (list_samples(directory) if names is None else names)]
