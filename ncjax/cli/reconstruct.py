"""The user-facing commands ``ncjax reconstruct`` and ``ncjax demo``.

``reconstruct`` reads panoramas, groups them by size into fixed-size batches
(the last one padded, so each size compiles once), runs
:func:`~ncjax.reconstruction.reconstruct_batch` and writes per image
``<name>.json``, ``<name>.obj/.ply/.glb`` (when a layout was found),
``<name>_overlay.png`` and ``<name>_plan.png``, and at the end ``summary.csv``
(one line per input image: its result, heights, area, or why it failed). Every file is written to a
temporary name and renamed, so an interrupted run leaves no half-written
file. A bad image is reported and skipped; the command ends with exit code
1 and the list of failures if any image failed, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import collections
import csv
import dataclasses
import io
import json
import math
import os
import pathlib
import sys
import time
import warnings

import numpy as np

from ..io.images import PanoramaError, PanoramaResizeWarning, read_panorama
from ..network.edges import EdgeSnap
from ..network.model import check_views
from ..network.predict import DEFAULT_VIEWS
from ..pipeline.config import DEFAULT_WORLD, WORLDS
from ..pipeline.types import LayoutStatus
from ..synth.dataset import rc_from_name
from .options import add_config_options, config_from_options

WORLD_HELP = (
    "room model: manhattan (walls at right angles), atlanta (vertical walls at any angles), or auto "
    "(per panorama, the one whose layout explains more of the boundaries; default)"
)
MAX_RC = 3.0  # metres; the capture rigs have radii of tens of centimetres
DEMO_DIR = pathlib.Path(__file__).parent.parent / "data" / "demo"


def enable_compilation_cache() -> None:
    """Keep XLA's compiled programs in ``$NCJAX_CACHE`` (default ``~/.cache/ncjax/xla``) across runs.

    Compilation is most of a first run's time (tens of seconds for network +
    pipeline); the persistent cache makes later runs with the same image size,
    batch and world start at once.
    """
    import jax

    directory = os.environ.get("NCJAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "ncjax", "xla"))
    jax.config.update("jax_compilation_cache_dir", directory)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def parse_rc(text: str) -> float | None:
    """``--rc``: a radius in metres [0, MAX_RC] (0: a central panorama), or None for "auto" (from each file name)."""
    if text == "auto":
        return None
    try:
        rc = float(text)
    except ValueError:
        rc = math.nan
    if not (math.isfinite(rc) and 0.0 <= rc <= MAX_RC):
        raise ValueError(
            f"--rc must be 'auto' or the radius of the circle of optical centres in metres, "
            f"0 <= rc <= {MAX_RC} (0 for a central panorama); got {text!r}"
        )
    return rc


PRIOR_OPTIONS = {
    "camera_height": "--camera-height",
    "ceiling_height": "--ceiling-height",
    "room_height": "--room-height",
}


def height_prior(args: argparse.Namespace, rc: float | None):
    """The :class:`~ncjax.HeightPrior` the options give: the one height given, else the default
    camera height when ``--rc 0``, else None (the scale comes from the non-central geometry)."""
    from ..pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior

    given = [(kind, getattr(args, kind)) for kind in PRIOR_OPTIONS if getattr(args, kind) is not None]
    if len(given) > 1:
        raise ValueError(f"give one of {', '.join(PRIOR_OPTIONS.values())}, not several")
    if given:
        kind, value = given[0]
        if not (math.isfinite(value) and 0.0 < value <= 20.0):
            raise ValueError(f"{PRIOR_OPTIONS[kind]} must be a height in metres in (0, 20], got {value}")
        return HeightPrior(kind, value)
    return HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT) if rc == 0 else None


def scale_fields(result, prior) -> dict:
    """The JSON record's keys on the scale: where it came from, the prior, and what the geometry measured."""
    from ..io.export import status_has_geometry
    from ..reconstruction import SCALE_SOURCES

    _, _, _, _, source, geometry = result
    fields = {
        "scale_source": SCALE_SOURCES[int(source)],
        "height_prior": None if prior is None else {"kind": prior.kind, "value": float(prior.value)},
        "geometry_measured": None,
    }
    if geometry is not None and status_has_geometry(bool(geometry.ok), int(geometry.status)):
        ceiling, floor = float(geometry.ceiling_height), float(geometry.floor_height)
        fields["geometry_measured"] = {
            "status": LayoutStatus(int(geometry.status)).name,
            "camera_height": round(-floor, 4),
            "ceiling_height": round(ceiling, 4),
            "room_height": round(ceiling - floor, 4),
        }
    return fields


