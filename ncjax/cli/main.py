"""The ``ncjax`` command line."""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import math
import os
import sys
from typing import NoReturn

from .arguments import DefaultsHelpFormatter, parse_size

CONVENTIONS = """\
frame      metres, right-handed, z up (revolution axis), circle of optical centres in z = 0
azimuth    varphi = pi - 2 pi (u + 0.5) / W   (decreases to the right)
elevation  phi = pi/2 - pi (v + 0.5) / H      (top row looks up)
centre     column u sees from rc (cos varphi, sin varphi, 0), rays radially outward
ray        (cos phi cos varphi, cos phi sin varphi, sin phi, rc sin phi sin varphi, -rc sin phi cos varphi, 0)
projection varphi = atan2(y, x), phi = atan2(z, sqrt(x^2 + y^2) - rc); NaN inside the circle
wall       ceiling line (ux, uy, 0, -h_c uy, h_c ux, -d), floor line the same with h_f
"""


def _info(args: argparse.Namespace) -> int:
    import jax

    import ncjax

    from ..network.weights import DEFAULT_MODEL_PATH, shipped_models
    from ..programs import SHIPPED_DIRECTORY, user_cache_directory, user_program_directory

    print(f"ncjax {ncjax.__version__}, jax {jax.__version__}, devices: {', '.join(str(d) for d in jax.devices())}")
    others = ", ".join(name for name in shipped_models() if name != DEFAULT_MODEL_PATH.stem)
    also = f"; also shipped: {others}" if others else ""
    print(f"model      {DEFAULT_MODEL_PATH.stem} (the default, {DEFAULT_MODEL_PATH}){also}")
    print(f"programs   {user_program_directory()} (traced programs kept; the package's own: {SHIPPED_DIRECTORY})")
    print(f"compiled   {user_cache_directory()} (XLA's compilation cache)")
    print(CONVENTIONS, end="")
    return 0


def _parse_rc(text: str) -> tuple[float, float]:
    parts = text.split(":")
    try:
        low, high = (float(parts[0]), float(parts[-1])) if len(parts) in (1, 2) else (None, None)
    except ValueError:
        low = high = None
    if low is None or not (math.isfinite(low) and math.isfinite(high) and 0 <= low <= high):
        raise ValueError(f"--rc must be MIN:MAX (or one value) in metres with 0 <= MIN <= MAX, got {text!r}")
    return low, high


# ncjax synth's defaults that a --kind replaces.
_SYNTH_WORLD, _SYNTH_RC, _SYNTH_SPP = "mix", "0.3:1.0", 8


def _synth(args: argparse.Namespace) -> int:
    height, width = parse_size(args.size)
    rc_range = _parse_rc(args.rc)
    if args.n < 1:
        raise ValueError(f"--n must be >= 1, got {args.n}")
    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1, got {args.batch}")
    if args.spp < 1:
        raise ValueError(f"--spp must be >= 1, got {args.spp}")
    from tqdm import tqdm

    import ncjax

    from ..synth.dataset import _check_output_directory, write_dataset
    from ..synth.photoreal import PhotorealConfig

    if args.kind is not None:
        config = _kind_config(args, height, width)
    else:
        config = ncjax.SynthConfig(
            room=ncjax.RoomConfig(world=args.world, rc_range=rc_range),
            scene=ncjax.synth.SceneConfig(decor=args.decor),
            render=ncjax.synth.RenderConfig(supersampling=args.supersampling, shadows=args.shadows),
            width=width,
            height=height,
            photoreal=_with_samples(PhotorealConfig(), args.spp) if args.photoreal else None,
        )
    _check_output_directory(args.out, args.overwrite)
    with tqdm(total=args.n, unit="pano", desc=f"ncjax synth {height}x{width}") as bar:
        names = write_dataset(args.out, args.n, args.seed, config, args.batch, args.overwrite, progress=bar.update)
    print(
        f"wrote {len(names)} samples to {args.out} (img, label_cor, 3D_gt, cam_pose, depth, semantic, json, split.json)"
    )
    return 0


