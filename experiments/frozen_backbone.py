"""The layout network's head trained on a frozen backbone: training within reach of 2 CPU cores.

A whole ``lite0-1024`` training step runs at 0.28 images/s on 2 CPU cores (experiments/RESULTS.md): the
backbone's backward pass is most of it. A frozen backbone's feature maps do not change while the rest
trains, so this script computes them once per rendered room, through one random camera of the training
augmentation (roll, flip, exposure, white balance, blur, noise, seams, bands, JPEG: ``ncjax train``'s), keeps
them in ``experiments/out/frozen_<backbone>_<kind>_<seed>_<n>.npz`` (float16), and trains the head (height
compression, LSTM, linear head) on them, each epoch's maps rolled by a random multiple of 32 columns (the
backbone's wrap-around padding makes that exact). About 13 images/s on 2 cores; rendering runs about 6 rooms/s,
the augmentation and the backbone's forward pass, once per room, 0.3 s.

``--backbone imagenet`` freezes the ImageNet weights as they ship (the shipped model's backbone was adapted to
the renders at a tenth of the learning rate); ``--backbone shipped`` freezes the fine-tuned backbone of the
model ``--init-head`` names. The head starts from ``--init-head``'s (the shipped model by default). With
``--deepest-stages-scale S`` (not 0) the backbone's stages after its stride-16 map (Lite0's last two, three
quarters of its weights) train too, their updates scaled by ``S``, on the kept stride-16 maps: about 2-2.7
images/s. Training checkpoints (weights and optimizer, ``--checkpoint``) are written after every epoch and
when ``--time-budget`` runs out; the same command resumes from the last one. Per epoch it prints the mean loss
and, on the first ``--validation-limit`` valid rooms, the boundary error (PE, px of the 1024-wide image) and
corner P / R. ``--seed`` draws the batch order and dropout (the rooms' maps stay the same): heads of 8 seeds on the
same rooms read the photographs' mean floor within 0.1-0.4 px of one another, the rooms drawn move it about a pixel
(experiments/RESULTS.md). The final weights go to ``--export`` (float16), a model file ``--model`` of
``benchmarks/real_panoramas.py``, ``benchmarks/central_layouts.py`` and ``experiments/network_table.py``
takes. ``--room FIELD=LOW:HIGH`` renders every source's rooms with that ``RoomConfig`` range instead (the capture
geometry of photographs: ``experiments/capture_geometry.py``), ``--scene FIELD=P`` with that ``SceneConfig``
probability (``furniture_probability=0``: empty rooms); ``--statistics-noise P`` moves the maps' per-image
channel statistics at random while the head trains (:func:`perturbed_statistics`).

    uv run python experiments/frozen_backbone.py --data synth-decor-home:601:500 synth-decor-open:602:500 \\
        --backbone imagenet --epochs 8 --export experiments/out/frozen_imagenet.safetensors
"""

from __future__ import annotations

import argparse
import functools
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from tqdm import tqdm

from ncjax.evaluation.network_metrics import network_table
from ncjax.network.checkpoint import load_checkpoint, load_model, save_checkpoint, save_model
from ncjax.network.efficientnet import FEATURE_STRIDES
from ncjax.network.model import HorizonNet, prediction_to_rows, use_imagenet_backbone
from ncjax.pipeline.corners import CORNER_LABEL_BASE
from ncjax.synth.labels import reencode_corner_prob
from ncjax.training.data import SYNTH_SOURCES, parse_synth_source, rendered_splits
from ncjax.training.loop import (
    LABEL_KEYS,
    TrainConfig,
    adamw_transform,
    augment_batch,
    horizonnet_loss,
    set_train_mode,
)

from common import room_ranges, scene_probabilities, source_config

OUT = pathlib.Path(__file__).parent / "out"
HEIGHT, WIDTH = 512, 1024
# the backbone's coarsest map: a roll by a multiple of its stride rolls every map by whole columns
COARSEST_STRIDE = max(FEATURE_STRIDES)
BATCH = 8
HEAD = nnx.All(nnx.Param, nnx.Not(nnx.PathContains("backbone")))  # what trains by default


def deepest_stages(model: HorizonNet) -> range:
    """Indices of the backbone's stages between its stride-16 and stride-32 maps (Lite0's 5 and 6)."""
    previous, last = model.backbone.config.feature_stages()[-2:]
    return range(previous + 1, last + 1)


def trainable(model: HorizonNet, deepest: bool) -> nnx.filterlib.Filter:
    """The head's parameters, and with ``deepest`` those of :func:`deepest_stages` too."""
    if not deepest:
        return HEAD
    stages = deepest_stages(model)

    def in_deepest_stages(path, _):
        return path[:2] == ("backbone", "stages") and path[2] in stages

    return nnx.All(nnx.Param, nnx.Any(nnx.Not(nnx.PathContains("backbone")), in_deepest_stages))


