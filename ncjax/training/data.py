"""Training data: rendered dataset folders, their arrays and batches, and painted stand-in panoramas."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pathlib
import time
from collections.abc import Callable, Iterator

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float, PRNGKeyArray

from ..evaluation.network_metrics import network_table
from ..geometry.camera import NonCentralPanorama
from ..network.model import HorizonNet, check_views, predict_views, prediction_to_rows
from ..pipeline.corners import CORNER_LABEL_BASE
from ..synth.dataset import (
    SPLITS,
    DatasetSample,
    labels_from_corners,
    list_samples,
    read_sample,
    read_split,
    rendered_samples,
    rendering_rgb8,
    split_of,
)
from ..synth.labels import reencode_corner_prob
from ..synth.photoreal import PhotorealConfig
from ..synth.render import SynthConfig
from ..synth.rooms import RoomConfig
from ..synth.scene import SceneConfig

# ----------------------------------------------------------------------------- stand-in data


def paint_panorama(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    wall_index: Array,
    height: int,
    colours: Float[Array, "3 3"],
) -> Float[Array, "H W 3"]:
    """A flat-shaded panorama: ceiling colour above ``ceiling_v``, walls between, floor below.

    Pixel row ``r`` covers ``[r - 0.5, r + 0.5]`` (docs/design.md pixel centres), and
    the boundary pixels get the covered fractions (sub-pixel labels). Walls
    alternate between two shades by index so that corners are visible.
    """
    rows = jnp.arange(height, dtype=ceiling_v.dtype)[:, None]
    above_ceiling = jnp.clip(ceiling_v[None, :] - (rows - 0.5), 0.0, 1.0)
    below_floor = jnp.clip((rows + 0.5) - floor_v[None, :], 0.0, 1.0)
    shade = jnp.where(wall_index % 2 == 0, 1.0, 0.65)[None, :, None]
    wall = 1.0 - above_ceiling - below_floor
    return (
        above_ceiling[..., None] * colours[0]
        + wall[..., None] * colours[1] * shade
        + below_floor[..., None] * colours[2]
    )


@functools.partial(jax.jit, static_argnames=("batch_size", "height", "width"))
def painted_batch(key: PRNGKeyArray, batch_size: int, height: int, width: int) -> dict[str, Array]:
    """A batch of flat-coloured panoramas of random rooms with exact labels (a stand-in data source).

    Rooms come from :func:`ncjax.synth.random_room` (mixed Manhattan / Atlanta) and
    labels from :func:`ncjax.synth.room_labels`; the images are painted with
    :func:`paint_panorama` in random colours. Meant for tests and smoke runs
    until rendered data is wired in.
    """
    from ..synth.labels import room_labels
    from ..synth.rooms import random_room

    room_config = RoomConfig(world="mix", max_walls=8, camera_tries=32, room_tries=2)

    def one(k):
        k_room, k_colour = jax.random.split(k)
        room = random_room(k_room, room_config)
        labels = room_labels(room, room.camera(width, height))
        colours = jax.random.uniform(k_colour, (3, 3), minval=0.1, maxval=0.9)
        image = paint_panorama(labels.ceiling_v, labels.floor_v, labels.wall_index, height, colours)
        return {
            "image": image.astype(jnp.float32),
            "ceiling_v": labels.ceiling_v.astype(jnp.float32),
            "floor_v": labels.floor_v.astype(jnp.float32),
            "corner_target": labels.corner_target.astype(jnp.float32),
        }

    return jax.vmap(one)(jax.random.split(key, batch_size))


def painted_batches(seed: int, batch_size: int, height: int, width: int) -> Callable[[int], Iterator[dict]]:
    """``start_step -> iterator`` of :func:`painted_batch` es, batch ``i`` keyed by ``(seed, i)``."""

    def from_step(start: int) -> Iterator[dict]:
        step = start
        while True:
            yield painted_batch(jax.random.fold_in(jax.random.PRNGKey(seed), step), batch_size, height, width)
            step += 1

    return from_step


# ----------------------------------------------------------------------------- dataset folders


def sample_arrays(sample: DatasetSample, height: int, width: int) -> dict[str, np.ndarray]:
    """One dataset sample at the network's input size (:func:`network_arrays`)."""
    return network_arrays(sample.image, sample.rc, sample.ceiling_corners, sample.floor_corners, height, width)