def radius_of(path: str, rc: float | None) -> float:
    """The radius of one image: the ``--rc`` value, or the ``_R<rc in 1e-4 m>`` of its name."""
    if rc is not None:
        return rc
    from_name = rc_from_name(pathlib.Path(path).stem)
    if from_name is None:
        raise PanoramaError(
            f"{path}: --rc auto needs the radius in the file name, e.g. L101_R06101.png for rc = 0.6101 m; "
            "pass --rc RADIUS instead"
        )
    if not 0.0 < from_name <= MAX_RC:
        raise PanoramaError(f"{path}: the radius in the file name, {from_name} m, is not in (0, {MAX_RC}] m")
    return from_name


def failure_message(record: dict) -> str:
    """Why the layout of a JSON record is not ok, for the person who ran the reconstruction."""
    status = record["status"]
    message = f"{status}: {LayoutStatus[status].reason}"
    if not record["floor_corners"]:
        return f"no layout found ({message})"
    sigma = record["room_height_sigma"]
    height = f"room height {record['room_height']:.2f} ± {sigma or math.inf:.2f} m"
    return f"layout of uncertain scale written ({message}; {height})"


MESH_SUFFIXES = ("obj", "ply", "glb")
SUMMARY_FILE = "summary.csv"
SUMMARY_COLUMNS = (
    "file",
    "name",
    "result",
    "status",
    "corners",
    "room_height_m",
    "room_height_sigma_m",
    "ceiling_height_m",
    "floor_height_m",
    "floor_area_m2",
    "perimeter_m",
    "branch",
    "rc_m",
    "scale_source",
    "message",
)
# summary.csv's columns taken from the JSON record's keys
SUMMARY_FIGURES = {
    "room_height_m": "room_height",
    "room_height_sigma_m": "room_height_sigma",
    "ceiling_height_m": "ceiling_height",
    "floor_height_m": "floor_height",
    "floor_area_m2": "floor_area",
    "perimeter_m": "perimeter",
    "rc_m": "rc",
}


def summary_row(path: str, record: dict | None, message: str = "") -> dict:
    """One image's line of ``summary.csv``: its layout's figures from the JSON record, or why it has none.

    Args:
        path: the input file as given.
        record: its JSON record (:func:`write_outputs`), or None when it has none (unreadable file,
            missing radius, failed batch).
        message: why the image has no ok layout ("" when it has one).

    Returns:
        The row, keyed by ``SUMMARY_COLUMNS``. ``result`` is "ok", "uncertain scale" (geometry
        written, scale unsure), "no layout" (the pipeline found none) or "error" (no record).
        Figures have 4 decimals; a layout's room-height sigma that the fit leaves open (JSON null)
        is "inf", as the CLI prints it; empty cells are figures the image does not have.
    """
    row = dict.fromkeys(SUMMARY_COLUMNS, "") | {"file": path, "name": pathlib.Path(path).stem, "message": message}
    if record is None:
        return row | {"result": "error"}
    written = bool(record["floor_corners"])
    figures = {column: "" if record[key] is None else f"{record[key]:.4f}" for column, key in SUMMARY_FIGURES.items()}
    if written and record["room_height_sigma"] is None:
        figures["room_height_sigma_m"] = "inf"
    return (
        row
        | figures
        | {
            "result": "ok" if record["ok"] else "uncertain scale" if written else "no layout",
            "status": record["status"],
            "corners": len(record["floor_corners"]) if written else "",
            "branch": record["branch"] if written else "",
            "scale_source": record.get("scale_source", "") if written else "",
        }
    )


