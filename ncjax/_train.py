"""Training of Non-central HorizonNet: loss, augmentations, optimiser, steps, checkpoints.

The loss is HorizonNet's (Sun et al. 2019): the L1 distance between predicted
and true boundary elevations in radians (ceiling and floor, averaged) plus the
binary cross-entropy between the corner logits and the target ``0.96**d``.

Augmentations keep the labels exact (:func:`augment_sample`):

- horizontal roll by ``s`` columns: the panorama of the room rotated about the
  revolution axis by ``2 pi s / W`` (the circle of optical centres is
  rotation-invariant); labels roll with the image.
- left-right flip: column ``u`` goes to ``W - 1 - u``, i.e. azimuth ``varphi``
  to ``-varphi``. The circle of centres and its radial rays are symmetric
  about the x axis, so the flipped image is exactly the panorama of the room
  mirrored in y (same ``rc``, same rows per column): a valid non-central
  panorama, labels flipped with it (tested with :func:`ncjax.room_labels`).
- photometric (gamma, brightness, greyscale): labels unchanged.

Randomness is a pure function of ``(seed, step)`` (augmentation and dropout
keys are ``fold_in(step_key_root(seed), step)``), so a run resumed from a checkpoint
continues the same trajectory bit for bit when the data does.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import os
import pathlib
import time
from collections.abc import Callable, Iterator
from typing import NamedTuple

import jax
import jax.numpy as jnp
import cv2
import numpy as np
import optax
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float, PRNGKeyArray

from ._checkpoint import check_warm_start, load_checkpoint, load_weights, save_checkpoint
from ._camera import NonCentralPanorama
from ._dataset import (
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
from ._render import SynthConfig
from ._network import (
    BoundaryPrediction,
    HorizonNet,
    HorizonNetConfig,
    check_views,
    init_model,
    prediction_to_rows,
    predict_views,
    row_to_elevation,
)
from ._network_metrics import network_table
from ._rooms import CORNER_LABEL_BASE, RoomConfig, reencode_corner_prob

# ----------------------------------------------------------------------------- configuration


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Optimiser and augmentation settings (hashable: a jit static argument).

    Attributes:
        peak_learning_rate: AdamW learning rate after warm-up.
        warmup_steps: linear warm-up from 0.
        total_steps: length of the cosine decay (to ``final_learning_rate_fraction``).
        final_learning_rate_fraction: end of the cosine, relative to the peak.
        weight_decay: AdamW's decoupled weight decay.
        gradient_clip: maximum global gradient norm.
        roll, flip: random horizontal roll / left-right flip (labels follow).
        max_gamma: gamma drawn log-uniformly in ``[1 / max_gamma, max_gamma]``.
        max_brightness: intensity factor drawn uniformly in ``[1 - b, 1 + b]``.
        greyscale_probability: probability of replacing the colours by their luminance.
    """

    peak_learning_rate: float = 1e-3
    warmup_steps: int = 200
    total_steps: int = 20_000
    final_learning_rate_fraction: float = 0.01
    weight_decay: float = 1e-4
    gradient_clip: float = 1.0
    roll: bool = True
    flip: bool = True
    max_gamma: float = 1.5
    max_brightness: float = 0.2
    greyscale_probability: float = 0.1

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        return cls(**json.loads(text))


def make_optimizer(model: HorizonNet, train_config: TrainConfig) -> nnx.Optimizer:
    """AdamW with linear warm-up, cosine decay and global-norm gradient clipping.

    Built in a jitted function, like :func:`~ncjax._network.init_model`, so that a
    fresh optimizer and one restored from a checkpoint have equal graph
    definitions (the jitted train step is then compiled once for both).
    """
    return _optimizer_builder(train_config)(model)


@functools.cache
def _optimizer_builder(train_config: TrainConfig):
    return nnx.jit(lambda model: _adamw(model, train_config))


def _adamw(model: HorizonNet, train_config: TrainConfig) -> nnx.Optimizer:
    schedule = optax.warmup_cosine_decay_schedule(
        init_value=0.0,
        peak_value=train_config.peak_learning_rate,
        warmup_steps=train_config.warmup_steps,
        decay_steps=max(train_config.total_steps, train_config.warmup_steps + 1),
        end_value=train_config.peak_learning_rate * train_config.final_learning_rate_fraction,
    )
    tx = optax.chain(
        optax.clip_by_global_norm(train_config.gradient_clip),
        optax.adamw(schedule, weight_decay=train_config.weight_decay),
    )
    return nnx.Optimizer(model, tx, wrt=nnx.Param)


