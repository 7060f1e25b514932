"""The user-facing command ``ncjax reconstruct``.

``reconstruct`` reads panoramas (files, or folders of them), groups them by size into
batches of ``--batch`` (the run's first image alone, so that its files come soonest; a batch short of
``--batch`` padded by :func:`~ncjax.reconstruction.reconstruct_batch`, so each size compiles once), runs
:func:`~ncjax.reconstruction.reconstruct_batch` and writes per image
``<name>.json``, ``<name>.obj/.ply/.glb`` and the 3D viewer ``<name>.html`` (when a layout was found),
``<name>_overlay.png`` and ``<name>_plan.png``, and at the end ``summary.csv``
(one line per image: its result, heights, area, or why it failed; the lines of other
images of an earlier summary in the folder are kept).

An image's files appear together or not at all (written under temporary names, then
renamed), and they replace or remove every earlier output of that image. The output
folder is checked writable before any work. ``--skip-existing`` resumes a batch. Ctrl-C
stops after the batch in progress and writes the summary of what finished (exit code
130). A bad image is reported and skipped; the command ends with exit code 1 and the
list of failures if any image failed, 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import os
import pathlib
import signal
import sys
import threading

import numpy as np

from ..io.images import PanoramaError
from ..network.config import DEFAULT_VIEWS, AdaptConfig, check_views
from ..network.edges import EdgeSnap
from ..pipeline.config import DEFAULT_WORLD, RENAMED, WORLDS
from ..reconstruction import DEFAULT_BATCH_SIZE
from .arguments import add_texture_argument
from .compilation import CompileLedger, enable_compilation_cache, settings_key
from .inputs import (
    PANORAMA_SUFFIXES,
    PendingImage,
    check_output_folder,
    expand_inputs,
    height_prior,
    make_output_folder,
    model_weights_option,
    one_line,
    parse_rc,
    read_image,
)
from .options import add_config_options, add_renamed_options, config_from_options
from .outputs import (
    MIN_RIG_TILT,
    ReconstructedImage,
    align_to_gravity,
    import_mesh_modules_in_background,
    write_outputs,
)
from .summary import SUMMARY_FILE, failure_message, read_summary, skipped_row, summary_row, update_summary

WORLD_HELP = (
    "room model: manhattan (walls at right angles), atlanta (vertical walls at any angles), or auto "
    "(per panorama, the one whose layout explains more of the boundaries; default); a layout that explains too "
    "few of them (LOW_CONFIDENCE) is replaced by walls read robustly off the floor boundary (branch plan)"
)


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
    texture_size: int | None = None
    adapt: object = None


def program_key(shape: tuple[int, ...], settings: ReconstructSettings) -> str:
    """:func:`~.compilation.settings_key` of the programs that reconstruct a batch of ``shape`` (its images'
    (batch, H, W, 3)) with ``settings``, central or not (they share them)."""
    from ..pipeline.config import static_structure

    parts = (
        settings.model.config,
        settings.world,
        settings.views,
        settings.edge_snap,
        static_structure(settings.config),
        settings.adapt,
    )
    return settings_key(shape, *parts)


def _reconstruct_group(
    settings: ReconstructSettings, items: list[PendingImage], on_done, on_error, ledger: CompileLedger, say
):
    """Reconstruct same-size images in fixed-size batches.

    Calls ``on_done(path, record)`` after each image, or ``on_error(path, message)``
    for each image of a batch whose reconstruction raised (XLA out of memory,
    say) and for an image whose files could not be written (a full disk, say):
    the other images and batches go on. Before a batch whose program this machine has not
    compiled yet (``ledger``), ``say`` prints that it compiles and for about how long.
    """
    import jax

    from ..reconstruction import reconstruct_batch

    batch_size = settings.batch_size
    for start in range(0, len(items), batch_size):
        chunk = items[start : start + batch_size]
        images = np.stack([item.image for item in chunk])
        radii = np.array([item.rc for item in chunk], np.float32)
        key = program_key((batch_size, *images.shape[1:]), settings)
        try:
            size = f"{images.shape[2]} x {images.shape[1]}"
            what = f"the network (its adaptation where asked) and the geometry for {size}"
            with ledger.compiling(key, what, say):
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
                        program_cache=True,
                        batch_size=batch_size,
                        adapt=settings.adapt,
                    )
                )
        except RuntimeError as error:  # XLA's errors (out of memory, ...): reported per image, the next batch goes on
            first_line = (str(error).strip().splitlines() or [""])[0]
            hint = "; try a smaller --batch" if "RESOURCE_EXHAUSTED" in first_line and batch_size > 1 else ""
            for item in chunk:
                on_error(
                    item.path, f"{item.path}: the reconstruction failed ({type(error).__name__}: {first_line}){hint}"
                )
            continue
        for index, (path, name, image, rc, gravity, file_size, sphere_crop) in enumerate(chunk):
            one = jax.tree.map(lambda x: x[index], tuple(result))
            try:
                record = write_outputs(
                    settings.out,
                    ReconstructedImage(name, image, one, float(rc), gravity, file_size, sphere_crop),
                    settings.world,
                    export=settings.export,
                    prior=settings.prior,
                    texture_size=settings.texture_size,
                )
            except (OSError, ValueError) as error:  # nothing of this image was written (write_outputs)
                on_error(path, f"{path}: its outputs could not be written ({one_line(error)})")
                continue
            on_done(path, record)


class StopRequest:
    """Ctrl-C as a request to stop at the next safe point, where the caller calls :meth:`check`.

    Inside the ``with`` block, the first SIGINT only sets :attr:`requested` (and calls
    ``on_request``): the work in progress (an XLA call, writing a batch's files) ends
    normally, and :meth:`check` then raises KeyboardInterrupt. A second SIGINT raises
    KeyboardInterrupt at once. Outside the main thread, where Python delivers no
    signals, it changes nothing.
    """

    def __init__(self, on_request=None):
        self.requested = False
        self._on_request = on_request
        self._installed = False
        self._previous = None

    def __enter__(self) -> StopRequest:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
            self._installed = True
        return self

    def __exit__(self, *exception) -> None:
        if self._installed:
            # None: a handler installed outside Python, which cannot be put back; Python's own then
            signal.signal(signal.SIGINT, signal.default_int_handler if self._previous is None else self._previous)
            self._installed = False

    def _handle(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        if self._on_request is not None:
            self._on_request()

    def check(self) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed."""
        if self.requested:
            raise KeyboardInterrupt


def image_names(images: list[str]) -> list[str]:
    """The name of each image's outputs, its file's stem (a ValueError if two images would write the same files)."""
    names = [pathlib.Path(path).stem for path in images]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"several images would write the same outputs: {', '.join(repeated)} (rename them)")
    return names