def write_summary(path: str, rows: list[dict]) -> None:
    """``summary.csv``: one line per input image (:func:`summary_row`), written atomically."""
    from ..io.files import write_atomic

    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_atomic(path, text.getvalue().encode("utf-8"))


def output_names(name: str) -> tuple[str, ...]:
    """The names of every file :func:`write_outputs` can write for the image ``name`` (JSON first)."""
    from ..io.formats import FORMATS, SUFFIXES

    return (
        f"{name}.json",
        *(f"{name}.{suffix}" for suffix in MESH_SUFFIXES),
        f"{name}_overlay.png",
        f"{name}_plan.png",
        *(f"{name}{SUFFIXES[format]}" for format in FORMATS),
    )


def write_outputs(
    out: str,
    name: str,
    image: np.ndarray,
    result,
    rc: float,
    world: str,
    extra: dict | None = None,
    export: tuple[str, ...] = (),
    prior=None,
    gravity: dict | None = None,
):
    """All files of one image, which appear together or not at all; returns the JSON record.

    The files are written into a hidden staging folder inside ``out`` and renamed into
    ``out`` at the end, ``<name>.json`` last (:func:`ncjax.io.files.replace_together`):
    an error or a Ctrl-C before the renames leaves nothing of this run in ``out``. Every
    earlier output of ``name`` is replaced or removed: the meshes and the layout formats
    exist only when the layout has geometry, and a format only when ``export`` names it.

    ``export`` names layout formats (:data:`ncjax.io.formats.FORMATS`) written beside the
    JSON when the layout has geometry. ``gravity`` (:func:`align_to_gravity`) says how the
    image was levelled: the JSON, the mesh and the metric formats are in the levelled frame
    (z up), the corner pixels of label_cor and HorizonNet's json in the input image's.
    """
    from ..geometry.camera import NonCentralPanorama
    from ..io.export import has_geometry, layout_record, write_json, write_png
    from ..io.files import replace_together
    from ..io.formats import write_layout_formats
    from ..io.mesh import write_mesh
    from ..viz.overlay import draw_overlay
    from ..viz.plan import draw_plan

    layout, ceiling_v, floor_v, corner_prob, *_ = result
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc=rc)
    extra = (extra or {}) | scale_fields(result, prior) | {"gravity": gravity}
    record = layout_record(layout, cam, name=name, world=world, extra=extra)
    with replace_together(out, owned=output_names(name), last=f"{name}.json") as staging:
        stem = os.path.join(staging, name)
        write_json(f"{stem}.json", record)
        if has_geometry(layout):
            write_mesh(stem, layout)
            try:
                if export:
                    rotation = None if gravity is None or gravity["rotation"] is None else np.array(gravity["rotation"])
                    write_layout_formats(stem, record, cam, export, rotation=rotation)
            except ValueError as error:  # a corner no ray sees: the other outputs still describe the layout
                print(f"{name}: layout formats not written ({error})", file=sys.stderr)
        overlay = draw_overlay(image, layout, cam, ceiling_v=ceiling_v, floor_v=floor_v, corner_prob=corner_prob)
        write_png(f"{stem}_overlay.png", overlay)
        write_png(f"{stem}_plan.png", draw_plan(layout, title=name, rc=rc))
    return record


@dataclasses.dataclass(frozen=True)
class ReconstructSettings:
    """What ``ncjax reconstruct`` does with every image (from its options)."""

    model: object
    batch_size: int
    world: str
    config: object
    views: int
    edge_snap: EdgeSnap | None
    out: str
    export: tuple[str, ...]
    prior: object