# ----------------------------------------------------------------------------- loss


def horizonnet_loss(
    prediction: BoundaryPrediction,
    ceiling_v: Float[ArrayLike, "B W"],
    floor_v: Float[ArrayLike, "B W"],
    corner_target: Float[ArrayLike, "B W"],
    image_height: int,
    corner_base: float = CORNER_LABEL_BASE,
) -> dict[str, Float[Array, ""]]:
    """HorizonNet's loss: L1 on the boundary elevations (radians) + BCE with logits on the corners.

    Args:
        prediction: network output for the batch.
        ceiling_v, floor_v: true boundary rows (pixels of an ``image_height``-row image).
        corner_target: ``0.96**d`` per column (the labels' encoding).
        image_height: rows of the image the labels refer to.
        corner_base: the network's corner encoding ``corner_base**d``
            (``HorizonNetConfig.corner_base``); the target is re-encoded to it.

    Returns:
        ``{"loss": boundary + corner, "boundary": ..., "corner": ...}``.
    """
    ceiling_error = jnp.abs(prediction.ceiling_elevation - row_to_elevation(ceiling_v, image_height))
    floor_error = jnp.abs(prediction.floor_elevation - row_to_elevation(floor_v, image_height))
    boundary = 0.5 * (jnp.mean(ceiling_error) + jnp.mean(floor_error))
    corner_target = reencode_corner_prob(corner_target, CORNER_LABEL_BASE, corner_base)
    corner = jnp.mean(optax.sigmoid_binary_cross_entropy(prediction.corner_logit, corner_target))
    return {"loss": boundary + corner, "boundary": boundary, "corner": corner}


# ----------------------------------------------------------------------------- augmentations

LABEL_KEYS = ("ceiling_v", "floor_v", "corner_target")


def roll_panorama(sample: dict[str, Array], shift: Array | int) -> dict[str, Array]:
    """Roll one sample by ``shift`` columns (a rotation of the room about the axis)."""
    rolled = {key: jnp.roll(sample[key], shift, axis=0) for key in LABEL_KEYS}
    return {**sample, **rolled, "image": jnp.roll(sample["image"], shift, axis=1)}


def flip_panorama(sample: dict[str, Array]) -> dict[str, Array]:
    """Mirror one sample left-right (the panorama of the room mirrored in y, see module docstring)."""
    flipped = {key: sample[key][::-1] for key in LABEL_KEYS}
    return {**sample, **flipped, "image": sample["image"][:, ::-1]}


def adjust_photometric(
    image: Float[Array, "H W 3"], gamma: Float[ArrayLike, ""], brightness: Float[ArrayLike, ""], greyscale: Bool[ArrayLike, ""]
) -> Float[Array, "H W 3"]:
    """Gamma, then a brightness factor, then optionally greyscale (Rec. 601 luma); clipped to [0, 1]."""
    image = jnp.clip(image, 0.0, 1.0) ** gamma * brightness
    luma = image @ jnp.array([0.299, 0.587, 0.114])
    image = jnp.where(greyscale, luma[..., None], image)
    return jnp.clip(image, 0.0, 1.0)


def augment_sample(key: PRNGKeyArray, sample: dict[str, Array], train_config: TrainConfig) -> dict[str, Array]:
    """Random roll, flip and photometric changes of one sample, labels kept exact."""
    k_roll, k_flip, k_gamma, k_bright, k_grey = jax.random.split(key, 5)
    width = sample["image"].shape[1]
    if train_config.roll:
        sample = roll_panorama(sample, jax.random.randint(k_roll, (), 0, width))
    if train_config.flip:
        flipped = flip_panorama(sample)
        do_flip = jax.random.bernoulli(k_flip)
        sample = jax.tree.map(lambda a, b: jnp.where(do_flip, a, b), flipped, sample)
    log_gamma = jnp.log(train_config.max_gamma)
    gamma = jnp.exp(jax.random.uniform(k_gamma, (), minval=-log_gamma, maxval=log_gamma))
    brightness = 1.0 + train_config.max_brightness * jax.random.uniform(k_bright, (), minval=-1.0, maxval=1.0)
    greyscale = jax.random.bernoulli(k_grey, train_config.greyscale_probability)
    return {**sample, "image": adjust_photometric(sample["image"], gamma, brightness, greyscale)}