def network_arrays(
    image: np.ndarray, rc: float, ceiling_corners: np.ndarray, floor_corners: np.ndarray, height: int, width: int
) -> dict[str, np.ndarray]:
    """A uint8 panorama and its layout at the network's input size: image and exact labels in its pixels.

    The image is shrunk with pixel-area averaging (``cv2.INTER_AREA``); the
    labels (boundary rows and the ``0.96**d`` corner target) are recomputed
    exactly for a camera of that size from the 3D corners (camera frame, image
    order; :func:`~ncjax.synth.dataset.labels_from_corners`), so no interpolation
    blurs the occlusion jumps.
    """
    if image.shape[:2] != (height, width):
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    camera = NonCentralPanorama(width, height, rc=rc)
    labels = labels_from_corners(ceiling_corners, floor_corners, camera)
    return {
        "image": image,
        "ceiling_v": np.asarray(labels.ceiling_v, np.float32),
        "floor_v": np.asarray(labels.floor_v, np.float32),
        "corner_target": np.asarray(labels.corner_target, np.float32),
    }


SYNTH_COMMAND_CONFIG = SynthConfig(room=RoomConfig(world="mix"))
"""What ``ncjax synth`` renders by default: world ``mix``, rc 0.3-1.0 m, 512 x 1024."""

_HOME_ROOMS = dataclasses.replace(
    SYNTH_COMMAND_CONFIG,
    room=RoomConfig(world="mix", rc_range=(0.0, 0.0)),
    scene=SceneConfig(decor=True, neutral_paint_probability=0.7, beam_probability=0.2),
)
_OPEN_ROOMS = dataclasses.replace(
    SYNTH_COMMAND_CONFIG,
    room=RoomConfig(world="mix", rc_range=(0.0, 0.0)),
    scene=SceneConfig(decor=True, door_probability=0.6, passage_probability=0.5, beam_probability=0.2),
)


def _narrow_rooms(room: dict, scene: dict) -> SynthConfig:
    """Narrow Manhattan rooms (closets, corridors) seen by a central camera, which stands, and lets the furniture
    stand, nearer the walls than in other rooms; ``room`` and ``scene`` set the rest of the :class:`RoomConfig` and
    the decor's :class:`SceneConfig`."""
    room = dict(world="manhattan", max_walls=6, height_range=(2.3, 2.9), rc_range=(0.0, 0.0), camera_margin=0.2) | room
    return dataclasses.replace(
        SYNTH_COMMAND_CONFIG,
        room=RoomConfig(**room),
        scene=SceneConfig(**(dict(decor=True, camera_clearance=0.15, candidates_per_slot=6) | scene)),
    )


# What both kinds of closet have: wide openings, pale walls, shelving.
_CLOSETS = dict(
    passage_width_range=(0.9, 2.2),
    neutral_paint_probability=0.7,
    furniture_weights=(("closet shelving", 20.0), ("closet shelving with clothes", 10.0)),
)