def align_to_gravity(image: np.ndarray) -> tuple[np.ndarray, dict]:
    """A central panorama levelled (:mod:`ncjax.io.align`), and the JSON record of its tilt.

    An image whose vertical the line segments do not fix reliably is kept as it is (``reliable`` false).
    """
    from ..io.align import estimate_tilt, level_panorama

    estimate = estimate_tilt(image)
    record = {"reliable": estimate.reliable, "segments": int(estimate.segments), "roll_deg": None, "pitch_deg": None}
    if not estimate.reliable:
        return image, record | {"rotation": None}
    rotation = np.asarray(estimate.rotation)
    levelled = level_panorama(image, rotation)
    record |= {"roll_deg": round(float(estimate.roll), 3), "pitch_deg": round(float(estimate.pitch), 3)}
    return levelled, record | {"rotation": np.round(rotation, 8).tolist()}


def _reconstruct_group(settings: ReconstructSettings, items, on_done, on_error):
    """Reconstruct same-size images in fixed-size batches.

    Calls ``on_done(path, record)`` after each image, or ``on_error(path, message)``
    for each image of a batch whose reconstruction raised (XLA out of memory,
    say): the other batches go on.
    """
    import jax

    from ..reconstruction import reconstruct_batch

    batch_size = settings.batch_size
    for start in range(0, len(items), batch_size):
        chunk = items[start : start + batch_size]
        padding = [chunk[-1]] * (batch_size - len(chunk))
        images = np.stack([image for _, _, image, _, _ in chunk + padding])
        radii = np.array([rc for _, _, _, rc, _ in chunk + padding], np.float32)
        try:
            result = jax.device_get(
                reconstruct_batch(
                    images,
                    radii,
                    settings.world,
                    model=settings.model,
                    config=settings.config,
                    views=settings.views,
                    edge_snap=settings.edge_snap,
                    prior=settings.prior,
                )
            )
        except RuntimeError as error:  # XLA's errors (out of memory, ...): reported per image, the next batch goes on
            first_line = (str(error).strip().splitlines() or [""])[0]
            hint = "; try a smaller --batch" if "RESOURCE_EXHAUSTED" in first_line and batch_size > 1 else ""
            for path, *_ in chunk:
                on_error(path, f"{path}: the reconstruction failed ({type(error).__name__}: {first_line}){hint}")
            continue
        for index, (path, name, image, rc, gravity) in enumerate(chunk):
            one = jax.tree.map(lambda x: x[index], tuple(result))
            record = write_outputs(
                settings.out,
                name,
                image,
                one,
                float(rc),
                settings.world,
                export=settings.export,
                prior=settings.prior,
                gravity=gravity,
            )
            on_done(path, record)


