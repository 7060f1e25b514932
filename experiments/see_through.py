"""Can the network's features tell the columns whose floor row sees through an opening, and do its rows gain?

On the photographs the floor rows run through doorways into the next room; there the ceiling row, through the
panorama's median ceiling-to-floor ratio, gives the wall (``experiments/boundary_fusion.py``). Taking the ceiling's
distance wherever it is nearer and nearer the label is worth most of a perfect per-column choice (raw 3D IoU 0.696 of
0.713, against 0.652); taking it wherever it is nearer, without the label, is worth nothing, as fans and headers
pull the ceiling rows in. This asks whether a column classifier can tell the openings.

It renders training-like rooms (``--data`` sources of ``ncjax train``, each through one random camera of the training
augmentation), labels each column by what its rendering shows just above its true floor line (an opening: a door or
what is seen through one, ``Semantic.OPENING``; ``experiments/doorway_rows.py``'s classes), and trains a small
circular 1-D convolution on the shipped model's frozen column features (backbone and height compressions, the
LSTM's input) to predict it (cross-entropy, the openings weighted up to half the loss). On held-out renders it
prints precision and recall; on each labelled photograph of ``--photos`` (4 views: 2 rolls, each mirrored) it
takes the ceiling's distance where the classifier says opening (probability over each of ``--thresholds``) and the
ceiling's wall is nearer than the floor's, and prints the floor rows' error and the raw 3D IoU of their prism, as
``experiments/boundary_fusion.py``.

    uv run python experiments/see_through.py --photos DIR [--data synth-decor-open:501:200 ...] [--epochs 30]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from boundary_fusion import row_distances
from doorway_rows import column_classes
from flax import nnx
from tqdm import tqdm

import ncjax
from ncjax.evaluation.panorama_labels import (
    central_camera,
    elevation_rows,
    labelled_image_paths,
    load_panorama,
    read_labelled_image,
)
from ncjax.evaluation.panorama_scores import raw_layout_ious, row_error
from ncjax.network.denoise import denoise_for_network
from ncjax.network.predict import default_model
from ncjax.synth.dataset import rendered_samples
from ncjax.synth.render import Semantic
from ncjax.training.data import SYNTH_SOURCES, parse_synth_source

from common import each_view, photo_like_image

OUT = Path(__file__).parent / "out"
DEFAULT_DATA = ("synth-decor-open:501:200", "synth-decor-home:502:200", "synth-decor-hall:503:100")
VALID_SHARE = 0.15  # of each source's rooms, the last ones


class ColumnClassifier(nnx.Module):
    """Per LSTM position's column features, a logit for each of its ``step`` image columns: two circular
    convolutions over the positions (a doorway spans many)."""

    def __init__(self, features: int, step: int, rngs: nnx.Rngs, hidden: int = 64):
        self.first = nnx.Conv(features, hidden, kernel_size=(5,), padding="CIRCULAR", rngs=rngs)
        self.second = nnx.Conv(hidden, hidden, kernel_size=(9,), padding="CIRCULAR", rngs=rngs)
        self.out = nnx.Conv(hidden, step, kernel_size=(1,), rngs=rngs)

    def __call__(self, columns: jax.Array) -> jax.Array:
        hidden = nnx.relu(self.second(nnx.relu(self.first(columns))))
        logits = self.out(hidden)  # (B, S, step)
        return logits.reshape(logits.shape[0], -1)  # (B, S * step) = (B, W)


@nnx.jit
def column_features(model, images: jax.Array) -> jax.Array:
    """The shipped model's LSTM input for uint8 RGB images at its input size, as ``ncjax.predict_boundaries``
    prepares them."""
    return model.column_features(denoise_for_network(images.astype(jnp.float32) / 255.0))


def rendered_columns(source: str, model) -> tuple[np.ndarray, np.ndarray]:
    """``(features (N, S, F), opening (N, W))`` of a source's rooms through one random training camera each;
    computed once, then read from ``experiments/out``."""
    kind = source.split(":")[0]
    seed, count = parse_synth_source(source)
    path = OUT / f"see_through_{kind}_{seed}_{count}.npz"
    if path.exists():
        with np.load(path) as stored:
            return stored["features"], stored["labels"]
    features, labels = [], []
    for index, _scene, rendering, room in tqdm(
        rendered_samples(count, seed, SYNTH_SOURCES[kind]), total=count, desc=kind
    ):
        image = photo_like_image(seed, index, rendering)
        features.append(np.asarray(column_features(model, jnp.asarray(image[None])))[0])
        labels.append(column_classes(np.asarray(rendering.semantic), np.asarray(room.floor_v)) == Semantic.OPENING)
    OUT.mkdir(exist_ok=True)
    np.savez(path, features=np.stack(features), labels=np.stack(labels))
    return np.stack(features), np.stack(labels)


def train(features: np.ndarray, labels: np.ndarray, step: int, epochs: int) -> ColumnClassifier:
    """The classifier after ``epochs`` passes in batches of 16, each batch rolled by a random number of positions."""
    classifier = ColumnClassifier(features.shape[-1], step, nnx.Rngs(0))
    positive = float(labels.mean())
    weight = 0.5 / max(positive, 1e-3)  # openings up to half the loss
    optimizer = nnx.Optimizer(classifier, optax.adam(1e-3), wrt=nnx.Param)

    @nnx.jit
    def update(classifier, optimizer, x, y, shift):
        x, y = jnp.roll(x, shift, axis=1), jnp.roll(y, shift * step, axis=1)

        def loss_fn(classifier):
            logits = classifier(x)
            per_column = optax.sigmoid_binary_cross_entropy(logits, y)
            return jnp.mean(per_column * jnp.where(y > 0, weight, 1.0))

        loss, grads = nnx.value_and_grad(loss_fn)(classifier)
        optimizer.update(classifier, grads)
        return loss

    rng = np.random.default_rng(0)
    for epoch in range(epochs):
        order, losses = rng.permutation(len(features)), []
        for start in range(0, len(order) - 15, 16):
            chosen = order[start : start + 16]
            shift = int(rng.integers(features.shape[1]))
            x, y = jnp.asarray(features[chosen]), jnp.asarray(labels[chosen], jnp.float32)
            losses.append(float(update(classifier, optimizer, x, y, shift)))
        if epoch % 10 == 9 or epoch == epochs - 1:
            print(f"epoch {epoch + 1}: loss {np.mean(losses):.4f}")
    return classifier


def photograph_openings(classifier: ColumnClassifier, model, image: np.ndarray) -> np.ndarray:
    """Per column the opening probability, averaged over the image rolled by half a turn and each mirrored."""

    def read(view):
        return (jax.nn.sigmoid(classifier(column_features(model, jnp.asarray(view[None]))))[0],)

    return np.mean([probability for (probability,) in each_view(image, 2, read)], axis=0)


def fused_scores(panorama, ceiling_v: np.ndarray, floor_v: np.ndarray, opening: np.ndarray) -> tuple[float, ...]:
    """Floor error and raw 3D IoU of the network's rows and of the rows with the ceiling's distance taken in the
    ``opening`` columns where it is nearer, and the share of columns said opening and taken."""
    cam = central_camera(panorama.width, panorama.height)
    from_floor, from_ceiling, _ = row_distances(cam, ceiling_v, floor_v)
    through = opening & np.isfinite(from_ceiling) & (from_ceiling < from_floor)
    fused_v = elevation_rows(cam, -np.arctan(1.0 / np.where(through, from_ceiling, from_floor)))
    return (
        row_error(floor_v, panorama.floor_v),
        row_error(fused_v, panorama.floor_v),
        raw_layout_ious(panorama, ceiling_v, floor_v)[1],
        raw_layout_ious(panorama, ceiling_v, fused_v)[1],
        float(opening.mean()),
        float(through.mean()),
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=Path, required=True, help="folder of labelled panoramas")
    parser.add_argument("--data", nargs="+", default=list(DEFAULT_DATA), help="rendered sources KIND:SEED:N")
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument(
        "--thresholds", type=float, nargs="+", default=[0.5], help="opening probabilities that take the ceiling"
    )
    args = parser.parse_args(argv)
    model = default_model()
    train_parts, valid_parts = [], []
    for source in args.data:
        features, labels = rendered_columns(source, model)
        cut = int(round(len(features) * (1 - VALID_SHARE)))
        train_parts.append((features[:cut], labels[:cut]))
        valid_parts.append((features[cut:], labels[cut:]))
    features, labels = (np.concatenate(parts) for parts in zip(*train_parts, strict=True))
    print(f"{len(features)} training rooms, {labels.mean():.1%} of their columns openings")
    classifier = train(features, labels, model.config.step_cols, args.epochs)
    valid_features, valid_labels = (np.concatenate(parts) for parts in zip(*valid_parts, strict=True))
    probability = np.asarray(jax.nn.sigmoid(classifier(jnp.asarray(valid_features))))
    for threshold in args.thresholds:
        said = probability > threshold
        hits = np.sum(said & valid_labels)
        print(
            f"held-out renders ({len(valid_features)}), threshold {threshold}: openings {valid_labels.mean():.1%} of "
            f"the columns, said {said.mean():.1%}, precision {hits / max(said.sum(), 1):.2f}, recall "
            f"{hits / max(valid_labels.sum(), 1):.2f}"
        )
    photographs = []
    for image_path, label_path in labelled_image_paths(args.photos):
        image = read_labelled_image(image_path)
        rows = [np.asarray(r, np.float64) for r in ncjax.predict_boundaries(image, model)[:2]]
        photographs.append((load_panorama(image_path, label_path), rows, photograph_openings(classifier, model, image)))
    for threshold in args.thresholds:
        table = np.array(
            [fused_scores(panorama, *rows, openings > threshold) for panorama, rows, openings in photographs]
        )
        if threshold == args.thresholds[0]:
            print("| photograph | floor px | fused | raw 3D IoU | fused | said opening | ceiling taken |")
            print("| --- | --- | --- | --- | --- | --- | --- |")
            for (panorama, _, _), row in zip(photographs, table, strict=True):
                print(f"| {panorama.name} | " + " | ".join(f"{value:.3f}" for value in row) + " |")
        better, worse = np.sum(table[:, 3] > table[:, 2] + 1e-9), np.sum(table[:, 3] < table[:, 2] - 1e-9)
        print(
            f"threshold {threshold}: over {len(table)} photographs floor error {table[:, 0].mean():.1f} -> "
            f"{table[:, 1].mean():.1f} px, raw 3D IoU {table[:, 2].mean():.3f} -> {table[:, 3].mean():.3f} (better on "
            f"{better}, worse on {worse}); columns said opening {table[:, 4].mean():.1%}, their ceiling taken "
            f"{table[:, 5].mean():.1%}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