def augment_batch(key: PRNGKeyArray, batch: dict[str, Array], train_config: TrainConfig) -> dict[str, Array]:
    """:func:`augment_sample` on every sample of a batch with independent keys."""
    keys = jax.random.split(key, batch["image"].shape[0])
    return jax.vmap(augment_sample, in_axes=(0, 0, None))(keys, batch, train_config)


# ----------------------------------------------------------------------------- steps


@functools.partial(nnx.jit, static_argnames=("train_config",))
def train_step(
    model: HorizonNet, optimizer: nnx.Optimizer, batch: dict[str, Array], key: PRNGKeyArray, train_config: TrainConfig
) -> dict[str, Array]:
    """One optimisation step on an augmented batch (model in train mode); returns the loss terms."""
    augment_key, dropout_key = jax.random.split(key)
    batch = augment_batch(augment_key, {k: batch[k] for k in ("image", *LABEL_KEYS)}, train_config)
    height = batch["image"].shape[1]

    def loss_fn(model):
        prediction = model(batch["image"], dropout_key=dropout_key)
        terms = horizonnet_loss(
            prediction, batch["ceiling_v"], batch["floor_v"], batch["corner_target"], height, model.config.corner_base
        )
        return terms["loss"], terms

    (_, terms), grads = nnx.value_and_grad(loss_fn, has_aux=True)(model)
    optimizer.update(model, grads)
    return terms


@nnx.jit
def eval_step(model: HorizonNet, batch: dict[str, Array]) -> tuple[dict[str, Array], BoundaryPrediction]:
    """Loss terms and raw predictions of a batch, no augmentation (call ``model.eval()`` first)."""
    prediction = model(batch["image"])
    height = batch["image"].shape[1]
    terms = horizonnet_loss(
        prediction, batch["ceiling_v"], batch["floor_v"], batch["corner_target"], height, model.config.corner_base
    )
    return terms, prediction


# ----------------------------------------------------------------------------- training loop


def step_key_root(seed: int) -> PRNGKeyArray:
    """Root of the per-step keys (``fold_in(root, step)``); "rbg" keys compile much faster on CPU."""
    return jax.random.key(seed, impl="rbg")


class TrainResult(NamedTuple):
    """What :func:`train` returns: the model (eval mode), the step reached, the per-step history."""

    model: HorizonNet
    step: int
    history: list[dict[str, float]]


def checkpoint_path(checkpoint_dir: str | pathlib.Path, step: int) -> pathlib.Path:
    return pathlib.Path(checkpoint_dir) / f"step_{step:08d}.safetensors"


def latest_checkpoint(checkpoint_dir: str | pathlib.Path) -> pathlib.Path | None:
    """The checkpoint with the highest step in ``checkpoint_dir``, or None."""
    files = sorted(pathlib.Path(checkpoint_dir).glob("step_*.safetensors"))
    return files[-1] if files else None


def _restore_or_init(config, train_config, checkpoint_dir, seed, resume, initial_weights):
    latest = latest_checkpoint(checkpoint_dir) if (resume and checkpoint_dir is not None) else None
    if latest is None:
        model = init_model(config, seed) if initial_weights is None else load_weights(initial_weights, config)
        return model, make_optimizer(model, train_config), 0
    model, optimizer, step = load_checkpoint(latest, lambda m, _: make_optimizer(m, train_config))
    if model.config != config:
        raise ValueError(f"{latest} was trained with {model.config}, not {config}; use another checkpoint_dir")
    return model, optimizer, step


