"""Do photographs read better stretched? The network on each panorama with its room made wider about the camera.

Scaling a room about a central camera by ``k`` across and not in height (HorizonNet's pano stretch, here the same
``k`` along both horizontal axes) moves every point's elevation to ``atan(tan(phi) / k)`` and keeps its azimuth: a
remapping of the rows alone. Each labelled panorama is read by the shipped model (4 views) as it is and stretched
by each ``k`` (``k > 1``: walls farther for their height, as the renders' rooms are against the photographs'), its
rows mapped back (``atan(k tan(phi'))``), and scored as ``benchmarks/real_panoramas.py`` scores them (ceiling /
floor px of a 512-row image, raw 3D IoU up to scale), for each ``k`` and for the columnwise mean and median of the
rows over all ``k``.

    uv run python experiments/stretched_views.py --data DIR [--factors 0.8 1 1.25 1.6]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.evaluation.panorama_labels import load_network, load_panoramas, read_labelled_image
from ncjax.evaluation.panorama_scores import raw_layout_ious, row_error
from ncjax.geometry.camera import NonCentralPanorama, angles_to_pixel, pixel_to_angles


def stretched_rows(rows: np.ndarray, height: int, factor: float) -> np.ndarray:
    """The rows of an equirectangular panorama of ``height`` rows whose elevations ``phi`` become
    ``atan(factor tan(phi))``."""
    cam = NonCentralPanorama(2 * height, height, rc=0.0)
    _, elevation = pixel_to_angles(cam, 0.0, np.asarray(rows, np.float64))
    return np.asarray(angles_to_pixel(cam, 0.0, jnp.arctan(factor * jnp.tan(elevation)))[1], np.float64)


def stretch_image(image: np.ndarray, factor: float) -> np.ndarray:
    """``image`` with its room stretched by ``factor`` across: each output row samples the input row
    :func:`stretched_rows` gives it (linear between rows)."""
    height = image.shape[0]
    source = np.clip(stretched_rows(np.arange(height, dtype=np.float64), height, factor), 0, height - 1)
    below = np.floor(source).astype(int)
    above = np.minimum(below + 1, height - 1)
    weight = (source - below)[:, None, None]
    mixed = image[below] * (1 - weight) + image[above] * weight
    return np.clip(np.round(mixed), 0, 255).astype(np.uint8)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of panoramas with label_cor files")
    parser.add_argument("--factors", type=float, nargs="+", default=[0.8, 1.0, 1.25, 1.6], help="stretch factors k")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        parser.error(f"no folder {args.data}")
    if min(args.factors) <= 0:
        parser.error("stretch factors must be > 0")
    panoramas = load_panoramas(args.data, None)
    model = load_network(None)
    names = [f"k {k:g}" for k in args.factors] + ["mean", "median"]
    scores: dict[str, list[tuple[float, float, float, bool]]] = {name: [] for name in names}
    print("| image | " + " | ".join(names) + " |  (ceiling / floor px, raw 3D IoU)")
    for panorama in panoramas:
        image = read_labelled_image(panorama.image_path)
        height = image.shape[0]
        reads = []
        for k in args.factors:
            ceiling, floor, _ = (
                np.asarray(a, np.float64) for a in ncjax.predict_boundaries(stretch_image(image, k), model, views=4)
            )
            # the stretched image's row v' shows the input's row stretched_rows(v', k)
            reads.append((stretched_rows(ceiling, height, k), stretched_rows(floor, height, k)))
        stacked = np.array(reads)  # (factors, 2, W)
        rows = reads + [tuple(stacked.mean(0)), tuple(np.median(stacked, 0))]
        cells = []
        for name, (ceiling, floor) in zip(names, rows, strict=True):
            ceiling_px = row_error(ceiling, panorama.ceiling_v) if panorama.score_ceiling else np.nan
            floor_px = row_error(floor, panorama.floor_v)
            iou = raw_layout_ious(panorama, ceiling, floor)[1]
            scores[name].append((ceiling_px, floor_px, iou, "closed" in panorama.tags))
            cells.append(f"{ceiling_px:.1f} / {floor_px:.1f} / {iou:.3f}")
        print(f"| {panorama.name} | " + " | ".join(cells) + " |", flush=True)
    for name, values in scores.items():
        table = np.array(values, float)
        closed = table[:, 3] > 0
        print(
            f"{name}: all {np.nanmean(table[:, 0]):.1f} / {np.nanmean(table[:, 1]):.1f} px, IoU "
            f"{np.nanmean(table[:, 2]):.3f}; closed rooms {np.nanmean(table[closed, 0]):.1f} / "
            f"{np.nanmean(table[closed, 1]):.1f} px, IoU {np.nanmean(table[closed, 2]):.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
