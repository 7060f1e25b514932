"""Time of the pipeline on one panorama under several PipelineConfig variants that differ in thresholds only.

The thresholds are traced (``ncjax.pipeline.config.TRACED_FIELDS``): the first variant compiles the
pipeline, the others reuse it. Prints the wall time per variant and the number of compiled programs.

    uv run python benchmarks/bench_config_variants.py [--world manhattan] [--variants 8]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import jax

import ncjax
from ncjax.pipeline.run import _layout_jit


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="manhattan", choices=("manhattan", "atlanta", "auto"))
    parser.add_argument("--variants", type=int, default=8)
    args = parser.parse_args(argv)
    room = ncjax.random_room(jax.random.key(5), ncjax.RoomConfig(world="manhattan"))
    cam = room.camera(1024, 512)
    label = ncjax.room_labels(room, cam)
    noise = jax.random.normal(jax.random.key(6), (2, 1024))
    rows = (label.ceiling_v + noise[0], label.floor_v + noise[1], label.corner_target)
    base = ncjax.NETWORK_PIPELINE_CONFIG
    for index in range(args.variants):
        config = dataclasses.replace(
            base,
            corner_threshold=base.corner_threshold + 0.01 * index,
            occlusion_threshold=base.occlusion_threshold + 0.5 * index,
            inlier_threshold=base.inlier_threshold + 0.1 * index,
        )
        start = time.perf_counter()
        layout = jax.block_until_ready(ncjax.layout_from_boundaries(*rows, cam, world=args.world, config=config))
        seconds = time.perf_counter() - start
        print(
            f"variant {index}: {seconds:7.2f} s, status {ncjax.LayoutStatus(int(layout.status)).name}, "
            f"compiled programs {_layout_jit._cache_size()}"
        )


if __name__ == "__main__":
    main()