class RunTally:
    """What ``ncjax reconstruct`` has done: each image's ``summary.csv`` row, the failures, and the progress bar.

    :meth:`done`, :meth:`failed` and :meth:`skipped` record one image each; :meth:`finish` or
    :meth:`interrupted` writes the summary and prints the run's last lines.
    """

    def __init__(self, images: list[str], out: str, bar):
        self.images, self.out, self.bar = images, out, bar
        self.adapted = 0  # images whose rows the network adapted to them read
        self.summary: dict[str, dict] = {}  # path -> its summary.csv row
        self.failures: list[str] = []
        self.summary_path = os.path.join(out, SUMMARY_FILE)

    def done(self, path: str, record: dict) -> None:
        """An image reconstructed and its files written (its layout may have failed: ``record["ok"]``)."""
        message = "" if record["ok"] else f"{failure_message(record)}; see {record['name']}_overlay.png"
        self.summary[path] = summary_row(path, record, message)
        self.adapted += bool(record.get("adapted"))
        if message:
            self.failures.append(f"{path}: {message}")
        self.bar.update()

    def failed(self, path: str, message: str) -> None:
        """An image without outputs, ``message`` saying why."""
        self.summary[path] = summary_row(path, None, message.removeprefix(f"{path}: "))
        self.failures.append(f"{path}: {self.summary[path]['message']}")
        self.bar.update()

    def skipped(self, path: str, name: str) -> None:
        """An image left out because its ``<name>.json`` exists (``--skip-existing``)."""
        self.summary[path] = skipped_row(path, os.path.join(self.out, f"{name}.json"))
        self.bar.update()

    def stopping(self) -> None:
        """Ctrl-C was pressed once: say so on the bar."""
        self.bar.set_description("ncjax reconstruct: stopping after this batch (Ctrl-C again: at once)")

    def interrupted(self) -> int:
        """Write the summary of the images done so far; returns 130."""
        self.bar.close()
        update_summary(self.summary_path, [self.summary[path] for path in self.images if path in self.summary])
        print(
            f"interrupted: {len(self.summary)} of {len(self.images)} images done; {self.summary_path} lists them",
            file=sys.stderr,
        )
        return 130

    def finish(self) -> int:
        """Write the summary of every image and print the counts and the failures; returns 0, or 1 after failures."""
        self.bar.close()
        update_summary(self.summary_path, [self.summary[path] for path in self.images])
        skipped = sum(row["result"] == "skipped" for row in self.summary.values())
        succeeded = len(self.images) - len(self.failures) - skipped
        skipped_note = f", {skipped} skipped (their .json existed)" if skipped else ""
        adapted_note = (
            f"; {self.adapted} read by the network adapted to their own flat floor and ceiling" if self.adapted else ""
        )
        print(
            f"{succeeded} of {len(self.images)} images reconstructed into {self.out}{skipped_note} "
            f"(one line per image: {SUMMARY_FILE}){adapted_note}"
        )
        if self.failures:
            statuses = any(row["reason"] and row["result"] != "skipped" for row in self.summary.values())
            hint = f" (what each status means: {SUMMARY_FILE}'s reason column)" if statuses else ""
            print(f"{len(self.failures)} failed{hint}:", file=sys.stderr)
            for reason in self.failures:
                print(f"  {reason}", file=sys.stderr)
            return 1
        return 0


