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
  panorama, labels flipped with it (tested with :func:`ncjax.synth.room_labels`).
- photometric: a random camera's rendition of the image
  (:func:`ncjax.synth.augment.random_augment`: exposure, colour, blur, vignetting,
  noise, stitching seams, black bands at the poles, JPEG); labels unchanged (near a
  seam the image may move by a pixel or two, as in real stitching: the labels stay the scene's).

Randomness is a pure function of ``(seed, step)`` (augmentation and dropout
keys are ``fold_in(step_key_root(seed), step)``), so a run resumed from a checkpoint
continues the same trajectory bit for bit when the data does.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import pathlib
import time
from collections.abc import Callable, Iterator
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import nnx
from jaxtyping import Array, ArrayLike, Float, PRNGKeyArray

from ..geometry.camera import row_to_elevation
from ..network.checkpoint import load_checkpoint, load_weights, save_checkpoint
from ..network.model import BoundaryPrediction, HorizonNet, HorizonNetConfig, init_model
from ..pipeline.corners import CORNER_LABEL_BASE
from ..synth.augment import AugmentConfig, random_augment
from ..synth.labels import reencode_corner_prob

# ----------------------------------------------------------------------------- configuration


# Older photometric settings (gamma, brightness factor, greyscale), replaced by ``augment``: dropped when an
# older configuration is read, since the augmentation they drove is gone (training uses its caller's settings).
_REPLACED_FIELDS = ("max_gamma", "max_brightness", "greyscale_probability")


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
        backbone_learning_rate_scale: the backbone's learning rate relative to
            the rest of the network (its updates, weight decay included, are
            scaled by it); 0 freezes the backbone: its weights and its batch-norm
            statistics (the backbone stays in eval mode while the rest trains).
        head_learning_rate_scale: the same for the rest of the network, the part that reads the backbone's
            features (height compressions, LSTM and linear head); 0 freezes it, batch-norm statistics and
            dropout included, so that only the features adapt and the head reads them as it was trained to
            (a network fine-tuned whole on narrow rooms learns its head's sense of room size anew).
        roll, flip: random horizontal roll / left-right flip (labels follow).
        photometric: a random camera's rendition of each image (``augment``).
        augment: ranges and probabilities of the photometric and camera effects.
        micro_batches: each step's gradient summed over this many equal parts of its batch, one part after
            another: the memory of one part (a batch of 16 at 512 x 1024 does not fit 24 GB on a CPU; in 4 parts the
            whole run takes 12 GB), the same update but for the batch-norm statistics, which each part updates in
            turn.
    """

    peak_learning_rate: float = 1e-3
    warmup_steps: int = 200
    total_steps: int = 20_000
    final_learning_rate_fraction: float = 0.01
    weight_decay: float = 1e-4
    gradient_clip: float = 1.0
    backbone_learning_rate_scale: float = 1.0
    head_learning_rate_scale: float = 1.0
    roll: bool = True
    flip: bool = True
    photometric: bool = True
    augment: AugmentConfig = AugmentConfig()
    micro_batches: int = 1

    def __post_init__(self):
        if not self.backbone_learning_rate_scale >= 0.0:
            raise ValueError(f"backbone_learning_rate_scale must be >= 0, got {self.backbone_learning_rate_scale}")
        if not self.head_learning_rate_scale >= 0.0:
            raise ValueError(f"head_learning_rate_scale must be >= 0, got {self.head_learning_rate_scale}")
        if self.backbone_learning_rate_scale == 0 and self.head_learning_rate_scale == 0:
            raise ValueError("backbone_learning_rate_scale and head_learning_rate_scale are both 0: nothing trains")
        if self.micro_batches < 1:
            raise ValueError(f"micro_batches must be >= 1, got {self.micro_batches}")

    def to_json(self) -> str:
        return json.dumps(dataclasses.asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> TrainConfig:
        """The configuration :meth:`to_json` wrote, also an older one: missing fields take their defaults."""
        values = json.loads(text)
        for name in _REPLACED_FIELDS:
            values.pop(name, None)
        if "augment" in values:
            values["augment"] = AugmentConfig.from_dict(values["augment"])
        return cls(**values)


def make_optimizer(model: HorizonNet, train_config: TrainConfig) -> nnx.Optimizer:
    """AdamW with linear warm-up, cosine decay and global-norm gradient clipping.

    The backbone's updates are then scaled by ``train_config.backbone_learning_rate_scale`` and the rest's by
    ``train_config.head_learning_rate_scale`` (the clipping norm counts every gradient).

    Built in a jitted function, like :func:`~ncjax.network.model.init_model`, so that a
    fresh optimizer and one restored from a checkpoint have equal graph
    definitions (the jitted train step is then compiled once for both).
    """
    return _optimizer_builder(train_config)(model)


@functools.cache
def _optimizer_builder(train_config: TrainConfig):
    return nnx.jit(lambda model: _adamw(model, train_config))


def _adamw(model: HorizonNet, train_config: TrainConfig) -> nnx.Optimizer:
    return nnx.Optimizer(model, adamw_transform(train_config), wrt=nnx.Param)


def adamw_transform(train_config: TrainConfig) -> optax.GradientTransformation:
    """:func:`make_optimizer`'s update rule, for an optimizer of any part of the network (the backbone's updates,
    where its parameters are among those updated, scaled by ``backbone_learning_rate_scale``, the rest's by
    ``head_learning_rate_scale``)."""
    schedule = optax.warmup_cosine_decay_schedule(
        init_value=0.0,
        peak_value=train_config.peak_learning_rate,
        warmup_steps=train_config.warmup_steps,
        decay_steps=max(train_config.total_steps, train_config.warmup_steps + 1),
        end_value=train_config.peak_learning_rate * train_config.final_learning_rate_fraction,
    )
    return optax.chain(
        optax.clip_by_global_norm(train_config.gradient_clip),
        optax.adamw(schedule, weight_decay=train_config.weight_decay),
        optax.masked(optax.scale(train_config.backbone_learning_rate_scale), _backbone_mask),
        optax.masked(optax.scale(train_config.head_learning_rate_scale), _head_mask),
    )


def _backbone_mask(params):
    """True for the leaves of the backbone's parameters (state paths starting with ``backbone``)."""
    return jax.tree_util.tree_map_with_path(lambda path, _: path[0].key == "backbone", params)


def _head_mask(params):
    """True for the leaves of every parameter outside the backbone."""
    return jax.tree.map(lambda in_backbone: not in_backbone, _backbone_mask(params))


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


def augment_sample(key: PRNGKeyArray, sample: dict[str, Array], train_config: TrainConfig) -> dict[str, Array]:
    """Random roll, flip and camera effects (:func:`~ncjax.synth.augment.random_augment`) of one sample,
    labels kept exact."""
    k_roll, k_flip, k_photometric = jax.random.split(key, 3)
    width = sample["image"].shape[1]
    if train_config.roll:
        sample = roll_panorama(sample, jax.random.randint(k_roll, (), 0, width))
    if train_config.flip:
        flipped = flip_panorama(sample)
        do_flip = jax.random.bernoulli(k_flip)
        sample = jax.tree.map(lambda a, b: jnp.where(do_flip, a, b), flipped, sample)
    if train_config.photometric:
        sample = {**sample, "image": random_augment(k_photometric, sample["image"], train_config.augment)}
    return sample


def augment_batch(key: PRNGKeyArray, batch: dict[str, Array], train_config: TrainConfig) -> dict[str, Array]:
    """:func:`augment_sample` on every sample of a batch with independent keys."""
    keys = jax.random.split(key, batch["image"].shape[0])
    return jax.vmap(augment_sample, in_axes=(0, 0, None))(keys, batch, train_config)


# ----------------------------------------------------------------------------- steps


def set_train_mode(model: HorizonNet, train_config: TrainConfig) -> None:
    """Train mode, except for a frozen backbone or head (learning-rate scale 0), which stays in eval mode.

    Frozen, the pretrained features stay exactly those it was trained with: its batch-norm
    statistics do not drift to the renders' colours and textures. A frozen head keeps its statistics and
    runs without dropout, as it reads features at inference.
    """
    model.train()
    if train_config.backbone_learning_rate_scale == 0:
        model.backbone.eval()
    if train_config.head_learning_rate_scale == 0:  # everything outside the backbone, as the optimizer's mask
        model.eval()
        model.backbone.train()


@functools.partial(nnx.jit, static_argnames=("train_config",))
def train_step(
    model: HorizonNet, optimizer: nnx.Optimizer, batch: dict[str, Array], key: PRNGKeyArray, train_config: TrainConfig
) -> dict[str, Array]:
    """One optimisation step on an augmented batch (model in train mode); returns the loss terms.

    The gradient is the mean of those of ``train_config.micro_batches`` equal parts of the batch, taken one after
    another (a scan: one part's activations in memory at a time); the loss terms are the parts' means.
    """
    augment_key, dropout_key = jax.random.split(key)
    batch = augment_batch(augment_key, {k: batch[k] for k in ("image", *LABEL_KEYS)}, train_config)
    height = batch["image"].shape[1]
    parts = train_config.micro_batches
    if batch["image"].shape[0] % parts:
        raise ValueError(f"a batch of {batch['image'].shape[0]} does not split into {parts} equal micro-batches")
    graphdef, params, statistics = nnx.split(model, nnx.Param, ...)

    def part_loss(params, statistics, part, part_key):
        part_model = nnx.merge(graphdef, params, statistics, copy=True)  # fresh variables in this trace
        prediction = part_model(part["image"], dropout_key=part_key)
        terms = horizonnet_loss(
            prediction, part["ceiling_v"], part["floor_v"], part["corner_target"], height, model.config.corner_base
        )
        return terms["loss"], (terms, nnx.state(part_model, nnx.Not(nnx.Param)))

    if parts == 1:  # no loop: on a CPU a scan of one part makes the step a third slower
        (_, (terms, statistics)), gradient = jax.value_and_grad(part_loss, has_aux=True)(
            params, statistics, batch, dropout_key
        )
    else:

        def accumulate(carry, inputs):
            gradient_sum, statistics = carry
            (_, (terms, statistics)), gradient = jax.value_and_grad(part_loss, has_aux=True)(
                params, statistics, *inputs
            )
            return (jax.tree.map(jnp.add, gradient_sum, gradient), statistics), terms

        split = jax.tree.map(lambda x: x.reshape(parts, x.shape[0] // parts, *x.shape[1:]), batch)
        (gradient_sum, statistics), terms = jax.lax.scan(
            accumulate,
            (jax.tree.map(jnp.zeros_like, params), statistics),
            (split, jax.random.split(dropout_key, parts)),
        )
        gradient, terms = jax.tree.map(lambda g: g / parts, gradient_sum), jax.tree.map(jnp.mean, terms)
    nnx.update(model, statistics)
    optimizer.update(model, gradient)
    return terms


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


def remove_old_checkpoints(checkpoint_dir: str | pathlib.Path, keep: int) -> None:
    """Delete the checkpoints in ``checkpoint_dir`` but the ``keep`` with the highest steps."""
    for old in sorted(pathlib.Path(checkpoint_dir).glob("step_*.safetensors"))[:-keep]:
        old.unlink()


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
    time_budget: float | None = None,
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
            initialisation (:func:`~ncjax.network.checkpoint.load_weights`; a fresh
            optimizer, steps counted from 0). A checkpoint to resume wins.

    Returns:
        :class:`TrainResult` with the model in eval mode.
    """
    from tqdm.auto import tqdm

    deadline = None if time_budget is None else time.monotonic() + time_budget
    model, optimizer, start = _restore_or_init(config, train_config, checkpoint_dir, seed, resume, initial_weights)
    set_train_mode(model, train_config)
    iterator = data(start) if callable(data) else data
    base_key = step_key_root(seed)
    history: list[dict[str, float]] = []

    def save(step):
        if checkpoint_dir is None:
            return
        save_checkpoint(
            checkpoint_path(checkpoint_dir, step), model, optimizer, step=step, train_config_json=train_config.to_json()
        )
        remove_old_checkpoints(checkpoint_dir, keep_checkpoints)

    def run_validation(step):
        model.eval()
        metrics = validate(model, step)
        set_train_mode(model, train_config)
        history.append({"step": step, **{f"val_{k}": float(v) for k, v in metrics.items()}})
        return metrics

    bar = tqdm(range(start, steps), initial=start, total=steps, disable=not progress, desc="train")
    tick, images = time.perf_counter(), 0
    reached = start
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
        reached = step + 1
        if deadline is not None and time.monotonic() >= deadline and reached < steps:
            bar.write(f"time budget spent: stopping at step {reached} of {steps} (a rerun resumes from its checkpoint)")
            break
    bar.close()
    if reached > start:
        if not (checkpoint_every and reached % checkpoint_every == 0):
            save(reached)
        if validate is not None and not (validate_every and reached % validate_every == 0):
            run_validation(reached)
    model.eval()
    return TrainResult(model, reached, history)
