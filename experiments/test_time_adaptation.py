"""Can a photograph's own geometry correct the network's rows? Test-time adaptation to a flat floor and ceiling.

A room's floor and ceiling are flat and level, so in a central panorama every column sees its wall's foot and top at
the same distance: ``tan(ceiling elevation) / tan(-floor elevation)`` is the room's ``h_c / h_f`` in every column
where both rows lie on the wall. Rows that run through a doorway into the next room's floor, or onto a counter,
break it. Per labelled panorama of ``--data``, the shipped backbone's batch-norm scales and offsets (the rest frozen,
the statistics as trained: TENT, Wang et al. 2021, with this geometric loss in place of entropy) take ``--steps``
Adam steps of ``--learning-rate`` on the Huber loss (``--huber`` in log ratio) of each column's log ratio about their
median (held fixed), from the shipped weights for every panorama (``ncjax.network.adapt.adapt_to_panorama``);
the adapted model's rows (4 views, edge snap, as ``ncjax reconstruct`` reads them) are then scored against the
label as ``benchmarks/real_panoramas.py`` scores rows (mean |row error| in px of a 512-row image, over the columns
where both are finite), and their central layout
(``experiments/common.py``'s: unlevelled rows, world auto, ``NETWORK_PIPELINE_CONFIG``, camera height 1.6 m) by its
3D IoU against the label (0 without one), beside the shipped model's. No label is used to adapt; the settings were
set once, before the first run, not chosen on the photographs.

    uv run python experiments/test_time_adaptation.py --data ../shared/data/real-dev [--steps 5]
        [--learning-rate 1e-3] [--huber 0.05]
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import numpy as np

import ncjax
from ncjax.evaluation.panorama_labels import label_boundaries, labelled_image_paths, read_label_cor, read_labelled_image
from ncjax.evaluation.panorama_scores import row_error
from ncjax.io.formats_read import read_layout
from ncjax.network.adapt import AdaptConfig, adapt_to_panorama
from ncjax.network.predict import default_model, predict_boundaries

from common import central_layout, corners_iou, written_layout


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--learning-rate", type=float, default=1e-3)
    parser.add_argument("--huber", type=float, default=0.05)
    args = parser.parse_args(argv)
    config = AdaptConfig(args.steps, args.learning_rate, args.huber)
    errors = []
    for image_path, label_path in labelled_image_paths(args.data):
        image = read_labelled_image(image_path)
        height, width = image.shape[:2]
        cam = ncjax.NonCentralPanorama(width, height, rc=0.0)
        label = read_layout(label_path, width, height)
        _, _, ceiling_label, floor_label = label_boundaries(read_label_cor(label_path, width, height), width, height)
        model, losses = adapt_to_panorama(default_model(), image, config)
        row = []
        for network in (default_model(), model):
            ceiling, floor, corner_prob = predict_boundaries(image, network)
            with tempfile.TemporaryDirectory() as folder:
                corners = written_layout(central_layout(ceiling, floor, corner_prob, cam), cam, pathlib.Path(folder))
            row += [row_error(ceiling, ceiling_label), row_error(floor, floor_label), corners_iou(corners, label)]
        errors.append(row)
        print(
            f"{image_path.stem}: loss {losses[0]:.4f} before the first step, {losses[-1]:.4f} before the last; "
            f"ceiling / floor px, layout 3D IoU {row[0]:.1f} / {row[1]:.1f}, {row[2]:.3f} -> "
            f"{row[3]:.1f} / {row[4]:.1f}, {row[5]:.3f}",
            flush=True,
        )
    mean = np.nanmean(np.asarray(errors), axis=0)
    print(f"\nmean over {len(errors)} (steps {args.steps}, learning rate {args.learning_rate:g}, huber {args.huber}):")
    for name, (ceiling, floor, iou) in (("shipped", mean[:3]), ("adapted", mean[3:])):
        print(f"{name}: ceiling / floor rows {ceiling:.1f} / {floor:.1f} px, central layouts' 3D IoU {iou:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