SYNTH_SOURCES = {
    "synth": SYNTH_COMMAND_CONFIG,
    "synth-decor": dataclasses.replace(SYNTH_COMMAND_CONFIG, scene=SceneConfig(decor=True)),
    "synth-decor-central": dataclasses.replace(
        SYNTH_COMMAND_CONFIG, room=RoomConfig(world="mix", rc_range=(0.0, 0.0)), scene=SceneConfig(decor=True)
    ),
    "synth-decor-home": _HOME_ROOMS,
    "synth-photoreal-home": dataclasses.replace(_HOME_ROOMS, photoreal=PhotorealConfig()),
    "synth-decor-small": dataclasses.replace(
        SYNTH_COMMAND_CONFIG,
        room=RoomConfig(world="mix", size_range=(1.2, 4.0), max_walls=6, rc_range=(0.0, 0.0)),
        scene=SceneConfig(decor=True),
    ),
    "synth-decor-closet": _narrow_rooms(
        dict(size_range=(1.2, 2.6)),
        dict(opening_slots=2, door_probability=1.0, passage_probability=0.85, **_CLOSETS),
    ),
    "synth-decor-closet-door": _narrow_rooms(
        dict(
            max_walls=4, size_range=(1.2, 2.6), width_range=(0.6, 1.2), camera_margin=0.1, doorway_distance=(0.03, 0.15)
        ),
        dict(passage_at_camera=True, camera_clearance=0.05, opening_slots=1, furniture_probability=1.0, **_CLOSETS),
    ),
    "synth-decor-hall": _narrow_rooms(
        dict(size_range=(3.0, 7.5), width_range=(0.9, 1.6)),
        dict(
            door_probability=0.9,
            open_door_probability=0.75,
            passage_probability=0.2,
            passage_width_range=(0.9, 1.6),
            neutral_paint_probability=0.8,
            furniture_probability=0.15,
        ),
    ),
    "synth-decor-open": _OPEN_ROOMS,
    "synth-photoreal-open": dataclasses.replace(_OPEN_ROOMS, photoreal=PhotorealConfig()),
}
"""The configuration of each kind of rendered data source, ``KIND:SEED:N``
(``synth-decor``: what ``ncjax synth --decor`` renders; ``synth-decor-central``: such
rooms seen by a central camera, rc = 0, as most real panoramas are; ``synth-decor-home``: the
same with white, off-white or pale walls in 70% of them, as in most homes, and beams or dropped headers across
the ceiling in 20% (as the open plans); ``synth-photoreal-home``: the
rooms of ``synth-decor-home`` (the same ones for the same seed) path-traced and photographed
(:mod:`ncjax.synth.photoreal`); ``synth-decor-small``:
closets, bathrooms and corridors, sides of 1.2-4 m and at most 6 walls, seen by a central
camera, whose walls fill the panorama as no room of the other kinds does; ``synth-decor-closet``: walk-in
closets and alcoves, sides of 1.2-2.6 m, their walls lined with shelving (some with clothes hanging), seen by
a central camera from inside, most with a passage 0.9-2.2 m wide that fills much of a wall and shows the room
behind it (the label stays in the closet's wall plane); ``synth-decor-closet-door``: closets 0.6-1.2 m deep and
1.2-2.6 m wide photographed from their opening, as they mostly are: the camera 3-15 cm inside it, the opening
filling nearly all of that wall (labelled in its plane, close under the camera) and showing the room behind, shelving
along the other walls; ``synth-decor-hall``: corridors 0.9-1.6 m wide and
3-7.5 m long, seen by a central camera from inside, doors along them, most open on the rooms behind (whose floors
run on past the corridor's wall-floor edge, close to the bottom of the image), few pieces of furniture;
``synth-decor-open``:
realistic rooms seen by a central camera with more doors, half of them wide passages to the next
room, as in open plans, across which the boundary stays in the wall plane; ``synth-photoreal-open``: the
rooms of ``synth-decor-open`` path-traced and photographed)."""


RENDER_CHUNK = 64
"""Rooms per file of a render cache (:func:`rendered_splits`)."""


class RenderingStopped(Exception):
    """The time budget ran out while a ``KIND:SEED:N`` source was rendered into its cache, or the render budget
    left no rooms to train or validate on; what was rendered is kept there, and the same command goes on from it."""


def _cache_files(n: int) -> list[tuple[int, int]]:
    """``(first, last)`` rooms of each render-cache file of a source of ``n`` rooms, in order."""
    return [(first, min(first + RENDER_CHUNK, n)) for first in range(0, n, RENDER_CHUNK)]


def _cache_file(cache: pathlib.Path, first: int, last: int) -> pathlib.Path:
    return cache / f"{first:06d}-{last:06d}.npz"