def train(
    config: HorizonNetConfig,
    data: Iterator[dict] | Callable[[int], Iterator[dict]],
    steps: int,
    checkpoint_dir: str | pathlib.Path | None = None,
    *,
    train_config: TrainConfig = TrainConfig(),
    checkpoint_every: int = 500,
    keep_checkpoints: int = 3,
    validate: Callable[[HorizonNet, int], dict[str, float]] | None = None,
    validate_every: int = 0,
    seed: int = 0,
    resume: bool = True,
    progress: bool = True,
    initial_weights: str | pathlib.Path | None = None,
) -> TrainResult:
    """Train (or resume training) a :class:`HorizonNet` up to ``steps`` optimisation steps.

    Args:
        config: the architecture.
        data: batches ``{"image": (B, H, W, 3) float32 in [0, 1], "ceiling_v",
            "floor_v", "corner_target": (B, W)}``, rows in pixels of that image.
            Either an iterator or a function ``start_step -> iterator``; the
            function form lets a resumed run see exactly the batches it would
            have seen without the interruption.
        steps: total number of steps (a resumed run does ``steps - start``).
        checkpoint_dir: where ``step_XXXXXXXX.safetensors`` files go (None: no checkpoints).
        train_config: optimiser and augmentation settings (the same on resume).
        checkpoint_every: save every that many steps, and at the end.
        keep_checkpoints: how many recent checkpoints to keep.
        validate: ``(model in eval mode, step) -> metrics``, called every
            ``validate_every`` steps (0: never) and at the end; metrics go to the history.
        seed: initialisation and per-step augmentation / dropout keys.
        resume: continue from the latest checkpoint in ``checkpoint_dir`` if any.
        progress: show a tqdm bar with the loss and images per second.
        initial_weights: a model file to start from instead of a random
            initialisation (:func:`~ncjax._checkpoint.load_weights`; a fresh
            optimizer, steps counted from 0). A checkpoint to resume wins.

    Returns:
        :class:`TrainResult` with the model in eval mode.
    """
    from tqdm.auto import tqdm

    model, optimizer, start = _restore_or_init(config, train_config, checkpoint_dir, seed, resume, initial_weights)
    model.train()
    iterator = data(start) if callable(data) else data
    base_key = step_key_root(seed)
    history: list[dict[str, float]] = []

    def save(step):
        if checkpoint_dir is None:
            return
        save_checkpoint(
            checkpoint_path(checkpoint_dir, step), model, optimizer, step=step, train_config_json=train_config.to_json()
        )
        for old in sorted(pathlib.Path(checkpoint_dir).glob("step_*.safetensors"))[:-keep_checkpoints]:
            old.unlink()

    def run_validation(step):
        model.eval()
        metrics = validate(model, step)
        model.train()
        history.append({"step": step, **{f"val_{k}": float(v) for k, v in metrics.items()}})
        return metrics

    bar = tqdm(range(start, steps), initial=start, total=steps, disable=not progress, desc="train")
    tick, images = time.perf_counter(), 0
    for step in bar:
        batch = next(iterator)
        terms = train_step(model, optimizer, batch, jax.random.fold_in(base_key, step), train_config)
        terms = {k: float(v) for k, v in terms.items()}
        history.append({"step": step + 1, **terms})
        images += batch["image"].shape[0]
        elapsed = time.perf_counter() - tick
        bar.set_postfix(loss=f"{terms['loss']:.4f}", img_s=f"{images / max(elapsed, 1e-9):.1f}")
        if step == start:  # do not count compilation in the throughput
            tick, images = time.perf_counter(), 0
        if checkpoint_every and (step + 1) % checkpoint_every == 0:
            save(step + 1)
        if validate is not None and validate_every and (step + 1) % validate_every == 0:
            metrics = run_validation(step + 1)
            bar.write(f"step {step + 1}: " + ", ".join(f"{k} {float(v):.4g}" for k, v in metrics.items()))
    if steps > start:
        save(steps)
        if validate is not None and not (validate_every and steps % validate_every == 0):
            run_validation(steps)
    model.eval()
    return TrainResult(model, max(start, steps), history)


# ----------------------------------------------------------------------------- stand-in data


def paint_panorama(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    wall_index: Array,
    height: int,
    colours: Float[Array, "3 3"],
) -> Float[Array, "H W 3"]:
    """A flat-shaded panorama: ceiling colour above ``ceiling_v``, walls between, floor below.

    Pixel row ``r`` covers ``[r - 0.5, r + 0.5]`` (DESIGN.md pixel centres), and
    the boundary pixels get the covered fractions (sub-pixel labels). Walls
    alternate between two shades by index so that corners are visible.
    """
    rows = jnp.arange(height, dtype=ceiling_v.dtype)[:, None]
    above_ceiling = jnp.clip(ceiling_v[None, :] - (rows - 0.5), 0.0, 1.0)
    below_floor = jnp.clip((rows + 0.5) - floor_v[None, :], 0.0, 1.0)
    shade = jnp.where(wall_index % 2 == 0, 1.0, 0.65)[None, :, None]
    wall = 1.0 - above_ceiling - below_floor
    return (
        above_ceiling[..., None] * colours[0] + wall[..., None] * colours[1] * shade + below_floor[..., None] * colours[2]
    )


