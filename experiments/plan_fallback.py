"""Where a branch's layout is flagged LOW_CONFIDENCE, is the plan layout (walls read robustly off the floor rows'
plan, :mod:`ncjax.pipeline.plan`) the better room?

Per labelled panorama (``*.jpg``/``*.png`` with its label_cor ``<stem>.txt``) the central pipeline's layout (the
shipped model's rows, 4 views, edge snap, no gravity alignment, camera height 1.6 m, ``NETWORK_PIPELINE_CONFIG``, as
``experiments/plan_layouts.py``) is scored against the label (3D IoU, no layout as 0) three ways:

- ``branches``: the plan fallback off (``plan.fallback`` False): auto's branch, flagged or not;
- ``fallback``: the network's configuration: the plan layout replaces a ``LOW_CONFIDENCE`` one;
- ``plan everywhere``: every layout that leaves a row unexplained flagged (``checks.min_explained_fraction`` 1),
  so the plan layout replaces every one where it has geometry: what the plan layout itself is worth.

It prints each image's three scores, each layout's status, branch and share of the rows explained
(``Layout.explained_fraction``), and the means. The same settings on the
photo-like central renders: ``uv run python experiments/central_renders.py --settings "auto,no plan fallback,plan
everywhere"``.

    uv run python experiments/plan_fallback.py --data DIR
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from ncjax.io.export import branch_name
from ncjax.network.predict import default_model
from ncjax.pipeline.types import LayoutStatus

from common import central_layout, corners_iou, labelled_rows, network_config, print_mean_ious, written_layout

SETTINGS = {
    "branches": network_config(**{"plan.fallback": False}),
    "fallback": network_config(),
    "plan everywhere": network_config(**{"checks.min_explained_fraction": 1.0}),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True, help="folder of panoramas with label_cor .txt")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        parser.error(f"no folder {args.data}")
    model = default_model()
    scores: dict[str, list[float]] = {name: [] for name in SETTINGS}
    print("| image | " + " | ".join(SETTINGS) + " |")
    print("| --- |" + " --- |" * len(SETTINGS))
    with tempfile.TemporaryDirectory() as work:
        for image_path, cam, label, rows in labelled_rows(args.data, model):
            cells = []
            for name, config in SETTINGS.items():
                layout = central_layout(*rows, cam, config)
                iou = corners_iou(written_layout(layout, cam, Path(work)), label)
                scores[name].append(iou)
                status = LayoutStatus(int(layout.status)).name
                explained = float(layout.explained_fraction)
                cells.append(f"{iou:.3f} ({status}, {branch_name(layout)}, {explained:.2f})")
            print(f"| {image_path.stem} | " + " | ".join(cells) + " |", flush=True)
    print_mean_ious(scores)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