def _write_cache_file(path: pathlib.Path, arrays: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_suffix(".partial")
    with open(partial, "wb") as file:  # renamed once whole: an interrupted write is never read
        np.savez(file, **arrays)
    os.replace(partial, path)


def _rendered_arrays(
    seed: int, first: int, last: int, height: int, width: int, batch_size: int, config: SynthConfig, bar
) -> dict[str, np.ndarray]:
    """:func:`network_arrays` of samples ``first`` to ``last - 1``, stacked, with each one's split (its index in
    :data:`SPLITS`) under ``"split"``."""
    samples = []
    for index, scene, rendering, labels in rendered_samples(last, seed, config, batch_size, bar.update, first):
        mask = np.asarray(labels.corner_mask)
        arrays = network_arrays(
            rendering_rgb8(rendering),
            float(scene.room.rc),
            np.asarray(labels.ceiling_corners)[mask],
            np.asarray(labels.floor_corners)[mask],
            height,
            width,
        )
        arrays["split"] = np.int8(list(SPLITS).index(split_of(index, seed)))
        samples.append(arrays)
    return {key: np.stack([a[key] for a in samples]) for key in samples[0]}


def rendered_splits(
    seed: int,
    n: int,
    height: int,
    width: int,
    batch_size: int = 16,
    config: SynthConfig = SYNTH_COMMAND_CONFIG,
    progress: bool = True,
    cache: pathlib.Path | None = None,
    deadline: float | None = None,
) -> dict[str, dict[str, np.ndarray]]:
    """The samples ``ncjax synth --n N --seed SEED`` would write, as :func:`load_split` arrays per split.

    Rendered in memory (the same rooms and pixels as the written files, in
    index order rather than name order), so a machine with a fast accelerator
    trains without writing and decoding thousands of files. Splits without
    samples are left out.

    With ``cache`` (a folder for this source, its configuration and size) the rooms are kept there in files of
    :data:`RENDER_CHUNK` and read back rather than rendered again: a rerun, or a resumed training, starts at
    once, and rooms that take seconds each (photoreal ones on a CPU) are rendered over several runs.

    Raises:
        RenderingStopped: with ``cache``, ``deadline`` (a :func:`time.monotonic` time) passed between two files
            while rooms were left to render.
    """
    from tqdm.auto import tqdm

    chunks = _cache_files(n) if cache else [(0, n)]
    parts = []
    with tqdm(total=n, desc=f"render seed {seed}", disable=not progress) as bar:
        for first, last in chunks:
            path = None if cache is None else _cache_file(cache, first, last)
            if path is not None and path.exists():
                with np.load(path) as stored:
                    parts.append(dict(stored))
                bar.update(last - first)
                continue
            if path is not None and deadline is not None and time.monotonic() >= deadline:
                raise RenderingStopped(f"rendered {first} of {n} rooms into {cache}; rerun the same command to go on")
            parts.append(_rendered_arrays(seed, first, last, height, width, batch_size, config, bar))
            if path is not None:
                _write_cache_file(path, parts[-1])
    arrays = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
    split = arrays.pop("split")
    return {
        name: {key: value[split == code] for key, value in arrays.items()}
        for code, name in enumerate(SPLITS)
        if np.any(split == code)
    }


def render_cache_folder(cache: pathlib.Path, source: str, height: int, width: int) -> pathlib.Path:
    """The folder of ``cache`` that keeps the rooms of ``KIND:SEED:N`` ``source`` at ``height`` x ``width``: named
    by the kind, the seed, the size and a digest of the kind's configuration (any N: a sample does not depend on
    it), so a changed configuration never reads another's rooms."""
    kind, seed, _ = source.split(":")
    digest = hashlib.sha256(repr(SYNTH_SOURCES[kind]).encode()).hexdigest()[:10]
    return cache / f"{kind}_{seed}_{height}x{width}_{digest}"


def load_split(
    directory: str, split: str, height: int, width: int, limit: int | None = None, progress: bool = True
) -> dict[str, np.ndarray]:
    """Stack the samples of one split of a dataset folder (``split.json``) with :func:`sample_arrays`.

    ``split="all"`` takes every sample; folders without ``split.json`` (e.g.
    the authors') are used whole for any split.

    Raises:
        ValueError: not a dataset folder, an unknown split, or an empty one.
    """
    from tqdm.auto import tqdm

    names = list_samples(directory)
    if split != "all" and os.path.exists(os.path.join(directory, "split.json")):
        splits = read_split(directory)
        if split not in splits:
            raise ValueError(f"{directory}: split {split!r} not in split.json (has {', '.join(splits)})")
        kept = set(splits[split])
        names = [name for name in names if name in kept]
    names = names[:limit] if limit else names
    if not names:
        raise ValueError(f"{directory}: no complete samples in split {split!r}")
    arrays = [
        sample_arrays(read_sample(directory, name), height, width)
        for name in tqdm(names, desc=f"load {split}", disable=not progress)
    ]
    return {key: np.stack([a[key] for a in arrays]) for key in arrays[0]}


def parse_synth_source(source: str) -> tuple[int, int] | None:
    """``(seed, n)`` of a ``KIND:SEED:N`` data source (``KIND`` one of :data:`SYNTH_SOURCES`)
    (its configuration: ``SYNTH_SOURCES[source.split(":")[0]]``), None for a folder path.

    Raises:
        ValueError: ``KIND:`` followed by anything but two integers, N >= 1.
    """
    kind = source.split(":")[0]
    if kind not in SYNTH_SOURCES or ":" not in source:
        return None
    parts = source.split(":")
    if len(parts) != 3 or not all(p.lstrip("-").isdigit() for p in parts[1:]) or int(parts[2]) < 1:
        raise ValueError(f"data source {source!r}: expected {kind}:SEED:N with integers SEED and N >= 1")
    return int(parts[1]), int(parts[2])


def render_in_proportion(
    sources: list[str],
    height: int,
    width: int,
    render_cache: pathlib.Path,
    deadline: float,
    batch_size: int = 16,
    progress: bool = True,
) -> dict[str, int]:
    """Render ``KIND:SEED:N`` sources into their :func:`render_cache_folder` in ``render_cache`` until ``deadline``
    (a :func:`time.monotonic` time, checked between files of :data:`RENDER_CHUNK` rooms), the next file always the
    source's that has the smallest share of its rooms: when time runs out every source has about the same share of
    its rooms, so that the mix the sources' N set holds whatever the rendering costs.

    Returns:
        For each source, how many of its rooms, from the first on, are in the cache (N once all are).

    Raises:
        ValueError: a source that is not ``KIND:SEED:N``.
    """
    from tqdm.auto import tqdm

    synth = {}
    for source in sources:
        parsed = parse_synth_source(source)
        if parsed is None:
            raise ValueError(f"{source!r} is not a rendered source KIND:SEED:N")
        synth[source] = parsed
    files = {source: _cache_files(n) for source, (_, n) in synth.items()}
    done = dict.fromkeys(synth, 0)  # files of each source in the cache, from its first on

    def rooms(source: str) -> int:
        return files[source][done[source] - 1][1] if done[source] else 0

    def share(source: str) -> float:
        return rooms(source) / synth[source][1]

    with tqdm(total=sum(n for _, n in synth.values()), desc="render", disable=not progress) as bar:
        while unfinished := [source for source in synth if done[source] < len(files[source])]:
            source = min(unfinished, key=share)  # the first such source on ties
            folder = render_cache_folder(render_cache, source, height, width)
            first, last = files[source][done[source]]
            path = _cache_file(folder, first, last)
            if not path.exists():
                if time.monotonic() >= deadline:
                    break
                seed, config = synth[source][0], SYNTH_SOURCES[source.split(":")[0]]
                _write_cache_file(path, _rendered_arrays(seed, first, last, height, width, batch_size, config, bar))
            else:
                bar.update(last - first)
            done[source] += 1
    return {source: rooms(source) for source in synth}


def training_data(
    sources: list[str],
    height: int,
    width: int,
    validation_limit: int | None,
    render_cache: pathlib.Path | None = None,
    deadline: float | None = None,
    rendered_rooms: dict[str, int] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Train and validation arrays pooled, in the given order, from dataset folders and
    ``KIND:SEED:N`` renders (:data:`SYNTH_SOURCES`).

    Such a source is rendered in memory (:func:`rendered_splits`; with ``render_cache``, kept in its
    :func:`render_cache_folder` there and rendered until ``deadline``); validation takes the first
    ``validation_limit`` images of the pooled valid splits (None: all). With ``rendered_rooms`` (what
    :func:`render_in_proportion` returns) a source takes only its first rooms, those in the cache; one that has
    fewer than its N may lack a split.

    Raises:
        RenderingStopped: ``deadline`` passed while rooms were left to render into ``render_cache``, or
            ``rendered_rooms`` give no training or no validation rooms.
    """
    synth_sources = [parse_synth_source(source) for source in sources]  # malformed ones fail before any work
    pooled: dict[str, list[dict[str, np.ndarray]]] = {"train": [], "valid": []}
    for source, synth in zip(sources, synth_sources, strict=True):
        if synth is None:
            for split in pooled:
                pooled[split].append(
                    load_split(source, split, height, width, limit=validation_limit if split == "valid" else None)
                )
            continue
        seed, n = synth
        rooms = n if rendered_rooms is None else rendered_rooms[source]
        if rooms == 0:
            continue
        cache = None if render_cache is None else render_cache_folder(render_cache, source, height, width)
        config = SYNTH_SOURCES[source.split(":")[0]]
        rendered = rendered_splits(seed, rooms, height, width, config=config, cache=cache, deadline=deadline)
        for split in pooled:
            if split in rendered:
                pooled[split].append(rendered[split])
            elif rooms == n:
                raise ValueError(f"data source {source!r} has no {split} samples; render more (N)")
    for split, parts in pooled.items():
        if not parts:
            raise RenderingStopped(f"no {split} rooms in {render_cache} yet; rerun the same command to go on")
    train_arrays, valid = (
        {key: np.concatenate([a[key] for a in parts]) for key in parts[0]} for parts in pooled.values()
    )
    limit = len(valid["image"]) if validation_limit is None else validation_limit
    return train_arrays, {key: value[:limit] for key, value in valid.items()}


def folder_batches(arrays: dict[str, np.ndarray], batch_size: int, seed: int) -> Callable[[int], Iterator[dict]]:
    """``start_step -> iterator`` of batches drawn from :func:`load_split` arrays.

    Batch ``i`` holds distinct samples chosen by a generator seeded with
    ``(seed, i)``, so a resumed run sees the same batches.
    """
    count = len(arrays["image"])
    if batch_size > count:
        raise ValueError(f"batch size {batch_size} exceeds the {count} samples")

    def from_step(start: int) -> Iterator[dict]:
        step = start
        while True:
            chosen = np.random.default_rng((seed, step)).choice(count, batch_size, replace=False)
            batch = {key: value[chosen] for key, value in arrays.items()}
            yield {**batch, "image": batch["image"].astype(np.float32) / 255.0}
            step += 1

    return from_step


def evaluate_arrays(
    model: HorizonNet, arrays: dict[str, np.ndarray], batch_size: int = 8, views: int = 1
) -> dict[str, float]:
    """Table netcorExp's row (:func:`~ncjax.evaluation.network_table`) of a model on :func:`load_split` arrays.

    The corner output is compared in the labels' ``0.96**d`` encoding whatever
    the model's ``corner_base`` (:func:`~ncjax.synth.labels.reencode_corner_prob`).

    ``views``: the network's output averaged over rolled and mirrored views
    (:func:`~ncjax.network.model.predict_views`); 1 is the network alone.
    """
    check_views(views)
    model.eval()
    count, height, width = arrays["image"].shape[:3]
    outputs = []
    for start in range(0, count, batch_size):
        images = arrays["image"][start : start + batch_size]
        padded = np.concatenate([images, np.repeat(images[-1:], batch_size - len(images), 0)])
        prediction = _forward(model, jnp.asarray(padded, jnp.float32) / 255.0, views)
        rows = prediction_to_rows(prediction, height, width)
        outputs.append([np.asarray(r)[: len(images)] for r in rows])
    ceiling_v, floor_v, corner_prob = (np.concatenate(parts) for parts in zip(*outputs, strict=True))
    corner_prob = reencode_corner_prob(corner_prob, model.config.corner_base, CORNER_LABEL_BASE)
    table = network_table(
        ceiling_v, floor_v, corner_prob, arrays["ceiling_v"], arrays["floor_v"], arrays["corner_target"]
    )
    return {key: float(value) for key, value in table.items()}


_forward = nnx.jit(predict_views, static_argnames=("views",))