def _with_samples(photoreal, samples: int):
    """The photoreal settings ``photoreal`` with ``samples`` paths a pixel."""
    return dataclasses.replace(photoreal, trace=dataclasses.replace(photoreal.trace, samples_per_pixel=samples))


def _kind_config(args: argparse.Namespace, height: int, width: int):
    """The rooms and rendering of the training source ``args.kind`` at ``height`` x ``width``, with ``--spp``
    for a photoreal one; the options that the source sets are refused."""
    from ..training.data import SYNTH_SOURCES

    if args.kind not in SYNTH_SOURCES:
        raise ValueError(f"--kind must be one of {', '.join(sorted(SYNTH_SOURCES))}; got {args.kind!r}")
    given = {
        "--world": args.world != _SYNTH_WORLD,
        "--rc": args.rc != _SYNTH_RC,
        "--decor": args.decor,
        "--photoreal": args.photoreal,
        "--shadows": args.shadows,
        "--supersampling": args.supersampling != 1,
    }
    if any(given.values()):
        options = ", ".join(name for name, set_here in given.items() if set_here)
        raise ValueError(f"--kind {args.kind} sets the rooms and their rendering: leave out {options}")
    config = dataclasses.replace(SYNTH_SOURCES[args.kind], height=height, width=width)
    if args.spp != _SYNTH_SPP:
        if config.photoreal is None:
            raise ValueError(f"--spp is for photoreal rooms, and --kind {args.kind} is ray-cast")
        config = dataclasses.replace(config, photoreal=_with_samples(config.photoreal, args.spp))
    return config


def _train(args: argparse.Namespace) -> int:
    from .train import run_train

    return run_train(args)


def _evaluate(args: argparse.Namespace) -> int:
    from .evaluate import check_evaluate_mode, run_layout_evaluation

    if check_evaluate_mode(args) == "layouts":
        return run_layout_evaluation(args)
    return _evaluate_network(args)