@functools.partial(jax.jit, static_argnames=("batch_size", "height", "width"))
def painted_batch(key: PRNGKeyArray, batch_size: int, height: int, width: int) -> dict[str, Array]:
    """A batch of flat-coloured panoramas of random rooms with exact labels (a stand-in data source).

    Rooms come from :func:`ncjax.random_room` (mixed Manhattan / Atlanta) and
    labels from :func:`ncjax.room_labels`; the images are painted with
    :func:`paint_panorama` in random colours. Meant for tests and smoke runs
    until rendered data is wired in.
    """
    from ._rooms import random_room, room_labels

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
    order; :func:`~ncjax._dataset.labels_from_corners`), so no interpolation
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


def rendered_splits(
    seed: int,
    n: int,
    height: int,
    width: int,
    batch_size: int = 16,
    config: SynthConfig = SYNTH_COMMAND_CONFIG,
    progress: bool = True,
) -> dict[str, dict[str, np.ndarray]]:
    """The samples ``ncjax synth --n N --seed SEED`` would write, as :func:`load_split` arrays per split.

    Rendered in memory (the same rooms and pixels as the written files, in
    index order rather than name order), so a machine with a fast accelerator
    trains without writing and decoding thousands of files. Splits without
    samples are left out.
    """
    from tqdm.auto import tqdm

    per_split: dict[str, list[dict[str, np.ndarray]]] = {split: [] for split in SPLITS}
    with tqdm(total=n, desc=f"render seed {seed}", disable=not progress) as bar:
        for index, scene, rendering, labels in rendered_samples(n, seed, config, batch_size, bar.update):
            mask = np.asarray(labels.corner_mask)
            arrays = network_arrays(
                rendering_rgb8(rendering), float(scene.room.rc), np.asarray(labels.ceiling_corners)[mask],
                np.asarray(labels.floor_corners)[mask], height, width,
            )
            per_split[split_of(index, seed)].append(arrays)
    return {
        split: {key: np.stack([a[key] for a in samples]) for key in samples[0]}
        for split, samples in per_split.items() if samples
    }


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
    """``(seed, n)`` of a ``synth:SEED:N`` data source, None for a folder path.

    Raises:
        ValueError: ``synth:`` followed by anything but two integers, N >= 1.
    """
    if not source.startswith("synth:"):
        return None
    parts = source.split(":")
    if len(parts) != 3 or not all(p.lstrip("-").isdigit() for p in parts[1:]) or int(parts[2]) < 1:
        raise ValueError(f"data source {source!r}: expected synth:SEED:N with integers SEED and N >= 1")
    return int(parts[1]), int(parts[2])


