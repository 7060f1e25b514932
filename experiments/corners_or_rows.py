"""What limits the central layouts of real photographs: the network's corners or its rows?

For each labelled panorama of a folder (``*.jpg``/``*.png`` with its label_cor ``<stem>.txt``, as
``benchmarks/central_layouts.py`` reads them) the shipped model gives the rows and corner probability (4 views,
edge snap; no gravity alignment, so that both runs see the same rows), and the central pipeline
(``NETWORK_PIPELINE_CONFIG``, world auto, camera height 1.6 m) runs twice on those rows: with the network's
corner probability, and with the label's corner columns in its place (HorizonNet's ``0.96**d`` target of the
label's floor corners: every corner found, none spurious). Each layout's label_cor is scored against the
label as ``central_layouts.py`` scores it (:func:`ncjax.evaluation.central_metrics.evaluate_corners`, both at camera
height 1; no layout counts 0). If the labelled corners lift the mean 3D IoU little, the rows are what the
network has to learn.

    uv run python experiments/corners_or_rows.py --data DIR
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import numpy as np

import ncjax
from ncjax.network.predict import default_model
from ncjax.synth.labels import corner_target

from common import central_layout, corners_iou, labelled_rows, written_layout


def layout_iou(layout: ncjax.Layout, cam: ncjax.NonCentralPanorama, label, folder: pathlib.Path) -> float:
    """3D IoU of one layout's label_cor against the label (0 without a layout or a scorable one)."""
    return corners_iou(written_layout(layout, cam, folder), label)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    args = parser.parse_args(argv)
    model = default_model()
    ious = {"network corners": [], "labelled corners": []}
    print("| image | network corners | labelled corners |")
    print("| --- | --- | --- |")
    with tempfile.TemporaryDirectory() as work:
        for image_path, cam, label, (ceiling_v, floor_v, corner_prob) in labelled_rows(args.data, model):
            columns = np.asarray(label.floor)[:, 0]
            labelled = np.asarray(corner_target(columns, np.ones(len(columns), bool), cam.width))
            row = []
            for name, probability in (("network corners", corner_prob), ("labelled corners", labelled)):
                layout = central_layout(ceiling_v, floor_v, probability, cam)
                ious[name].append(layout_iou(layout, cam, label, pathlib.Path(work)))
                row.append(f"{ious[name][-1]:.3f}")
            print(f"| {image_path.stem} | {' | '.join(row)} |", flush=True)
    means = {name: np.mean(values) for name, values in ious.items()}
    print(f"| mean of {len(ious['network corners'])} | {' | '.join(f'{m:.3f}' for m in means.values())} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