def run_reconstruct(args: argparse.Namespace) -> int:
    """``ncjax reconstruct IMAGES_OR_FOLDERS... --rc RC|auto --out DIR``.

    Returns:
        0 when every image of this run gave a layout (or was skipped), 1 when some did not, 130 after
        Ctrl-C (the images done so far are in ``summary.csv``).
    """
    from tqdm import tqdm

    rc = parse_rc(args.rc)
    prior = height_prior(args)
    check_views(args.views)
    config = pipeline_config(args)
    if args.batch < 1:
        raise ValueError(f"--batch must be >= 1, got {args.batch}")
    images = expand_inputs(args.images, args.recursive, out=args.out)
    names = image_names(images)
    check_output_folder(args.out)
    # an earlier summary.csv that cannot be merged stops the run before any work
    read_summary(os.path.join(args.out, SUMMARY_FILE))
    model = model_weights_option(args.model)
    if not args.adapt_max_rc >= 0:
        raise ValueError(f"--adapt-max-rc must be >= 0, got {args.adapt_max_rc}")
    adapt = AdaptConfig(max_rc=args.adapt_max_rc) if args.adapt else None
    make_output_folder(args.out)  # only now that the inputs and the model are good
    settings = ReconstructSettings(
        model,
        args.batch,
        args.world,
        config,
        args.views,
        args.edge_snap,
        args.out,
        args.export,
        prior,
        args.texture_size,
        adapt,
    )
    ledger = CompileLedger(enable_compilation_cache())
    import_mesh_modules_in_background()
    bar = tqdm(total=len(images), unit="image", desc="ncjax reconstruct")
    tally = RunTally(images, args.out, bar)

    def reconstruct(group):
        from ..reconstruction import background_compilations_deferred

        # what a first run compiles for later runs waits until this group's files are written
        with background_compilations_deferred():
            _reconstruct_group(settings, group, tally.done, tally.failed, ledger, tally.bar.write)

    groups: dict[tuple[int, int], list] = collections.defaultdict(list)
    # the run's first image goes alone (padded: the same programs), so that its files appear after one image's
    # work, not a whole batch's
    batch_size = 1
    try:
        with StopRequest(on_request=tally.stopping) as stop:
            for path, name in zip(images, names, strict=True):
                if args.skip_existing and os.path.exists(os.path.join(args.out, f"{name}.json")):
                    tally.skipped(path, name)
                    continue
                try:
                    panorama, radius = read_image(
                        path, rc, lambda line: tally.bar.write(line, file=sys.stderr), args.pad_to_sphere
                    )
                except PanoramaError as error:
                    tally.failed(path, str(error))
                    stop.check()
                    continue
                # a rig levelled by resampling keeps its optical centres on the tilted circle, which leaves about
                # rc / range of its tilt (experiments/rig_tilt.py): far less than the tilt itself, if that is not tiny
                min_tilt = MIN_RIG_TILT if radius > 0 else 0.0
                image, gravity = align_to_gravity(panorama.image, min_tilt) if args.align else (panorama.image, None)
                group = groups[image.shape[:2]]
                group.append(PendingImage(path, name, image, radius, gravity, panorama.file_size, panorama.crop))
                if len(group) == batch_size:
                    reconstruct(group)
                    group.clear()
                    batch_size = settings.batch_size
                stop.check()
            for group in groups.values():
                if group:
                    reconstruct(group)
                    stop.check()
    except KeyboardInterrupt:
        return tally.interrupted()
    return tally.finish()