def _evaluate_network(args: argparse.Namespace) -> int:
    import json

    from ..network.predict import DEFAULT_MODEL_PATH, default_model
    from ..training.data import evaluate_arrays, load_split
    from .inputs import load_model_option

    model = load_model_option(args.model) if args.model else default_model()
    config = model.config
    arrays = load_split(args.data, args.split, config.input_height, config.input_width, limit=args.limit)
    row = evaluate_arrays(model, arrays, views=args.views)
    print(
        f"model {args.model or DEFAULT_MODEL_PATH}, {len(arrays['image'])} images of {args.data} ({args.split}), "
        f"{args.views} view(s) averaged"
    )
    print(f"PE {row['pe_mean']:.3f} +- {row['pe_std']:.3f} px (1024-wide)")
    print(
        f"corners: precision {row['precision']:.3f}, recall {row['recall']:.3f}, "
        f"accuracy {row['accuracy']:.3f}, IoU {row['iou']:.3f}"
    )
    if args.json:
        with open(args.json, "w") as file:
            json.dump(
                {"images": len(arrays["image"]), "data": args.data, "split": args.split, "views": args.views, **row},
                file,
                indent=1,
            )
    return 0


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``ncjax`` and its subcommands (each one's ``run`` is a default of its namespace).

    Args:
        command: the subcommand the command line names, if known: ``train``'s options (which import the
            training's modules, a tenth of a second) are only added for it or for None (all of them).
    """
    from ncjax import __version__

    from ..network.config import DEFAULT_VIEWS

    parser = argparse.ArgumentParser(
        prog="ncjax",
        description="Metric room layouts from non-central panoramas.",
        formatter_class=DefaultsHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"ncjax {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    info = commands.add_parser(
        "info",
        help="versions, devices, the default model, the cache folders and the camera conventions",
        formatter_class=DefaultsHelpFormatter,
    )
    info.set_defaults(run=_info)
    synth = commands.add_parser(
        "synth",
        help="render a synthetic dataset of non-central panoramas (authors' layout plus depth, semantics, json)",
        formatter_class=DefaultsHelpFormatter,
    )
    synth.add_argument("--n", type=int, required=True, help="number of panoramas")
    synth.add_argument("--out", required=True, help="output folder (must be new or empty)")
    synth.add_argument("--seed", type=int, default=0, help="random seed: same seed, same bytes")
    synth.add_argument(
        "--kind",
        help="the rooms of a source of ncjax train --data KIND:SEED:N (e.g. synth-decor-open, synth-decor-hall, "
        "synth-photoreal-home; ncjax train --help lists them): the same rooms and images as training renders for "
        "the same --seed and --size; --world, --rc, --decor, --photoreal, --shadows and --supersampling are the "
        "source's (default: none, the rooms those options describe)",
    )
    synth.add_argument(
        "--world",
        choices=("manhattan", "atlanta", "mix"),
        default=_SYNTH_WORLD,
        help="room model (mix: each room manhattan or atlanta at random, half and half)",
    )
    synth.add_argument("--size", default="512x1024", help="HxW in pixels")
    synth.add_argument("--rc", default=_SYNTH_RC, help="range of the radius rc in metres, MIN:MAX (0:0 is central)")
    synth.add_argument("--supersampling", type=int, default=1, help="odd s: s x s rays per pixel for the RGB image")
    synth.add_argument("--shadows", action="store_true", help="cast shadows from the furniture")
    synth.add_argument(
        "--decor",
        action="store_true",
        help="realistic rooms: open doors, posters and pictures, ceiling lights of several kinds and light panels, "
        "suspended and popcorn ceilings, sunlight, counters and desks with monitors "
        "(ncjax.synth.SceneConfig(decor=True))",
    )
    synth.add_argument(
        "--photoreal",
        action="store_true",
        help="RGB images with light as it behaves: path-traced (interreflections, area lights, windows showing "
        "real outdoor HDR panoramas and letting in their sun), denoised and developed by a camera model; about "
        "12-14 s a 512x1024 image on 2 CPU cores (ncjax.synth.PhotorealConfig)",
    )
    synth.add_argument(
        "--spp", type=int, default=_SYNTH_SPP, help="with --photoreal or a photoreal --kind: paths traced per pixel"
    )
    synth.add_argument("--batch", type=int, default=8, help="panoramas rendered per jitted call")
    synth.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty folder")
    synth.set_defaults(run=_synth)
    train = commands.add_parser(
        "train",
        help="train Non-central HorizonNet (checkpoints, resume, validation)",
        formatter_class=DefaultsHelpFormatter,
    )
    if command in (None, "train"):
        from .train import add_train_arguments

        add_train_arguments(train)
    train.set_defaults(run=_train)
    evaluate = commands.add_parser(
        "evaluate",
        help="layout metrics of predicted layout files against ground truth (PRED GT), "
        "or Table netcorExp of a model on a dataset split (--data)",
        description="ncjax evaluate PRED GT: 2D/3D IoU, corner and pixel error, depth RMSE and delta-1 of layout "
        "files (label_cor, HorizonNet, PanoAnnotator/MatterportLayout/LGT-Net, ZInD or ncjax JSON) of one image, "
        "or of two folders matched by image stem. ncjax evaluate --data DIR: the network on a dataset split.",
        formatter_class=DefaultsHelpFormatter,
    )
    evaluate.add_argument("pred", nargs="?", help="predicted layout file, or a folder of them")
    evaluate.add_argument("gt", nargs="?", help="ground-truth layout file, or a folder of them")
    evaluate.add_argument(
        "--size",
        help="HxW of the images, for layout files that record none, as label_cor (default: the size the image's "
        "other file records, else 512x1024)",
    )
    evaluate.add_argument(
        "--data",
        help="dataset folder (ncjax synth or the authors') to evaluate a network on (default: none, PRED GT "
        "are evaluated)",
    )
    evaluate.add_argument("--split", default="test", help="split of split.json, or all")
    evaluate.add_argument(
        "--model",
        help=".safetensors weights or a shipped model's name, e.g. compact1024 (default: the default model)",
    )
    evaluate.add_argument("--limit", type=int, help="evaluate the first N images only (default: all)")
    evaluate.add_argument("--json", help="also write the results to this json file (default: none)")
    evaluate.add_argument(
        "--views",
        type=int,
        default=DEFAULT_VIEWS,
        help="rolled and mirrored views the network averages (1 or even; the default is ncjax reconstruct's)",
    )
    evaluate.set_defaults(run=_evaluate)
    from .demo import add_demo_arguments, run_demo
    from .reconstruct import add_reconstruct_arguments, run_reconstruct

    reconstruct = commands.add_parser(
        "reconstruct",
        help="metric layouts of panoramas: json, mesh (obj/ply/glb), 3D viewer (html), overlay and floor-plan png",
        formatter_class=DefaultsHelpFormatter,
    )
    add_reconstruct_arguments(reconstruct)
    reconstruct.set_defaults(run=run_reconstruct)
    demo = commands.add_parser(
        "demo",
        help="reconstruct the built-in sample and compare it with its ground truth",
        formatter_class=DefaultsHelpFormatter,
    )
    add_demo_arguments(demo)
    demo.set_defaults(run=run_demo)
    from .view import add_view_arguments, run_view

    view = commands.add_parser(
        "view",
        help="serve a folder of results on this machine: an index (thumbnails, status, height, area) linking "
        "each room's 3D viewer, opened in the browser",
        formatter_class=DefaultsHelpFormatter,
    )
    add_view_arguments(view)
    view.set_defaults(run=run_view)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``ncjax`` console script.

    Returns:
        The exit code: 0 success, 1 a failure while working (an image without layout, a
        file that could not be written), 2 bad arguments or input files, 130 Ctrl-C.
        Every error is one line on stderr.
    """
    # OpenBLAS worker threads busy-wait for each other, which can stall small LAPACK
    # calls for seconds on a busy machine; it must be set before jax loads OpenBLAS.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from .inputs import one_line

    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(next((word for word in argv if not word.startswith("-")), None)).parse_args(argv)
    try:
        return args.run(args)
    except KeyboardInterrupt:
        resume = (
            f"; the same command resumes from the last checkpoint in {args.checkpoint_dir}"
            if args.command == "train" and not args.no_resume
            else ""
        )
        print(f"ncjax {args.command}: interrupted{resume}", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError) as error:
        print(f"ncjax {args.command}: error: {one_line(error)}", file=sys.stderr)
        return 2
    except OSError as error:  # a file that cannot be read or written: permissions, a full disk, ...
        print(f"ncjax {args.command}: error: {one_line(error)}", file=sys.stderr)
        return 1


# glibc's mallopt parameters, and the values the command sets (bytes)
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_MALLOC_SETTINGS = ((_M_MMAP_THRESHOLD, 32 << 20), (_M_TRIM_THRESHOLD, 256 << 20), (_M_TOP_PAD, 64 << 20))


def _allocate_in_large_steps() -> None:
    """Let glibc's malloc take memory from the system in large steps and keep it (nothing elsewhere).

    Loading a compiled program, XLA allocates and frees many blocks of a few hundred kilobytes: by default each
    is a new mapping, and the heaps grow and shrink a page at a time, tens of thousands of system calls and page
    faults on the way to the first layout (0.2 s of the 3 s of a warm ``ncjax reconstruct`` on 2 cores).
    Blocks up to 32 MB then come from the heaps, which grow 64 MB at a time and give back only what exceeds
    256 MB. Set by the command for its own process; the API leaves a caller's process as it is.
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return
    for parameter, value in _MALLOC_SETTINGS:
        mallopt(parameter, value)


def console_script() -> NoReturn:
    """The ``ncjax`` command: :func:`main`, then the process ends at once with its exit code.

    Every file is written and closed when :func:`main` returns, so Python's teardown has nothing
    left to do but free what the process loaded: on 2 CPU cores, unloading XLA's compiled programs
    and running the libraries' exit hooks add 0.5-0.9 s to every command. The programs a first run compiles in
    the background for later runs (:func:`~ncjax.reconstruction.finish_background_compilations`) are waited for.
    """
    _allocate_in_large_steps()
    code = main()
    reconstruction = sys.modules.get("ncjax.reconstruction")  # not imported by the commands that reconstruct nothing
    if reconstruction is not None and any(not future.done() for future in reconstruction._BACKGROUND):
        print("ncjax: finishing the optimised programs for later runs", file=sys.stderr)
        reconstruction.finish_background_compilations()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    console_script()
