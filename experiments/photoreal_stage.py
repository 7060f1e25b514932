"""The prepared accelerator stage: the same recipe on the same rooms, the home rooms path-traced or ray-cast.

Heads trained on the shipped backbone's frozen features read the photographs' floors 2.7 px worse after the
path-traced (photoreal) rooms than after the same rooms ray-cast (8 seeds each, experiments/RESULTS.md, "What the
photoreal renders teach"). Whether the whole network does too is what this stage measures: two ``ncjax train``
commands from the shipped weights, identical but for the home rooms (``synth-photoreal-home:91:N`` or
``synth-decor-home:91:N``, the same rooms), run side by side on one accelerator (each process given under half of
its memory) with their own checkpoints, render caches, histories and logs. Only the backbone trains: the head
that reads its features stays the shipped one's (``--head-learning-rate-scale 0``), which on 2 cores kept the plain
bedrooms' rows where the whole network trained pulled them in (experiments/RESULTS.md, "Which part learns what").
Each writes a float16 model (``lite0-photoreal.safetensors``, ``lite0-raycast.safetensors``) and resumes from its
checkpoints when rerun.
Score both with ``benchmarks/real_panoramas.py --data ../shared/data/real-dev --model FILE`` against the shipped
model.

    python experiments/photoreal_stage.py [--out DIR] [--work DIR] [--one-at-a-time] [--micro-batches N] [--smoke]

``--one-at-a-time`` runs the arms one after the other (a CPU; a step's batch of 16 does not fit 24 GB there, so
give it ``--micro-batches 4``: the same update from four parts of 4 in turn, 12 GB); ``--smoke`` runs the exact
options at a few rooms and 2 steps of 4 images (a check that both arms start, train and export, minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys

ARMS = {"photoreal": "synth-photoreal-home", "raycast": "synth-decor-home"}
# KIND:SEED:N of the rooms both arms share, after the home rooms (seed 91).
SHARED_ROOMS = (
    ("synth-decor-open", 92, 500),
    ("synth-decor-hall", 94, 200),
    ("synth-decor-closet", 93, 100),
    ("synth-decor", 95, 300),
)
HOME_ROOMS = 1000
SMOKE_ROOMS = {"home": 16, "shared": 64}


def arm_command(arm: str, out: pathlib.Path, work: pathlib.Path, smoke: bool, micro_batches: int = 1) -> list[str]:
    """The ``ncjax train`` command of one arm: its model and history in ``out``, its checkpoints and rendered rooms
    under ``work``; each step's batch taken in ``micro_batches`` parts."""
    home = SMOKE_ROOMS["home"] if smoke else HOME_ROOMS
    data = [f"{ARMS[arm]}:91:{home}"] + [
        f"{kind}:{seed}:{SMOKE_ROOMS['shared'] if smoke else n}" for kind, seed, n in SHARED_ROOMS
    ]
    steps, batch = ("2", "4") if smoke else ("600", "16")
    checkpoints = work / arm
    return [
        sys.executable, "-m", "ncjax.cli", "train", "--data", *data, "--preset", "lite0-1024",
        "--init-from", str(pathlib.Path(__file__).resolve().parents[1] / "ncjax" / "models" / "lite0-1024.safetensors"),
        "--steps", steps, "--batch", batch, "--peak-learning-rate", "2e-5", "--warmup-steps", "30",
        "--backbone-learning-rate-scale", "1", "--head-learning-rate-scale", "0", "--validate-every", "0",
        "--time-budget", "520", "--render-budget", "240", "--checkpoint-dir", str(checkpoints),
        "--render-cache", str(checkpoints / "rendered"),
        "--history", str(out / f"{arm}_history.json"), "--export", str(out / f"lite0-{arm}.safetensors"),
        "--export-dtype", "float16", "--micro-batches", str(micro_batches),
    ]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("."), help="models, histories and logs")
    parser.add_argument(
        "--work",
        type=pathlib.Path,
        default=pathlib.Path("checkpoints") / "photoreal-stage",
        help="checkpoints and rendered rooms (gigabytes: keep them out of what a device call brings back)",
    )
    parser.add_argument("--one-at-a-time", action="store_true", help="run the arms one after the other (a CPU)")
    parser.add_argument(
        "--micro-batches", type=int, default=1, help="each step's batch in this many parts (4 on a 24 GB CPU)"
    )
    parser.add_argument("--smoke", action="store_true", help="a few rooms and 2 steps")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    # Two processes share one accelerator: neither may take the 75% of its memory JAX takes by default.
    environment = {**os.environ, "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.45"}
    running = {}
    for arm in ARMS:
        log = open(args.out / f"{arm}.log", "w")  # noqa: SIM115 (closed once the arm ends)
        running[arm] = (
            subprocess.Popen(
                arm_command(arm, args.out, args.work, args.smoke, args.micro_batches),
                stdout=log,
                stderr=log,
                env=environment,
            ),
            log,
        )
        print(f"{arm}: started, log {args.out / f'{arm}.log'}", flush=True)
        if args.one_at_a_time:
            running[arm][0].wait()
    failed = []
    for arm, (process, log) in running.items():
        code = process.wait()
        log.close()
        print(f"{arm}: exit status {code}", flush=True)
        if code:
            failed.append(arm)
    if failed:
        print(f"photoreal_stage: error: {', '.join(failed)} failed; see their logs", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
