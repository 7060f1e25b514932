"""A model file at half precision (``ncjax train --export-dtype float16``) against the float32 one.

Saves the model with ``ncjax.save_model(..., dtype="float16")`` (half the bytes: a device's transfer limit or the
repository's size) and scores both files on the first ``--rooms`` test renders per world of
``network_table.py`` (Table netcorExp's metrics, the default views).

    uv run python experiments/half_precision.py --model FILE [--rooms 64]

``FILE`` holds float32 weights (the shipped ``lite0-1024`` is itself a float16 export, so it is refused).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from ncjax.network.checkpoint import load_model, model_file, read_metadata, save_model
from ncjax.network.predict import DEFAULT_MODEL_PATH, DEFAULT_VIEWS
from ncjax.training.data import evaluate_arrays, load_split

from common import OUT, TEST_SEEDS, test_renders


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=str(DEFAULT_MODEL_PATH), help="float32 model file or shipped name")
    parser.add_argument("--rooms", type=int, default=64, help="test renders per world (of network_table's 128)")
    args = parser.parse_args(argv)
    if read_metadata(model_file(args.model)).get("weights_dtype") == "float16":
        parser.error(f"{args.model} holds float16 weights already: give a float32 model file with --model")
    full = load_model(args.model)
    with tempfile.TemporaryDirectory() as folder:
        half_path = Path(folder) / "half.safetensors"
        save_model(full, half_path, dtype="float16")
        sizes = model_file(args.model).stat().st_size, half_path.stat().st_size
        half = load_model(half_path)
    arrays = [load_split(str(test_renders(world, 128, OUT)), "all", 512, 1024) for world in TEST_SEEDS]
    pooled = {key: np.concatenate([a[key][: args.rooms] for a in arrays]) for key in arrays[0]}
    print(f"{args.model}: {sizes[0]:,} bytes float32, {sizes[1]:,} bytes float16; {len(pooled['image'])} test renders")
    print("| weights | precision | recall | IoU | PE mean (px) |")
    print("| --- | --- | --- | --- | --- |")
    for name, model in (("float32", full), ("float16", half)):
        row = evaluate_arrays(model, pooled, views=DEFAULT_VIEWS)
        print(f"| {name} | {row['precision']:.4f} | {row['recall']:.4f} | {row['iou']:.4f} | {row['pe_mean']:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
