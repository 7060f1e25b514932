"""Where the batched pipeline spends its time: XLA's own trace, summed per pipeline stage.

Each stage function (RANSAC, the wall solver's SVD, the layout solver, the
adjustment, ...) is wrapped in a ``jax.named_scope`` before tracing, one
batch is run under ``jax.profiler.trace``, and the duration of every XLA
kernel is attributed to the innermost stage that emitted most of its
operations. Run it pinned to one core for single-core figures:

    taskset -c 0 uv run python benchmarks/profile_pipeline.py [--world manhattan] [--batch 64] [--adjustment-stride 2]
"""

from __future__ import annotations

import argparse
import collections
import functools
import glob
import gzip
import json
import os
import re
import sys
import tempfile

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax
from bench_pipeline import inputs

import ncjax.pipeline.config
import ncjax.pipeline.run
from ncjax.pipeline.types import Rows

# the functions whose operations are attributed to a stage of their own name
STAGES = [
    "gather_evidence",
    "ransac_wall",
    "side_extrapolation",
    "boundary_errors",
    "manhattan_labels",
    "final_walls",
    "solve_atlanta_layout",
    "plan_lines",
    "refine",
    "adjust_layout",
    "layout_uncertainty",
    "assemble_layout",
    "_row_errors",
    "pixel_to_ray",
    "correlation_time",
    "_residual_terms",
    "corner_residual",
    "_fitted_residuals",
    "probe_jacobian",
    "normal_matrix",
    "transpose_product",
    "jacobian_product",
    "solve_wall",
    "sample_columns",
    "boundary_angles",
    "scaled_null_space",
    "constrained_null_vector",
    "_jacobi_svd",
    "_triangular_factor",
    "linear_walls",
    "search_scale",
    "refine_walls",
    "gauss_newton_step",
]
_PREFIX = "stage_"


def _scoped(fn, name):
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.named_scope(_PREFIX + name):
            return fn(*args, **kwargs)

    return wrapped


def _kernel_stages(hlo_text: str) -> dict[str, str]:
    """Per instruction of the optimised HLO, the stage path that most of its (fused) operations came from."""
    computations, current = {}, None
    for line in hlo_text.splitlines():
        header = re.match(r"^(?:ENTRY )?%?([\w.\-]+) .*\{\s*$", line)
        if header:
            current = computations.setdefault(header.group(1), [])
        elif current is not None:
            current.append(line)

    def stage(line):
        name = re.search(r'op_name="([^"]*)"', line)
        return "/".join(re.findall(_PREFIX + r"(\w+)", name.group(1))) or "(other)" if name else None

    stages = {}
    for lines in computations.values():
        for line in lines:
            instruction = re.match(r"\s*(?:ROOT )?%?([\w.\-]+) = ", line)
            if not instruction:
                continue
            found = [stage(line)]
            for called in re.findall(r"(?:calls|body|condition|to_apply)=%?([\w.\-]+)", line):
                found += [stage(inner) for inner in computations.get(called, [])]
            found = [s for s in found if s]
            stages[instruction.group(1)] = collections.Counter(found).most_common(1)[0][0] if found else "(other)"
    return stages


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--world", default="manhattan", choices=["manhattan", "atlanta", "auto"])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--top", type=int, default=20)
    parser.add_argument(
        "--adjustment-stride",
        type=int,
        default=ncjax.pipeline.config.PipelineConfig().adjustment.stride,
        help="PipelineConfig's adjustment.stride",
    )
    parser.add_argument(
        "--capacity", type=int, default=ncjax.pipeline.config.PipelineConfig().capacity, help="PipelineConfig.capacity"
    )
    args = parser.parse_args(argv)
    # every module that holds a stage's function (its own, and those that import it) calls the scoped one
    for module in [m for n, m in sys.modules.items() if n.startswith("ncjax.")]:
        for name in STAGES:
            if callable(getattr(module, name, None)):
                setattr(module, name, _scoped(getattr(module, name), name))
    ceiling, floor, prob, cams = inputs(args.world, args.batch)
    cam = jax.tree.map(lambda x: x[0], cams)
    keys = jax.random.split(jax.random.key(0), args.batch)
    config = ncjax.pipeline.config.PipelineConfig(capacity=args.capacity).replace(
        adjustment={"stride": args.adjustment_stride}
    )
    batched = jax.jit(
        jax.vmap(lambda c, f, p, k: ncjax.pipeline.run.layout_of(Rows(c, f, p), cam, None, k, config, args.world))
    )
    jax.block_until_ready(batched(ceiling, floor, prob, keys))
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder, create_perfetto_trace=True):
            jax.block_until_ready(batched(ceiling, floor, prob, keys))
        (path,) = glob.glob(f"{folder}/**/*.trace.json.gz", recursive=True)
        with gzip.open(path) as file:
            events = json.load(file)
    events = events["traceEvents"] if isinstance(events, dict) else events
    stages = _kernel_stages(batched.lower(ceiling, floor, prob, keys).compile().as_text())
    totals = collections.Counter()
    for event in events:
        name = event.get("name", "")
        if event.get("ph") == "X" and name in stages:
            totals[stages[name]] += event.get("dur", 0) / 1e3 / args.batch
    print(f"{args.world}, batch {args.batch}: {sum(totals.values()):.2f} ms of XLA kernels per panorama")
    for stage, ms in totals.most_common(args.top):
        print(f"{ms:8.3f} ms  {stage}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
