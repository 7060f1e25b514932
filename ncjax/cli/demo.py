"""``ncjax demo``: the shipped sample reconstructed and compared with its ground truth."""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import sys
import time

import numpy as np

from ..io.images import read_panorama_file
from ..network.config import AdaptConfig
from ..pipeline.config import DEFAULT_WORLD, WORLDS
from ..pipeline.types import LayoutStatus
from .arguments import add_texture_argument
from .compilation import CompileLedger, enable_compilation_cache
from .inputs import check_output_folder, make_output_folder, model_weights_option, radius_of
from .outputs import ReconstructedImage, import_mesh_modules_in_background, write_outputs
from .reconstruct import (
    WORLD_HELP,
    ReconstructSettings,
    add_boundary_arguments,
    add_export_argument,
    add_pipeline_arguments,
    pipeline_config,
    program_key,
)
from .summary import failure_message

DEMO_DIR = pathlib.Path(__file__).parent.parent / "data" / "demo"
# `ncjax reconstruct`'s default (central panoramas whose rows are not flat adapted), so that the two share programs
ADAPT = AdaptConfig()


def run_demo(args: argparse.Namespace) -> int:
    """``ncjax demo``: reconstruct the shipped sample and compare it with its ground truth."""
    import jax

    from ..evaluation import layout_metrics as metrics
    from ..reconstruction import DEFAULT_BATCH_SIZE, reconstruct_batch

    start = time.perf_counter()
    config = pipeline_config(args)
    check_output_folder(args.out)
    model = model_weights_option(None)
    make_output_folder(args.out)
    ledger = CompileLedger(enable_compilation_cache())
    import_mesh_modules_in_background()
    with open(DEMO_DIR / "ground_truth.json") as file:
        truth = json.load(file)
    path = DEMO_DIR / truth["image"]
    image, file_size, _ = read_panorama_file(path)
    rc = radius_of(str(path), None)
    print(
        f"ncjax demo: {truth['image']} ({image.shape[1]} x {image.shape[0]}, rc = {rc} m from its name, "
        f"a {truth['world']} room rendered by ncjax synth and never seen in training)"
    )
    # the programs of `ncjax reconstruct`'s default --batch: one run of either serves the other
    settings = ReconstructSettings(
        model, DEFAULT_BATCH_SIZE, args.world, config, args.views, args.edge_snap, args.out, (), None, adapt=ADAPT
    )
    key = program_key((DEFAULT_BATCH_SIZE, *image.shape), settings)
    with ledger.compiling(
        key,
        f"the network and the geometry for {image.shape[1]} x {image.shape[0]}",
        lambda line: print(line, flush=True),
    ):
        result = jax.device_get(
            reconstruct_batch(
                image[None],
                np.array([rc], np.float32),
                args.world,
                config=config,
                views=args.views,
                edge_snap=args.edge_snap,
                program_cache=True,
                adapt=ADAPT,
            )
        )
    one = jax.tree.map(lambda x: x[0], tuple(result))
    name = pathlib.Path(truth["image"]).stem
    reconstructed = ReconstructedImage(name, image, one, rc, file_size=file_size)
    record = write_outputs(args.out, reconstructed, args.world, export=args.export, texture_size=args.texture_size)
    elapsed = time.perf_counter() - start
    if not record["ok"]:
        print(f"{failure_message(record)}: {LayoutStatus[record['status']].reason}", file=sys.stderr)
        return 1
    scores = metrics.evaluate_layout(one[0], truth)
    true_height = truth["ceiling_corners"][0][2] - truth["floor_corners"][0][2]
    print(
        f"layout: {len(record['ceiling_corners'])} corners ({record['branch']} branch, explains "
        f"{100 * record['explained_fraction']:.0f}% of the boundary pixels), "
        f"room height {record['room_height']:.3f} ± {record['room_height_sigma'] or math.inf:.3f} m "
        f"(true {true_height:.3f} m), "
        f"floor area {record['floor_area']:.2f} m^2"
    )
    found, true_count = len(record["ceiling_corners"]), len(truth["ceiling_corners"])
    corner_error = (
        f"corner error {scores['ce']:.3f} m"
        if math.isfinite(scores["ce"])
        else f"corner error n/a ({found} corners found, {true_count} in the ground truth)"
    )
    print(
        f"error against the ground truth: {corner_error}, 3D IoU {100 * scores['iou3d']:.1f}%, "
        f"2D IoU {100 * scores['iou2d']:.1f}%, height error {scores['height_error']:.3f} m"
    )
    print(
        f"outputs in {os.path.abspath(args.out)}/ (json, obj/ply/glb mesh, html 3D viewer, overlay and plan png); "
        f"{elapsed:.0f} s"
    )
    return 0


def add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="ncjax_demo", help="output folder (default ./ncjax_demo)")
    parser.add_argument("--world", choices=WORLDS, default=DEFAULT_WORLD, help=WORLD_HELP)
    add_export_argument(parser)
    add_texture_argument(parser)
    add_boundary_arguments(parser)
    add_pipeline_arguments(parser)
