"""``ncjax train``: the command line of :func:`ncjax.training.loop.train`."""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import numpy as np

from ..network.checkpoint import WEIGHTS_DTYPES, check_warm_start
from ..network.config import PRESETS, HorizonNetConfig
from ..training.data import (
    RenderingStopped,
    evaluate_arrays,
    folder_batches,
    painted_batches,
    parse_synth_source,
    render_in_proportion,
    training_data,
)
from ..training.loop import TrainConfig, train
from .options import add_config_options, config_from_options

# ----------------------------------------------------------------------------- command line


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``ncjax train``."""
    parser.add_argument(
        "--data",
        nargs="+",
        help="required: dataset folders (ncjax synth or the authors') or synth:SEED:N (the N rooms `ncjax synth "
        "--seed SEED` writes, rendered in memory), synth-decor:SEED:N (the same with --decor), "
        "synth-decor-central:SEED:N (such rooms with a central camera, rc 0), synth-decor-home:SEED:N (the same, "
        "70%% of them with white or pale walls, as most homes, a fifth with beams across the ceiling), "
        "synth-photoreal-home:SEED:N (the same rooms "
        "path-traced and photographed: ncjax synth --photoreal; seconds a room on a CPU), synth-decor-small:SEED:N "
        "(closets, bathrooms and corridors, sides 1.2-4 m, rc 0), synth-decor-closet:SEED:N (walk-in closets with "
        "shelving, most with a passage filling much of a wall, rc 0), synth-decor-closet-door:SEED:N (closets "
        "photographed from their opening, the camera 3-15 cm inside it, rc 0), synth-decor-hall:SEED:N (corridors "
        "0.9-1.6 m wide with doors along them, most open, rc 0) or synth-decor-open:SEED:N (rc 0, more doors, "
        "half of them wide passages to the next room, as in open plans), synth-photoreal-open:SEED:N (the same "
        "rooms path-traced and photographed); their splits are "
        "pooled, validation takes the first --validation-limit images of the pool. Or 'painted' (flat-coloured "
        "random rooms, a smoke test)",
    )
    parser.add_argument("--preset", default="compact", choices=sorted(PRESETS), help="the architecture")
    parser.add_argument(
        "--corner-base",
        type=float,
        help="the corner output's encoding base**d (default: the preset's, HorizonNet's 0.96)",
    )
    parser.add_argument(
        "--init-from",
        help="start from this model file's weights (fine-tuning) when no checkpoint is resumed "
        "(default: a random initialisation)",
    )
    parser.add_argument(
        "--steps", type=int, default=1000, help="total optimisation steps (a resumed run does the rest)"
    )
    parser.add_argument(
        "--batch", "--batch-size", dest="batch_size", type=int, default=4, metavar="N", help="images per step"
    )
    parser.add_argument(
        "--time-budget",
        type=float,
        metavar="SECONDS",
        help="stop (checkpoint, validate, export) once this much wall-clock time has passed since the command "
        "started, data preparation included; rerun the same command to continue (default: no limit)",
    )
    parser.add_argument("--checkpoint-dir", default="checkpoints/horizonnet", help="where the checkpoints go")
    parser.add_argument(
        "--render-cache",
        metavar="DIR",
        help="keep the rendered KIND:SEED:N rooms in DIR (64 a file) and read them back instead of rendering them "
        "again: a rerun starts at once, and a --time-budget that runs out while rendering keeps what was rendered "
        "for the next run (default: render in memory each run)",
    )
    parser.add_argument(
        "--render-budget",
        type=float,
        metavar="SECONDS",
        help="with --render-cache: no file of KIND:SEED:N rooms starts rendering after this much time since the "
        "command started; the training takes the rooms rendered by then (each source about the same share of its "
        "N: the source furthest behind renders next), and a rerun renders on from them. Keeps a slow renderer "
        "from spending --time-budget before any step (default: render every room first)",
    )
    parser.add_argument("--checkpoint-every", type=int, default=250, help="steps between checkpoints")
    parser.add_argument(
        "--validate-every", type=int, default=500, help="steps between validations (0: only at the end)"
    )
    parser.add_argument("--validation-limit", type=int, default=64, help="validation images (the 'valid' split)")
    parser.add_argument("--seed", type=int, default=0, help="initialisation, data order and augmentations")
    parser.add_argument("--no-resume", action="store_true", help="start afresh even if checkpoints exist")
    parser.add_argument("--history", help="write the loss and validation history to this json file (default: none)")
    parser.add_argument(
        "--export", help="also save the final weights (model only) to this .safetensors file (default: none)"
    )
    parser.add_argument(
        "--export-dtype",
        default="float32",
        choices=WEIGHTS_DTYPES,
        help="precision of the --export file; float16 halves it, read back as float32 (default: float32)",
    )
    parser.set_defaults(format_train_help=parser.format_help)
    add_config_options(
        parser,
        TrainConfig(),
        title="optimiser and augmentations (TrainConfig)",
        skip=("total_steps",),
        aliases={"peak_learning_rate": "--learning-rate"},
    )


def _render_within_budget(args: argparse.Namespace, height: int, width: int, deadline: float) -> dict[str, int]:
    """:func:`render_in_proportion` of ``--data``'s rendered sources until ``deadline``; says on stdout what the
    training takes of a source the budget left unfinished."""
    rooms_wanted = {source: synth[1] for source in args.data if (synth := parse_synth_source(source)) is not None}
    rendered_rooms = render_in_proportion(list(rooms_wanted), height, width, pathlib.Path(args.render_cache), deadline)
    unfinished = [
        f"{rooms} of {rooms_wanted[source]} rooms of {source}"
        for source, rooms in rendered_rooms.items()
        if rooms < rooms_wanted[source]
    ]
    if unfinished:
        print(f"render budget spent: training on {', '.join(unfinished)}; a rerun renders on")
    return rendered_rooms


def _batches_and_validation(args: argparse.Namespace, height: int, width: int, started: float):
    """The batches of ``--data`` and the validation on its valid images (None for the painted data), or None when
    the time budget ran out while rendering into ``--render-cache``, or the render budget left no rooms to train or
    validate on (said on stdout)."""
    if args.data == ["painted"]:
        return painted_batches(args.seed, args.batch_size, height, width), None
    deadline = None if args.time_budget is None else started + args.time_budget
    cache = None if args.render_cache is None else pathlib.Path(args.render_cache)
    try:
        rendered_rooms = None
        if args.render_budget is not None:
            rendered_rooms = _render_within_budget(args, height, width, started + args.render_budget)
        train_arrays, valid = training_data(
            args.data, height, width, args.validation_limit, cache, deadline, rendered_rooms
        )
    except RenderingStopped as stopped:
        print(f"stopped before training: {stopped}")
        return None

    def validate(model, step):
        return evaluate_arrays(model, valid)

    return folder_batches(train_arrays, args.batch_size, args.seed), validate


def _check_run_options(args: argparse.Namespace, train_config: TrainConfig) -> None:
    """A ValueError for options no run can take, before any data is read."""
    if args.steps < 1 or args.batch_size < 1:
        raise ValueError(f"--steps and --batch must be positive, got {args.steps} and {args.batch_size}")
    if args.batch_size % train_config.micro_batches:
        raise ValueError(f"--batch {args.batch_size} does not split into --micro-batches {train_config.micro_batches}")
    if args.time_budget is not None and not args.time_budget > 0:
        raise ValueError(f"--time-budget must be positive, got {args.time_budget}")
    if args.render_budget is not None and not (args.render_budget > 0 and args.render_cache):
        raise ValueError(f"--render-budget must be positive and comes with --render-cache, got {args.render_budget}")


def run_train(args: argparse.Namespace) -> int:
    """``ncjax train``: train (or resume) a preset on a dataset folder or the painted stand-in data.

    Without ``--data`` it prints its help and returns 2 (nothing is trained).
    """
    if args.data is None:
        print(args.format_train_help(), end="")
        print("ncjax train: error: give --data (dataset folders, synth:SEED:N or painted)", file=sys.stderr)
        return 2
    started = time.monotonic()
    config = HorizonNetConfig.preset(args.preset)
    if args.corner_base is not None:
        config = dataclasses.replace(config, corner_base=args.corner_base)
    if args.init_from is not None:
        check_warm_start(args.init_from, config)  # a wrong file fails here, before the data is read
    height, width = config.input_height, config.input_width
    train_config = config_from_options(args, TrainConfig(total_steps=args.steps))
    _check_run_options(args, train_config)
    prepared = _batches_and_validation(args, height, width, started)
    if prepared is None:
        return 0
    data, validate = prepared
    result = train(
        config,
        data,
        args.steps,
        args.checkpoint_dir,
        train_config=train_config,
        checkpoint_every=args.checkpoint_every,
        validate=validate,
        validate_every=args.validate_every,
        seed=args.seed,
        resume=not args.no_resume,
        initial_weights=args.init_from,
        time_budget=None if args.time_budget is None else max(0.0, args.time_budget - (time.monotonic() - started)),
    )
    losses = [h["loss"] for h in result.history if "loss" in h]
    if losses:
        print(f"step {result.step}: mean loss of the last 20 steps {np.mean(losses[-20:]):.4f}")
    for record in (h for h in result.history if "val_pe_mean" in h):
        print(
            f"step {record['step']}: valid PE {record['val_pe_mean']:.2f} px, corner precision "
            f"{record['val_precision']:.3f}, recall {record['val_recall']:.3f}"
        )
    if args.history:
        pathlib.Path(args.history).write_text(json.dumps(result.history) + "\n")
    if args.export:
        from ..network.checkpoint import save_model

        save_model(result.model, args.export, dtype=args.export_dtype)
        print(f"saved the model to {args.export} ({args.export_dtype})")
    return 0
