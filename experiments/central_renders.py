"""Central layouts of photo-like renders through the network: the central pipeline's settings chosen without photos.

The real panoramas of ``benchmarks/central_layouts.py`` measure the central mode; they must not choose its
settings. These renders stand in for them: furnished rooms seen by a central camera (rc = 0) as most
photographs are, of two kinds (:data:`ncjax.training.data.SYNTH_SOURCES`), ``synth-decor-home`` (pale walls,
as in most homes) and ``synth-decor-open`` (doors, half of them wide passages to the next room, as in open
plans), with seeds no model was trained on (``--seed`` and ``--seed + 1``), each image through one random
camera of the training augmentation (exposure, white balance, blur, noise, seams, black bands, JPEG). The
shipped model's rows (4 views, edge snap, as ``ncjax reconstruct``) are computed once and cached in
``experiments/out/central_renders_<kind>_<seed>_<n>_<model>_<hash>.npz`` (the model file's name and the start of
its SHA-256: new weights under an old name are not mistaken for it).

Each setting then runs the pipeline alone on those rows (:func:`ncjax.layout_from_boundaries`, ``rc = 0``,
the true camera height as the prior, so that only the shape is scored) and prints, per kind and over both:
the layouts returned (any status with geometry, as ``ncjax reconstruct`` writes them), the 3D IoU against
the rendered room's visible layout over all rooms (no layout as 0), mean and median, the corner error of the
layouts with the true corner count, and on how many rooms the layout beats the raw polygon of its own rows
(each column's floor row at the camera height, as ``benchmarks/real_panoramas.py`` scores it), whose mean
3D IoU is printed too.

    uv run python experiments/central_renders.py                    # 64 rooms per kind, DEFAULT_SETTINGS
    uv run python experiments/central_renders.py --settings "threshold 0.3,threshold 0.5,nms 3,nms 6,inlier 4"
    uv run python experiments/central_renders.py --rooms 8 --settings auto,manhattan
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import jax
import numpy as np
from tqdm import tqdm

import ncjax
from ncjax.evaluation import layout_metrics
from ncjax.evaluation.panorama_labels import raw_prediction_room
from ncjax.io.export import status_has_geometry
from ncjax.network.checkpoint import load_model
from ncjax.network.predict import DEFAULT_MODEL_PATH
from ncjax.pipeline.prior import HeightPrior
from ncjax.reconstruction import reconstruct_batch
from ncjax.synth.dataset import rendered_samples
from ncjax.training.data import SYNTH_SOURCES

from common import BATCH, OUT, PHOTO_LIKE_SEED, model_suffix, network_config, photo_like_image

KINDS = ("synth-decor-home", "synth-decor-open")
# world, and the options replacing NETWORK_PIPELINE_CONFIG's ("margin": world auto with manhattan_margin; "own
# heights": RANSAC's walls with their own heights, the paper's single-wall solver; then the network settings of
# NETWORK_PIPELINE_CONFIG chosen on the tuning renders, and the inlier threshold, each changed alone; "plan
# everywhere": every layout that leaves a row unexplained flagged, so that the plan layout replaces it)
SETTINGS = {
    "auto": ("auto", {}),
    "manhattan": ("manhattan", {}),
    "atlanta": ("atlanta", {}),
    "margin 0.1": ("auto", {"manhattan_margin": 0.1}),
    "margin 0.2": ("auto", {"manhattan_margin": 0.2}),
    "own heights": ("auto", {"prior_wall_heights": False}),
    "threshold 0.3": ("auto", {"corner_threshold": 0.3}),
    "threshold 0.5": ("auto", {"corner_threshold": 0.5}),
    "nms 3": ("auto", {"nms_radius": 3.0}),
    "nms 6": ("auto", {"nms_radius": 6.0}),
    "occlusion 6": ("auto", {"occlusion_threshold": 6.0}),
    "occlusion 12": ("auto", {"occlusion_threshold": 12.0}),
    "inlier 4": ("auto", {"inlier_threshold": 4.0}),
    "no range check": ("auto", {"checks.max_corner_range_ratio": math.inf}),
    "no plan fallback": ("auto", {"plan.fallback": False}),
    "plan everywhere": ("auto", {"checks.min_explained_fraction": 1.0}),
}
DEFAULT_SETTINGS = ("auto", "manhattan", "atlanta", "margin 0.1", "margin 0.2", "own heights")


def photo_like_rows(kind: str, seed: int, rooms: int, model_path: Path) -> dict[str, np.ndarray]:
    """Render ``rooms`` rooms of ``kind``, pass each through a random camera and the network; cached."""
    cache = OUT / f"central_renders_{kind}_{seed}_{rooms}{model_suffix(model_path)}.npz"
    if cache.exists():
        return dict(np.load(cache))
    model = load_model(model_path)
    images, truth = [], []
    for index, _scene, rendering, labels in tqdm(
        rendered_samples(rooms, seed, SYNTH_SOURCES[kind], BATCH), total=rooms, desc=f"render {kind}"
    ):
        images.append(photo_like_image(seed, index, rendering))
        mask = np.asarray(labels.corner_mask)
        truth.append((np.asarray(labels.ceiling_corners)[mask], np.asarray(labels.floor_corners)[mask]))
    rows = {"ceiling_v": [], "floor_v": [], "corner_prob": []}
    for start in tqdm(range(0, rooms, BATCH), desc=f"network {kind}"):
        batch = np.stack(images[start : start + BATCH])
        result = reconstruct_batch(batch, np.zeros(len(batch), np.float32), model=model)
        for key in rows:
            rows[key].append(np.asarray(getattr(result, key)))
    capacity = max(len(c) for c, _ in truth)
    data = {key: np.concatenate(value) for key, value in rows.items()}
    data["ceiling_corners"] = np.stack([np.pad(c, ((0, capacity - len(c)), (0, 0))) for c, _ in truth])
    data["floor_corners"] = np.stack([np.pad(f, ((0, capacity - len(f)), (0, 0))) for _, f in truth])
    data["corner_count"] = np.array([len(c) for c, _ in truth])
    OUT.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(cache, **data)
    return data


def true_layout(data: dict[str, np.ndarray], index: int) -> dict[str, np.ndarray]:
    count = data["corner_count"][index]
    return {
        "ceiling_corners": data["ceiling_corners"][index, :count],
        "floor_corners": data["floor_corners"][index, :count],
    }


def raw_ious(data: dict[str, np.ndarray]) -> np.ndarray:
    """Per room, the up-to-scale 3D IoU of the raw polygon of its rows (:func:`raw_prediction_room`)."""
    cam = ncjax.NonCentralPanorama(data["floor_v"].shape[1], data["floor_v"].shape[1] // 2, rc=0.0)
    return np.array(
        [
            layout_metrics.iou_3d(raw_prediction_room(c, f, cam), true_layout(data, i), up_to_scale=True)
            for i, (c, f) in enumerate(zip(data["ceiling_v"], data["floor_v"], strict=True))
        ]
    )


def setting_scores(data: dict[str, np.ndarray], world: str, options: dict) -> dict[str, np.ndarray]:
    """Per room: whether a layout with geometry came back, its 3D IoU (0 without) and its CE (NaN on a wrong count)."""
    width = data["floor_v"].shape[1]
    cam = ncjax.NonCentralPanorama(width, width // 2, rc=0.0)
    config = network_config(**options)
    prior = HeightPrior("camera_height", -data["floor_corners"][:, 0, 2])
    layouts = ncjax.layout_from_boundaries(
        data["ceiling_v"], data["floor_v"], data["corner_prob"], cam, world, config, prior=prior
    )
    returned, iou, ce = [], [], []
    for index in range(len(data["corner_count"])):
        layout = jax.tree.map(lambda x, i=index: np.asarray(x[i]), layouts)
        has = status_has_geometry(bool(layout.ok), int(layout.status))
        truth = true_layout(data, index)
        returned.append(has)
        iou.append(layout_metrics.iou_3d(layout, truth) if has else 0.0)
        ce.append(layout_metrics.corner_error(layout, truth)[0] if has else math.nan)
    return {"returned": np.array(returned), "iou": np.array(iou), "ce": np.array(ce)}


def table_line(name: str, scores: dict[str, np.ndarray], raw: np.ndarray) -> str:
    iou, ce = scores["iou"], scores["ce"]
    counted = np.isfinite(ce)
    ce_text = f"{np.mean(ce[counted]):.3f} m ({np.sum(counted)})" if counted.any() else "-"
    return (
        f"| {name} | {np.mean(scores['returned']):.1%} | {np.mean(iou):.1%} / {np.median(iou):.1%} | {ce_text} "
        f"| {np.sum(iou > raw)} of {len(iou)} |"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rooms", type=int, default=64, help="rooms per kind")
    parser.add_argument("--seed", type=int, default=PHOTO_LIKE_SEED, help="seed of the first kind (+1 for the second)")
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_PATH, help="network weights")
    parser.add_argument("--settings", default=",".join(DEFAULT_SETTINGS), help=f"comma list of: {', '.join(SETTINGS)}")
    args = parser.parse_args(argv)
    names = [name.strip() for name in args.settings.split(",")]
    unknown = [name for name in names if name not in SETTINGS]
    if unknown or args.rooms < 1:
        parser.error(f"unknown setting {unknown[0]!r}" if unknown else "--rooms must be at least 1")
    if not args.model.is_file():
        parser.error(f"no model file {args.model}")
    per_kind = {kind: photo_like_rows(kind, args.seed + i, args.rooms, args.model) for i, kind in enumerate(KINDS)}
    raw = {kind: raw_ious(data) for kind, data in per_kind.items()}
    print(f"{args.rooms} rooms per kind, seeds {args.seed} and {args.seed + 1}, model {args.model.name}")
    print("raw polygon of the rows, 3D IoU up to scale: " + ", ".join(f"{k} {np.mean(v):.1%}" for k, v in raw.items()))
    print("| setting | layouts returned | 3D IoU all rooms, mean / median | CE, true count (rooms) | beats raw |")
    print("| --- | --- | --- | --- | --- |")
    for name in names:
        world, options = SETTINGS[name]
        scores = {kind: setting_scores(data, world, options) for kind, data in per_kind.items()}
        for kind in KINDS:
            print(table_line(f"{name}, {kind}", scores[kind], raw[kind]))
        pooled = {key: np.concatenate([scores[kind][key] for kind in KINDS]) for key in scores[KINDS[0]]}
        print(table_line(f"**{name}, both**", pooled, np.concatenate([raw[kind] for kind in KINDS])))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