def run_reconstruct(args: argparse.Namespace) -> int:
    """``ncjax reconstruct IMAGES... --rc RC|auto --out DIR``."""
    from tqdm import tqdm

    from ..network.checkpoint import load_model
    from ..network.predict import default_model

    rc = parse_rc(args.rc)
    prior = height_prior(args, rc)
    check_views(args.views)
    config = pipeline_config(args)
    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1, got {args.batch}")
    names = [pathlib.Path(path).stem for path in args.images]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"several images would write the same outputs: {', '.join(repeated)} (rename them)")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out!r} exists and is not a folder")
    model = load_model(args.model) if args.model else default_model()
    settings = ReconstructSettings(
        model, args.batch, args.world, config, args.views, args.edge_snap, args.out, args.export, prior
    )
    os.makedirs(args.out, exist_ok=True)
    enable_compilation_cache()

    summary: dict[str, dict] = {}  # path -> its summary.csv row, in the order the images finished
    groups: dict[tuple[int, int], list] = collections.defaultdict(list)
    bar = tqdm(total=len(args.images), unit="image", desc="ncjax reconstruct")

    def done(path, record):
        message = "" if record["ok"] else f"{failure_message(record)}; see {record['name']}_overlay.png"
        summary[path] = summary_row(path, record, message)
        bar.update()

    def failed(path, message):
        summary[path] = summary_row(path, None, message.removeprefix(f"{path}: "))
        bar.update()

    for path, name in zip(args.images, names, strict=True):
        try:
            with warnings.catch_warnings(record=True) as notes:
                warnings.simplefilter("always", PanoramaResizeWarning)
                image = read_panorama(path)
            for note in notes:
                if issubclass(note.category, PanoramaResizeWarning):
                    bar.write(str(note.message), file=sys.stderr)
                else:
                    warnings.showwarning(note.message, note.category, note.filename, note.lineno)
            radius = radius_of(path, rc)
        except PanoramaError as error:
            failed(path, str(error))
            continue
        # a tilted non-central rig cannot be levelled by resampling its image: only central panoramas are
        image, gravity = align_to_gravity(image) if radius == 0 and args.align else (image, None)
        group = groups[image.shape[:2]]
        group.append((path, name, image, radius, gravity))
        if len(group) == args.batch:
            _reconstruct_group(settings, group, done, failed)
            group.clear()
    for group in groups.values():
        if group:
            _reconstruct_group(settings, group, done, failed)
    bar.close()
    write_summary(os.path.join(args.out, SUMMARY_FILE), [summary[path] for path in args.images])
    failures = [f"{path}: {row['message']}" for path, row in summary.items() if row["message"]]
    succeeded = len(args.images) - len(failures)
    print(
        f"{succeeded} of {len(args.images)} images reconstructed into {args.out} (one line per image: {SUMMARY_FILE})"
    )
    if failures:
        print(f"{len(failures)} failed:", file=sys.stderr)
        for reason in failures:
            print(f"  {reason}", file=sys.stderr)
        return 1
    return 0


def run_demo(args: argparse.Namespace) -> int:
    """``ncjax demo``: reconstruct the shipped sample and compare it with its ground truth."""
    import jax

    from .. import metrics
    from ..reconstruction import reconstruct_batch

    start = time.perf_counter()
    enable_compilation_cache()
    with open(DEMO_DIR / "ground_truth.json") as file:
        truth = json.load(file)
    path = DEMO_DIR / truth["image"]
    image = read_panorama(path)
    rc = radius_of(str(path), None)
    os.makedirs(args.out, exist_ok=True)
    print(
        f"ncjax demo: {truth['image']} ({image.shape[1]} x {image.shape[0]}, rc = {rc} m from its name, "
        f"a {truth['world']} room rendered by ncjax synth and never seen in training)"
    )
    result = jax.device_get(
        reconstruct_batch(
            image[None],
            np.array([rc], np.float32),
            args.world,
            config=pipeline_config(args),
            views=args.views,
            edge_snap=args.edge_snap,
        )
    )
    one = jax.tree.map(lambda x: x[0], tuple(result))
    record = write_outputs(args.out, pathlib.Path(truth["image"]).stem, image, one, rc, args.world, export=args.export)
    elapsed = time.perf_counter() - start
    if not record["ok"]:
        print(failure_message(record), file=sys.stderr)
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
    print(f"outputs in {os.path.abspath(args.out)}/ (json, obj/ply/glb mesh, overlay and plan png); {elapsed:.0f} s")
    return 0