def training_data(
    sources: list[str], height: int, width: int, validation_limit: int | None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Train and validation arrays pooled, in the given order, from dataset folders and ``synth:SEED:N`` renders.

    A ``synth:SEED:N`` source is rendered in memory (:func:`rendered_splits`);
    validation takes the first ``validation_limit`` images of the pooled valid
    splits (None: all).
    """
    synth_sources = [parse_synth_source(source) for source in sources]  # malformed ones fail before any work
    pooled: dict[str, list[dict[str, np.ndarray]]] = {"train": [], "valid": []}
    for source, synth in zip(sources, synth_sources):
        if synth is None:
            for split in pooled:
                pooled[split].append(load_split(source, split, height, width, limit=validation_limit if split == "valid" else None))
        else:
            rendered = rendered_splits(*synth, height, width)
            for split in pooled:
                if split not in rendered:
                    raise ValueError(f"data source {source!r} has no {split} samples; render more (N)")
                pooled[split].append(rendered[split])
    train_arrays, valid = ({key: np.concatenate([a[key] for a in parts]) for key in parts[0]} for parts in pooled.values())
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


def evaluate_arrays(model: HorizonNet, arrays: dict[str, np.ndarray], batch_size: int = 8, views: int = 1) -> dict[str, float]:
    """Table netcorExp's row (:func:`~ncjax.network_table`) of a model on :func:`load_split` arrays.

    The corner output is compared in the labels' ``0.96**d`` encoding whatever
    the model's ``corner_base`` (:func:`~ncjax._rooms.reencode_corner_prob`).

    ``views``: the network's output averaged over rolled and mirrored views
    (:func:`~ncjax._network.predict_views`); 1 is the network alone.
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
    ceiling_v, floor_v, corner_prob = (np.concatenate(parts) for parts in zip(*outputs))
    corner_prob = reencode_corner_prob(corner_prob, model.config.corner_base, CORNER_LABEL_BASE)
    table = network_table(
        ceiling_v, floor_v, corner_prob, arrays["ceiling_v"], arrays["floor_v"], arrays["corner_target"]
    )
    return {key: float(value) for key, value in table.items()}


_forward = nnx.jit(predict_views, static_argnames=("views",))


# ----------------------------------------------------------------------------- command line


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``ncjax train``."""
    parser.add_argument(
        "--data", nargs="+", default=["painted"],
        help="dataset folders (ncjax synth or the authors') or synth:SEED:N (the N rooms `ncjax synth --seed SEED` "
        "writes, rendered in memory); their splits are pooled, validation takes the first --validation-limit "
        "images of the pool. Or 'painted'",
    )
    parser.add_argument("--preset", default="compact", help="paper, resnet18, compact or compact1024")
    parser.add_argument(
        "--corner-base", type=float,
        help="the corner output's encoding base**d (default: the preset's, HorizonNet's 0.96)",
    )
    parser.add_argument(
        "--init-from", help="start from this model file's weights (fine-tuning) when no checkpoint is resumed"
    )
    parser.add_argument("--steps", type=int, default=1000, help="total optimisation steps (a resumed run does the rest)")
    parser.add_argument("--batch-size", type=int, default=4)
    parser.add_argument("--checkpoint-dir", default="checkpoints/horizonnet")
    parser.add_argument("--checkpoint-every", type=int, default=250)
    parser.add_argument("--validate-every", type=int, default=500, help="steps between validations (0: only at the end)")
    parser.add_argument("--validation-limit", type=int, default=64, help="validation images (the 'valid' split)")
    parser.add_argument("--learning-rate", type=float, default=TrainConfig.peak_learning_rate)
    parser.add_argument("--warmup-steps", type=int, default=TrainConfig.warmup_steps)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-resume", action="store_true", help="start afresh even if checkpoints exist")
    parser.add_argument("--history", help="write the loss and validation history to this json file")
    parser.add_argument("--export", help="also save the final weights (model only) to this .safetensors file")


def run_train(args: argparse.Namespace) -> int:
    """``ncjax train``: train (or resume) a preset on a dataset folder or the painted stand-in data."""
    if args.steps < 1 or args.batch_size < 1:
        raise ValueError(f"--steps and --batch-size must be positive, got {args.steps} and {args.batch_size}")
    config = HorizonNetConfig.preset(args.preset)
    if args.corner_base is not None:
        config = dataclasses.replace(config, corner_base=args.corner_base)
    if args.init_from is not None:
        check_warm_start(args.init_from, config)  # a wrong file fails here, before the data is read
    height, width = config.input_height, config.input_width
    train_config = TrainConfig(
        peak_learning_rate=args.learning_rate, warmup_steps=args.warmup_steps, total_steps=args.steps
    )
    validate = None
    if args.data == ["painted"]:
        data = painted_batches(args.seed, args.batch_size, height, width)
    else:
        train_arrays, valid = training_data(args.data, height, width, args.validation_limit)
        data = folder_batches(train_arrays, args.batch_size, args.seed)
        validate = lambda model, step: evaluate_arrays(model, valid)  # noqa: E731
    result = train(
        config,
        data,
        args.steps,
        args.checkpoint_dir,
        train_config=train_config,
        checkpoint_every=args.checkpoint_every,
        validate=validate,
        validate_every=args.validate_every,
        seed=args.seed,
        resume=not args.no_resume,
        initial_weights=args.init_from,
    )
    losses = [h["loss"] for h in result.history if "loss" in h]
    if losses:
        print(f"step {result.step}: mean loss of the last 20 steps {np.mean(losses[-20:]):.4f}")
    for record in (h for h in result.history if "val_pe_mean" in h):
        print(
            f"step {record['step']}: valid PE {record['val_pe_mean']:.2f} px, corner precision "
            f"{record['val_precision']:.3f}, recall {record['val_recall']:.3f}"
        )
    if args.history:
        pathlib.Path(args.history).write_text(json.dumps(result.history) + "\n")
    if args.export:
        from ._checkpoint import save_model

        save_model(result.model, args.export)
        print(f"saved the model to {args.export}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone ``ncjax train`` (same as the console script's sub-command)."""
    parser = argparse.ArgumentParser(prog="ncjax train", description="Train Non-central HorizonNet.")
    add_train_arguments(parser)
    return run_train(parser.parse_args(argv))
