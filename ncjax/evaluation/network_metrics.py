"""Network metrics of the paper's Table netcorExp (Section "Ablation study: Non-central HorizonNet").

Boundary extraction: the pixel error (PE) per column between predicted and
true ceiling and floor rows. Rows are expressed in pixels of a 1024-wide
(512-row) panorama whatever the evaluated size, so figures compare with the
paper's 1024 x 512 images: a row error at width W is multiplied by 1024 / W.
Each image gets its mean error over its W columns and both boundaries; the
table reports the mean and standard deviation of that over the images.

Corner prediction: the paper compares the predicted corner probability with
the target ``0.96**d`` (d in columns to the nearest corner) through
precision, recall, accuracy and IoU without stating a threshold. Here both
are binarised at ``threshold`` (0.5 by default, i.e. a target column is
positive within ``d < 16.98`` columns of a corner, ``0.96**d > 0.5``) and
the counts are pooled over all columns of all images:

    precision = TP / (TP + FP), recall = TP / (TP + FN),
    accuracy = (TP + TN) / (TP + TN + FP + FN), IoU = TP / (TP + FP + FN).

An undefined ratio (0 / 0) is NaN.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

REFERENCE_WIDTH = 1024


def boundary_pixel_error(
    ceiling_v: Float[Array, " W"],
    floor_v: Float[Array, " W"],
    true_ceiling_v: Float[Array, " W"],
    true_floor_v: Float[Array, " W"],
) -> Float[Array, ""]:
    """Mean |row error| over the columns and both boundaries of one image, in 1024-wide pixels."""
    scale = REFERENCE_WIDTH / ceiling_v.shape[-1]
    error = jnp.concatenate([jnp.abs(ceiling_v - true_ceiling_v), jnp.abs(floor_v - true_floor_v)])
    return scale * jnp.mean(error)


def corner_confusion(
    corner_prob: Float[Array, " W"], corner_target: Float[Array, " W"], threshold: float = 0.5
) -> Int[Array, 4]:
    """Column counts ``(TP, FP, FN, TN)`` of one image, probability and target binarised at ``threshold``."""
    predicted, actual = corner_prob > threshold, corner_target > threshold
    counts = [predicted & actual, predicted & ~actual, ~predicted & actual, ~predicted & ~actual]
    return jnp.stack([jnp.sum(c) for c in counts]).astype(jnp.int32)


def _ratio(numerator, denominator):
    return jnp.where(denominator > 0, numerator / jnp.maximum(denominator, 1), jnp.nan)


def corner_scores(confusion: Int[Array, 4]) -> dict[str, Float[Array, ""]]:
    """Precision, recall, accuracy and IoU of pooled ``(TP, FP, FN, TN)`` counts."""
    tp, fp, fn, tn = (confusion[i].astype(jnp.float32) for i in range(4))
    return {
        "precision": _ratio(tp, tp + fp),
        "recall": _ratio(tp, tp + fn),
        "accuracy": _ratio(tp + tn, tp + tn + fp + fn),
        "iou": _ratio(tp, tp + fp + fn),
    }


@jax.jit
def network_table(
    ceiling_v: Float[Array, "N W"],
    floor_v: Float[Array, "N W"],
    corner_prob: Float[Array, "N W"],
    true_ceiling_v: Float[Array, "N W"],
    true_floor_v: Float[Array, "N W"],
    corner_target: Float[Array, "N W"],
) -> dict[str, Float[Array, ""]]:
    """One row of Table netcorExp for N images: corner precision, recall, accuracy, IoU, PE mean and std."""
    errors = jax.vmap(boundary_pixel_error)(ceiling_v, floor_v, true_ceiling_v, true_floor_v)
    confusion = jnp.sum(jax.vmap(corner_confusion)(corner_prob, corner_target), axis=0)
    return {**corner_scores(confusion), "pe_mean": jnp.mean(errors), "pe_std": jnp.std(errors)}