def add_reconstruct_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("images", nargs="+", help="panorama files (full 360 x 180 degrees, width = 2 x height)")
    parser.add_argument(
        "--rc",
        required=True,
        help="radius in metres (0: a central panorama, scale from a height prior), or 'auto' to read it from "
        "the names (_R06101)",
    )
    parser.add_argument("--out", required=True, help="output folder (created if needed)")
    parser.add_argument("--world", choices=WORLDS, default=DEFAULT_WORLD, help=WORLD_HELP)
    parser.add_argument("--model", help="network weights (.safetensors); default: the shipped model")
    parser.add_argument("--batch", type=int, default=4, help="images per jitted call (default 4)")
    add_prior_arguments(parser)
    parser.add_argument(
        "--no-align",
        dest="align",
        action="store_false",
        help="keep a central panorama as it is; by default its roll and pitch are estimated from the image's "
        "lines and undone before the network (the JSON records them)",
    )
    add_export_argument(parser)
    add_boundary_arguments(parser)
    add_pipeline_arguments(parser)


def add_prior_arguments(parser: argparse.ArgumentParser) -> None:
    """``--camera-height``, ``--ceiling-height``, ``--room-height``: a height that fixes the scale."""
    from ..pipeline.prior import DEFAULT_CAMERA_HEIGHT

    group = parser.add_argument_group(
        "height prior (the scale of a central panorama; with rc > 0 used only where the geometry cannot fix it)"
    )
    group.add_argument(
        "--camera-height",
        dest="camera_height",
        type=float,
        help=f"camera above the floor, metres (default with --rc 0: {DEFAULT_CAMERA_HEIGHT}, as HorizonNet)",
    )
    group.add_argument("--ceiling-height", dest="ceiling_height", type=float, help="ceiling above the camera, metres")
    group.add_argument("--room-height", dest="room_height", type=float, help="floor to ceiling, metres")


def parse_export(text: str) -> tuple[str, ...]:
    """``--export``: a comma list of layout formats (an unknown name is an argparse error)."""
    from ..io.formats import check_formats

    try:
        return check_formats(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def add_export_argument(parser: argparse.ArgumentParser) -> None:
    """``--export FORMATS``: the layout also as label_cor, HorizonNet, PanoAnnotator (mp3d) or ZInD files."""
    parser.add_argument(
        "--export",
        type=parse_export,
        default=(),
        metavar="FORMATS",
        help="also write the layout for central-panorama tools, a comma list of label_cor (HorizonNet's corner "
        "pixels), horizonnet (HorizonNet's inference json), mp3d (PanoAnnotator / MatterportLayout / LGT-Net "
        "json) and zind (ZInD json): <name>.label_cor.txt, <name>.horizonnet.json, ...",
    )


def add_boundary_arguments(parser: argparse.ArgumentParser) -> None:
    """``--views`` and ``--no-edge-snap``: how the network's boundaries are made (the CLI and the experiments)."""
    parser.add_argument(
        "--views",
        type=int,
        default=DEFAULT_VIEWS,
        help=f"rolled and mirrored views the network averages (1 or even; default {DEFAULT_VIEWS}): "
        "more is more accurate and slower",
    )
    parser.add_argument(
        "--no-edge-snap",
        dest="edge_snap",
        action="store_const",
        const=None,
        default=EdgeSnap(),
        help="use the network's boundary rows as they are, not snapped to the image's edges",
    )


def add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="ncjax_demo", help="output folder (default ./ncjax_demo)")
    parser.add_argument("--world", choices=WORLDS, default=DEFAULT_WORLD, help=WORLD_HELP)
    add_export_argument(parser)
    add_boundary_arguments(parser)
    add_pipeline_arguments(parser)


def add_pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    """Every :class:`~ncjax.PipelineConfig` setting as an option, from the network's configuration."""
    from ..reconstruction import NETWORK_PIPELINE_CONFIG

    add_config_options(
        parser, NETWORK_PIPELINE_CONFIG, title="pipeline settings (PipelineConfig; defaults: NETWORK_PIPELINE_CONFIG)"
    )


def pipeline_config(args: argparse.Namespace):
    """The :class:`~ncjax.PipelineConfig` the options give (a ValueError names a bad value)."""
    from ..reconstruction import NETWORK_PIPELINE_CONFIG

    return config_from_options(args, NETWORK_PIPELINE_CONFIG)