def head_inputs(model: HorizonNet, maps: list[jax.Array], deepest: bool) -> list[jax.Array]:
    """The kept maps as float32 for the head; with ``deepest`` the stride-32 map recomputed from the stride-16 one by
    :func:`deepest_stages` (the kept one is what the frozen backbone gave)."""
    maps = [m.astype(jnp.float32) for m in maps]
    if not deepest:
        return maps
    x = maps[-2]
    for index in deepest_stages(model):
        x = model.backbone.stage(index, x)
    return [*maps[:-1], x]


def frozen_model(backbone: str, init_head: str) -> HorizonNet:
    """``init_head``'s model, its backbone the ImageNet weights (``"imagenet"``) or its own (``"shipped"``)."""
    model = load_model(init_head)
    if backbone == "imagenet":
        use_imagenet_backbone(model)
    return model


@nnx.jit
def _features(model: HorizonNet, images: jax.Array) -> list[jax.Array]:
    return [f.astype(jnp.float16) for f in model.backbone_features(images)]


@jax.jit
def _augmented(key: jax.Array, batch: dict[str, jax.Array]) -> dict[str, jax.Array]:
    return augment_batch(key, batch, TrainConfig())


def cached_features(
    source: str,
    backbone: str,
    model: HorizonNet,
    rooms: dict[str, tuple[float, float]],
    scene: dict[str, float] | None = None,
) -> dict[str, dict[str, np.ndarray]]:
    """Per split (train, valid), the frozen backbone's maps (``map0``..``map3``, float16) of ``source``'s rooms (their
    ``RoomConfig`` ranges replaced by ``rooms``, their ``SceneConfig`` probabilities by ``scene``) through one random
    training camera each, and their labels; computed once, then read from the cache."""
    kind = source.split(":")[0]
    seed, count = parse_synth_source(source)
    config = source_config(kind, rooms, scene)
    changed = "".join(f"_{field.removesuffix('_range')}{low:g}-{high:g}" for field, (low, high) in rooms.items())
    changed += "".join(f"_{field.removesuffix('_probability')}{p:g}" for field, p in (scene or {}).items())
    path = OUT / f"frozen_{backbone}_{kind}_{seed}_{count}{changed}.npz"
    if path.exists():
        with np.load(path) as stored:
            splits = {name.split("/")[0] for name in stored.files}
            return {
                split: {n.split("/")[1]: stored[n] for n in stored.files if n.startswith(split)} for split in splits
            }
    rendered = rendered_splits(seed, count, HEIGHT, WIDTH, config=config)
    result = {}
    for split in ("train", "valid"):
        arrays, parts = rendered[split], []
        for start in tqdm(range(0, len(arrays["image"]), BATCH), desc=f"features {kind}:{seed} {split}"):
            batch = {key: jnp.asarray(arrays[key][start : start + BATCH]) for key in LABEL_KEYS}
            batch["image"] = jnp.asarray(arrays["image"][start : start + BATCH], jnp.float32) / 255.0
            batch = _augmented(jax.random.fold_in(jax.random.key(seed), start), batch)
            maps = _features(model, batch["image"])
            parts.append(
                {
                    **{f"map{i}": np.asarray(m) for i, m in enumerate(maps)},
                    **{k: np.asarray(batch[k]) for k in LABEL_KEYS},
                }
            )
        result[split] = {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    OUT.mkdir(exist_ok=True)
    temporary = path.with_suffix(".tmp.npz")
    np.savez(
        temporary, **{f"{split}/{key}": value for split, arrays in result.items() for key, value in arrays.items()}
    )
    temporary.replace(path)
    return result


def trains_deepest_stages(train_config: TrainConfig) -> bool:
    """Whether :func:`deepest_stages` train (a backbone learning-rate scale other than 0)."""
    return train_config.backbone_learning_rate_scale > 0


def head_training(peak: float, total_steps: int, warmup: int, backbone_scale: float = 0.0) -> TrainConfig:
    """``ncjax train``'s settings; a backbone scale of 0 freezes the whole backbone (eval mode, no updates), any
    other trains its deepest stages in train mode with updates scaled by it."""
    return TrainConfig(
        peak_learning_rate=peak,
        warmup_steps=warmup,
        total_steps=total_steps,
        backbone_learning_rate_scale=backbone_scale,
    )


def head_optimizer(model: HorizonNet, train_config: TrainConfig) -> nnx.Optimizer:
    """``ncjax train``'s AdamW (warm-up, cosine, weight decay, clipping) on the head's parameters (and the
    deepest stages' where the backbone's scale is not 0)."""
    return nnx.Optimizer(
        model, adamw_transform(train_config), wrt=trainable(model, trains_deepest_stages(train_config))
    )


def perturbed_statistics(key: jax.Array, maps: list[jax.Array], probability: float) -> list[jax.Array]:
    """Each map's per-image channel means and standard deviations moved at random, with ``probability`` per map:
    each by a normal draw scaled by that statistic's spread over the batch (DSU: Li et al. 2022, "Uncertainty
    modeling for out-of-distribution generalization"). A photograph's features differ from a render's most in
    such statistics if the head, taught to ignore them, reads photographs better."""
    perturbed = []
    for index, features in enumerate(maps):
        apply_key, mean_key, std_key = jax.random.split(jax.random.fold_in(key, index), 3)
        mean = jnp.mean(features, axis=(1, 2), keepdims=True)
        std = jnp.sqrt(jnp.var(features, axis=(1, 2), keepdims=True) + 1e-6)
        new_mean = mean + jax.random.normal(mean_key, mean.shape) * jnp.std(mean, axis=0, keepdims=True)
        new_std = std + jax.random.normal(std_key, std.shape) * jnp.std(std, axis=0, keepdims=True)
        moved = (features - mean) / std * new_std + new_mean
        perturbed.append(jnp.where(jax.random.uniform(apply_key) < probability, moved, features))
    return perturbed


def _rolled(maps: list[jax.Array], labels: list[jax.Array], shift: jax.Array):
    """Maps and labels rolled by ``shift`` coarsest columns (``shift * 32`` image columns)."""
    maps = [jnp.roll(m, shift * (COARSEST_STRIDE // s), axis=2) for m, s in zip(maps, FEATURE_STRIDES, strict=True)]
    return maps, [jnp.roll(label, shift * COARSEST_STRIDE, axis=1) for label in labels]


@functools.partial(nnx.jit, static_argnames=("deepest", "statistics_noise"))
def train_step(model, optimizer, maps, labels, key, deepest=False, statistics_noise=0.0):
    roll_key, dropout_key = jax.random.split(key)
    maps, labels = _rolled(maps, labels, jax.random.randint(roll_key, (), 0, WIDTH // COARSEST_STRIDE))

    def loss_fn(model):
        inputs = head_inputs(model, maps, deepest)
        if statistics_noise > 0:
            inputs = perturbed_statistics(jax.random.fold_in(key, 1), inputs, statistics_noise)
        features = model.compressed_columns(inputs, WIDTH)
        prediction = model.sequence_head(features, dropout_key=dropout_key)
        return horizonnet_loss(prediction, *labels, HEIGHT, model.config.corner_base)["loss"]

    loss, grads = nnx.value_and_grad(loss_fn, argnums=nnx.DiffState(0, trainable(model, deepest)))(model)
    optimizer.update(model, grads)
    return loss


@functools.partial(nnx.jit, static_argnames="deepest")
def _predict(model, maps, deepest=False):
    return model.sequence_head(model.compressed_columns(head_inputs(model, maps, deepest), WIDTH))


def validate(model: HorizonNet, arrays: dict[str, np.ndarray], train_config: TrainConfig) -> dict[str, float]:
    """Table netcorExp's PE and corner P / R of the head on cached valid maps (1 view); the model is left in
    ``train_config``'s train mode."""
    model.eval()
    rows = []
    for start in range(0, len(arrays["ceiling_v"]), BATCH):
        maps = [jnp.asarray(arrays[f"map{i}"][start : start + BATCH]) for i in range(4)]
        prediction = _predict(model, maps, trains_deepest_stages(train_config))
        rows.append([np.asarray(r) for r in prediction_to_rows(prediction, HEIGHT, WIDTH)])
    ceiling_v, floor_v, corner_prob = (np.concatenate(parts) for parts in zip(*rows, strict=True))
    corner_prob = reencode_corner_prob(corner_prob, model.config.corner_base, CORNER_LABEL_BASE)
    table = network_table(ceiling_v, floor_v, corner_prob, *(arrays[k] for k in LABEL_KEYS))
    set_train_mode(model, train_config)
    return {key: float(value) for key, value in table.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", nargs="+", required=True, help="rendered sources KIND:SEED:N (ncjax train's)")
    parser.add_argument("--backbone", choices=("imagenet", "shipped"), default="imagenet")
    parser.add_argument("--init-head", default="lite0-1024", help="model whose head (and backbone: shipped) starts")
    parser.add_argument("--epochs", type=int, default=8)
    parser.add_argument("--peak-learning-rate", type=float, default=3e-4)
    parser.add_argument("--warmup-steps", type=int, default=50)
    parser.add_argument(
        "--deepest-stages-scale",
        type=float,
        default=0.0,
        help="0: the whole backbone frozen; else its stages after the stride-16 map train too, from the kept "
        "stride-16 maps, their updates scaled by this",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="the head's batch order and dropout (the rooms' features stay the same): heads of several seeds "
        "show how far a head moves by chance",
    )
    parser.add_argument(
        "--statistics-noise",
        type=float,
        default=0.0,
        help="probability per map and step of moving its per-image channel statistics at random (DSU); 0: never",
    )
    parser.add_argument(
        "--room",
        action="append",
        default=[],
        metavar="FIELD=LOW:HIGH",
        help="a RoomConfig range for every source's rooms (repeatable): camera_height_range=1.35:1.75, ...",
    )
    parser.add_argument(
        "--scene",
        action="append",
        default=[],
        metavar="FIELD=P",
        help="a SceneConfig probability for every source's rooms (repeatable): furniture_probability=0 (empty "
        "rooms), ...",
    )
    parser.add_argument("--time-budget", type=float, default=float("inf"), help="seconds of training, then stop")
    parser.add_argument("--validation-limit", type=int, default=64)
    parser.add_argument("--checkpoint", type=pathlib.Path, help="default: next to --export")
    parser.add_argument("--export", type=pathlib.Path, required=True, help="final weights (float16 model file)")
    args = parser.parse_args(argv)
    try:
        for source in args.data:
            if parse_synth_source(source) is None:
                raise ValueError(f"{source!r} is not a rendered source KIND:SEED:N ({', '.join(SYNTH_SOURCES)})")
        rooms, scene = room_ranges(args.room), scene_probabilities(args.scene)
        for source in args.data:
            source_config(source.split(":")[0], rooms, scene)
        model = frozen_model(args.backbone, args.init_head)
    except (ValueError, FileNotFoundError) as error:
        print(f"frozen_backbone: error: {error}", file=sys.stderr)
        return 2
    checkpoint = args.checkpoint or args.export.with_suffix(".checkpoint.safetensors")

    model.eval()
    cached = [cached_features(source, args.backbone, model, rooms, scene) for source in args.data]
    train_arrays, valid = (
        {k: np.concatenate([c[split][k] for c in cached]) for k in cached[0][split]} for split in ("train", "valid")
    )
    valid = {key: value[: args.validation_limit] for key, value in valid.items()}
    del cached
    count = len(train_arrays["ceiling_v"])
    steps_per_epoch = count // BATCH
    total = args.epochs * steps_per_epoch

    train_config = head_training(args.peak_learning_rate, total, args.warmup_steps, args.deepest_stages_scale)
    deepest = trains_deepest_stages(train_config)

    def build(model, _=None):
        return head_optimizer(model, train_config)

    if checkpoint.exists():
        model, optimizer, step = load_checkpoint(checkpoint, build)
        print(f"resumed from {checkpoint} at step {step} of {total}")
    else:
        optimizer, step = build(model), 0
        print(
            f"{count} training rooms, {total} steps of {BATCH}; before training: {validate(model, valid, train_config)}"
        )
    set_train_mode(model, train_config)  # a frozen backbone stays in eval mode, its batch statistics too
    dropout_key = jax.random.key(1 + args.seed)
    start = time.perf_counter()
    while step < total:
        epoch, losses = step // steps_per_epoch, []
        order = np.random.default_rng((args.seed, epoch)).permutation(count)
        for index in tqdm(range(step % steps_per_epoch, steps_per_epoch), desc=f"epoch {epoch + 1}/{args.epochs}"):
            chosen = np.sort(order[index * BATCH : (index + 1) * BATCH])
            maps = [jnp.asarray(train_arrays[f"map{i}"][chosen]) for i in range(4)]
            labels = [jnp.asarray(train_arrays[k][chosen]) for k in LABEL_KEYS]
            losses.append(
                float(
                    train_step(
                        model,
                        optimizer,
                        maps,
                        labels,
                        jax.random.fold_in(dropout_key, step),
                        deepest,
                        args.statistics_noise,
                    )
                )
            )
            step += 1
            if time.perf_counter() - start > args.time_budget:
                break
        save_checkpoint(checkpoint, model, optimizer, step=step)
        print(json.dumps({"step": step, "loss": float(np.mean(losses)), **validate(model, valid, train_config)}))
        if time.perf_counter() - start > args.time_budget:
            print(f"time budget spent at step {step} of {total}; the same command resumes from {checkpoint}")
            return 0
    model.eval()
    save_model(model, args.export, "float16")
    print(f"wrote {args.export}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
