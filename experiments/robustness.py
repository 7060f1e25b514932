"""How the shipped model and pipeline hold up when the panorama is degraded: noise, blur, JPEG, darkness.

Real captures differ from our renders; this measures the part of that gap we
can simulate. Each degradation is applied to the first ``--rooms`` test renders
without occlusion of ``network_table.py`` (seeds 99 / 98, never used for
training or tuning) and the degraded images go through ``ncjax.reconstruct_batch``
with the shipped configuration. Some degradations lie inside the training
augmentation's ranges (greyscale, blur up to 1.2 px, read noise up to 0.02),
the others beyond them (``ncjax.synth.augment.AugmentConfig``); JPEG is not among them.

Per degradation and world: failures, CE mean / median, 3D IoU of the ok rooms
and over all rooms with failures as 0, the share of rooms given a layout
whatever its corner count and that layout's 3D IoU (scored as
``network_table.py``), and the mean error of the boundary rows the geometry used.

    uv run python experiments/robustness.py              # 32 rooms per world
    uv run python experiments/robustness.py --rooms 8
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

import ncjax.synth.augment
from ncjax.cli.reconstruct import add_boundary_arguments
from ncjax.network.predict import default_model
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG
from ncjax.synth.dataset import list_samples, read_sample

from common import (
    OUT,
    TEST_SEEDS,
    ground_truth,
    layout_scores,
    layouts_of,
    scores_summary,
    test_renders,
    used_row_errors,
)

TEST_ROOMS = 128  # the renders of network_table.py


def _float_op(operation):
    """An image operation on [0, 1] floats (``ncjax.synth.augment``) applied to an RGB uint8 image."""

    def apply(image: np.ndarray) -> np.ndarray:
        result = operation(jnp.asarray(image, jnp.float32) / 255.0)
        return np.asarray(jnp.round(result * 255.0), np.uint8)

    return apply


def jpeg(quality: int):
    def apply(image: np.ndarray) -> np.ndarray:
        ok, encoded = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, quality])
        if not ok:
            raise RuntimeError("OpenCV could not encode a JPEG")
        return cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1].copy()

    return apply


# name -> (operation on an RGB uint8 image, inside the training augmentation's ranges)
DEGRADATIONS = {
    "none": (lambda image: image, True),
    "greyscale": (_float_op(ncjax.network.to_greyscale), True),
    "blur 1 px": (_float_op(lambda x: ncjax.network.gaussian_blur(x, 1.0)), True),
    "blur 2.5 px": (_float_op(lambda x: ncjax.network.gaussian_blur(x, 2.5, radius=8)), False),
    "sensor noise 0.05": (
        _float_op(lambda x: ncjax.synth.augment.add_sensor_noise(jax.random.key(0), x, 0.05, 0.05)),
        False,
    ),
    "dark (exposure x0.25)": (_float_op(lambda x: ncjax.synth.augment.adjust_exposure(x, 0.25)), False),
    "JPEG quality 30": (jpeg(30), False),
}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=32, help="test renders without occlusion per world")
    parser.add_argument("--degradations", nargs="+", choices=list(DEGRADATIONS), default=list(DEGRADATIONS))
    parser.add_argument("--out", type=Path, default=OUT)
    add_boundary_arguments(parser)
    args = parser.parse_args(argv)
    if args.rooms < 1:
        parser.error("--rooms must be >= 1")
    start = time.time()
    model = default_model()
    lines = [
        f"First {args.rooms} test renders without occlusion per world, {args.views} view(s), rows snapped: "
        f"{args.edge_snap is not None}, "
        "NETWORK_PIPELINE_CONFIG.",
        "",
        "| degradation | in training ranges | world | failed (%) | CE mean / median (m) | 3D IoU ok (%) | IoU all0 "
        "(%) | "
        "layout returned (%) | 3D IoU of the returned (%) | row error ceiling / floor (px) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    record = {}
    for world in TEST_SEEDS:
        folder = str(test_renders(world, TEST_ROOMS, args.out))
        samples = [read_sample(folder, name) for name in list_samples(folder)]
        samples = [s for s in samples if not any(s.metadata["corner_is_occlusion"])][: args.rooms]
        truths = [ground_truth(s, world) for s in samples]
        for name in args.degradations:
            operation, trained = DEGRADATIONS[name]
            degraded = [dataclasses.replace(s, image=operation(s.image)) for s in samples]
            layouts, boundaries = layouts_of(
                degraded, world, model, NETWORK_PIPELINE_CONFIG, args.views, args.edge_snap
            )
            s = scores_summary(layout_scores(layouts, truths))
            rows = used_row_errors(samples, boundaries)
            record[f"{name}/{world}"] = s | rows
            lines.append(
                f"| {name} | {'yes' if trained else 'no'} | {world} | {s['failed']:.1f} | {s['ce']:.3f} / "
                f"{s['ce_median']:.3f} | "
                f"{s['iou3d']:.1f} | {s['iou3d_all']:.1f} | {s['returned']:.1f} | {s['iou3d_returned']:.1f} | "
                f"{rows['ceiling_mean']:.2f} / {rows['floor_mean']:.2f} |"
            )
    table = "\n".join(lines)
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"robustness_{args.rooms}.md").write_text(table + "\n")
    (args.out / f"robustness_{args.rooms}.json").write_text(json.dumps(record, indent=1) + "\n")
    return record


if __name__ == "__main__":
    main()