def add_reconstruct_arguments(parser: argparse.ArgumentParser) -> None:
    kinds = ", ".join(suffix.removeprefix(".") for suffix in PANORAMA_SUFFIXES)
    parser.add_argument(
        "images",
        nargs="+",
        help="panorama files (full 360 x 180 degrees, width = 2 x height), or folders: their panorama files "
        f"({kinds}, sorted by name)",
    )
    parser.add_argument(
        "--recursive", action="store_true", help="a folder also gives the panoramas of its subfolders, at any depth"
    )
    parser.add_argument(
        "--rc",
        required=True,
        help="radius in metres (0: a central panorama, scale from a height prior), or 'auto' to read it from "
        "the names (_R06101)",
    )
    parser.add_argument("--out", required=True, help="output folder (created if needed)")
    parser.add_argument(
        "--skip-existing",
        action="store_true",
        help="skip the images whose <name>.json is already in --out (to resume a batch); summary.csv lists them "
        "as skipped, with the figures of that record",
    )
    parser.add_argument("--world", choices=WORLDS, default=DEFAULT_WORLD, help=WORLD_HELP)
    parser.add_argument(
        "--model",
        help="network weights (.safetensors) or a shipped model's name, e.g. compact1024 (default: the default model)",
    )
    parser.add_argument(
        "--batch",
        type=int,
        default=DEFAULT_BATCH_SIZE,
        help="panoramas per call of the geometry's programs (a smaller last batch is padded: any number of "
        "images runs the same programs)",
    )
    add_prior_arguments(parser)
    parser.add_argument(
        "--no-align",
        dest="align",
        action="store_false",
        help="keep a panorama as it is; by default its roll and pitch are estimated from the image's lines and "
        "undone before the network (the JSON records them): exactly for a central panorama, to about rc / range of "
        f"its tilt for a rig's (one tilted by less than {MIN_RIG_TILT:g} degrees is kept as it is)",
    )
    parser.add_argument(
        "--pad-to-sphere",
        action="store_true",
        help="a panorama wider than 2:1 without photo-sphere metadata goes all the way round but not up to the "
        "poles: pad it with black above and below to the full sphere, taking its rows as centred on the horizon "
        "(square pixels); one whose XMP GPano metadata says where it lies is padded there without this option, and "
        "the outputs' pixels are those of the full panorama (the JSON's sphere_crop gives the file's place in it)",
    )
    add_export_argument(parser)
    add_texture_argument(parser)
    add_boundary_arguments(parser)
    parser.add_argument(
        "--adapt",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="where the network's boundaries do not see one flat floor and ceiling, fit the network to the "
        "panorama's own (a few gradient steps of the backbone's batch norms, no labels) and read them again: on "
        "real photographs the rows come 2-3 px nearer the walls' true edges, for about 3 s more per 1024 x 512 "
        "image so adapted on 2 CPU cores; --no-adapt reads every panorama with the network as trained",
    )
    parser.add_argument(
        "--adapt-max-rc",
        type=float,
        default=AdaptConfig().max_rc,
        metavar="M",
        help="adapt only panoramas whose circle of optical centres is at most this radius in metres (0: central "
        "ones; inf: the rig's too, which the one real capture measured did not gain from)",
    )
    add_pipeline_arguments(parser)


def add_prior_arguments(parser: argparse.ArgumentParser) -> None:
    """``--camera-height``, ``--ceiling-height``, ``--room-height``: a height that fixes the scale."""
    from ..pipeline.prior import DEFAULT_CAMERA_HEIGHT

    group = parser.add_argument_group(
        "height prior (the scale of a central panorama; with rc > 0 used only where the geometry cannot fix "
        "the scale, and the JSON says so)"
    )
    group.add_argument(
        "--camera-height",
        dest="camera_height",
        type=float,
        help=f"camera above the floor, metres (default {DEFAULT_CAMERA_HEIGHT}, as HorizonNet)",
    )
    group.add_argument(
        "--ceiling-height", dest="ceiling_height", type=float, help="ceiling above the camera, metres (default: none)"
    )
    group.add_argument("--room-height", dest="room_height", type=float, help="floor to ceiling, metres (default: none)")


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
        "json) and zind (ZInD json): <name>.label_cor.txt, <name>.horizonnet.json, ... (default: none)",
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


def add_pipeline_arguments(parser: argparse.ArgumentParser) -> None:
    """Every :class:`~ncjax.PipelineConfig` setting as an option, from the network's configuration."""
    from ..reconstruction import NETWORK_PIPELINE_CONFIG

    add_config_options(
        parser,
        NETWORK_PIPELINE_CONFIG,
        title="pipeline settings (PipelineConfig; defaults: NETWORK_PIPELINE_CONFIG)",
        skip=("prior.room_height",),  # the height prior's route sets it (--camera-height and kin)
    )
    add_renamed_options(parser, RENAMED)


def pipeline_config(args: argparse.Namespace):
    """The :class:`~ncjax.PipelineConfig` the options give (a ValueError names a bad value)."""
    from ..reconstruction import NETWORK_PIPELINE_CONFIG

    return config_from_options(args, NETWORK_PIPELINE_CONFIG)
