"""What ``ncjax reconstruct`` reads: its options (radius, height prior, model), its image files and folders."""

from __future__ import annotations

import argparse
import math
import os
import pathlib
import tempfile
import warnings
from typing import NamedTuple

import numpy as np

from ..io.images import (
    PANORAMA_SUFFIXES,
    PanoramaDevelopedWarning,
    PanoramaError,
    PanoramaFile,
    PanoramaResizeWarning,
    rc_from_name,
    read_panorama_file,
)
from ..io.photo_sphere import SphereCrop

MAX_RC = 3.0  # metres; the capture rigs have radii of tens of centimetres


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


def height_prior(args: argparse.Namespace):
    """The :class:`~ncjax.HeightPrior` the options give: the one height given, else the default camera height.

    It is the scale of a central panorama (``rc = 0``), and of a non-central one only where the
    geometry cannot fix the scale (:data:`ncjax.reconstruction.SCALE_FAILURES`)."""
    from ..pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior

    given = [(kind, getattr(args, kind)) for kind in PRIOR_OPTIONS if getattr(args, kind) is not None]
    if len(given) > 1:
        raise ValueError(f"give one of {', '.join(PRIOR_OPTIONS.values())}, not several")
    if given:
        kind, value = given[0]
        if not (math.isfinite(value) and 0.0 < value <= 20.0):
            raise ValueError(f"{PRIOR_OPTIONS[kind]} must be a height in metres in (0, 20], got {value}")
        return HeightPrior(kind, value)
    return HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT)


def radius_of(path: str, rc: float | None) -> float:
    """The radius of one image: the ``--rc`` value, or the ``_R<rc in 1e-4 m>`` of its name."""
    if rc is not None:
        return rc
    from_name = rc_from_name(pathlib.Path(path).stem)
    if from_name is None:
        raise PanoramaError(
            f"{path}: --rc auto needs the radius in the file name, e.g. L101_R06101.png for rc = 0.6101 m; "
            "pass --rc RADIUS instead (--rc 0 for an ordinary 360-degree camera)"
        )
    if not 0.0 < from_name <= MAX_RC:
        raise PanoramaError(f"{path}: the radius in the file name, {from_name} m, is not in (0, {MAX_RC}] m")
    return from_name


def read_image(path: str, rc: float | None, report, assume_horizon_centred: bool = False) -> tuple[PanoramaFile, float]:
    """The panorama of ``path`` (:func:`~ncjax.io.images.read_panorama_file`: the image, the size of the panorama
    its file's pixels belong to, where its rows lie in it) and its radius (``--rc``, or from its name); ``report``
    takes the line that says the file was resized, padded to the full sphere or developed from HDR.

    Raises:
        PanoramaError: the file cannot be used (the message says why).
    """
    with warnings.catch_warnings(record=True) as notes:
        warnings.simplefilter("always", PanoramaResizeWarning)
        warnings.simplefilter("always", PanoramaDevelopedWarning)
        panorama = read_panorama_file(path, assume_horizon_centred)
    for note in notes:
        if issubclass(note.category, (PanoramaResizeWarning, PanoramaDevelopedWarning)):
            report(str(note.message))
        else:
            warnings.showwarning(note.message, note.category, note.filename, note.lineno)
    return panorama, radius_of(path, rc)


class PendingImage(NamedTuple):
    """An image read and waiting for its batch.

    Attributes:
        path: its file as given.
        name: the stem of its outputs.
        image: the panorama to reconstruct (resized and levelled where needed), RGB uint8.
        rc: its radius, metres.
        gravity: how it was levelled (:func:`~.outputs.align_to_gravity`), or None.
        file_size: (W, H) of the panorama its file's pixels belong to, whose pixels the exports give.
        sphere_crop: where its file's pixels lie in that panorama (:class:`~ncjax.io.photo_sphere.SphereCrop`), or
            None when the file is the full panorama.
    """

    path: str
    name: str
    image: np.ndarray
    rc: float
    gravity: dict | None
    file_size: tuple[int, int]
    sphere_crop: SphereCrop | None = None


def one_line(error: BaseException) -> str:
    """An exception as one line: ``path: reason`` for an OSError that names its file, else its text."""
    if isinstance(error, OSError) and error.strerror and error.filename:
        return f"{error.filename}: {error.strerror}"
    lines = [line.strip() for line in str(error).splitlines() if line.strip()]
    return "; ".join(lines) or type(error).__name__


def panorama_files(folder: str, recursive: bool = False, out: str | None = None) -> list[str]:
    """The panorama files of a folder (:data:`PANORAMA_SUFFIXES`, any case), sorted by path.

    Hidden files and folders (a leading dot) are left out, and so are the outputs of
    earlier runs: the output folder ``out`` when it is a subfolder, and the overlay and
    plan images (``*_overlay.png``, ``*_plan.png``) when ``out`` is ``folder`` itself
    (an overlay is a panorama too).

    Args:
        folder: the folder.
        recursive: also the files of its subfolders, at any depth.
        out: the output folder of the run.
    """
    output_folder = os.path.realpath(out) if out is not None else None
    found = []
    for directory, subfolders, files in os.walk(folder):
        is_output = os.path.realpath(directory) == output_folder
        if is_output and directory != folder:
            subfolders[:] = []
            continue
        subfolders[:] = sorted(name for name in subfolders if not name.startswith(".")) if recursive else []
        found += [
            os.path.join(directory, name)
            for name in files
            if not name.startswith(".")
            and os.path.splitext(name)[1].lower() in PANORAMA_SUFFIXES
            and not (is_output and name.endswith(("_overlay.png", "_plan.png")))
        ]
    return sorted(found, key=lambda path: pathlib.Path(os.path.relpath(path, folder)).parts)


def expand_inputs(paths: list[str], recursive: bool = False, out: str | None = None) -> list[str]:
    """The images of the command line: each file as given, each folder replaced by its panorama files
    (:func:`panorama_files`).

    Raises:
        ValueError: for a folder without panorama files.
    """
    files = []
    for path in paths:
        if not os.path.isdir(path):
            files.append(path)
            continue
        found = panorama_files(path, recursive, out=out)
        if not found:
            kinds = ", ".join(suffix.removeprefix(".") for suffix in PANORAMA_SUFFIXES)
            where = "in it or its subfolders" if recursive else "in it (--recursive also reads its subfolders)"
            raise ValueError(f"{path} is a folder without panorama files ({kinds}) {where}")
        files += found
    return files


def check_output_folder(out: str) -> None:
    """Check, creating nothing, that the output folder can be written in or created: it is a writable folder, or
    the nearest folder above it that exists is (the checks before any work; :func:`make_output_folder` then
    makes sure).

    Raises:
        ValueError: ``out`` is a file, or it cannot be created or written in (one line).
    """
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out} exists and is not a folder")
    existing = os.path.abspath(out)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    if not os.path.isdir(existing):
        raise ValueError(f"--out {out} is not a folder ncjax can write in ({existing} is a file)")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"--out {out} is not a folder ncjax can write in (Permission denied)")


def make_output_folder(out: str) -> None:
    """Create the output folder if needed and check that files can be written in it (a probe file, removed).

    Raises:
        ValueError: ``out`` is a file, cannot be created or is not writable (one line).
    """
    check_output_folder(out)
    try:
        os.makedirs(out, exist_ok=True)
        descriptor, probe = tempfile.mkstemp(prefix=".ncjax-probe-", dir=out)
        os.close(descriptor)
        os.remove(probe)
    except OSError as error:
        raise ValueError(f"--out {out} is not a folder ncjax can write in ({error.strerror or error})") from None


def load_model_option(path: str):
    """The model of ``--model PATH`` (:func:`~ncjax.network.checkpoint.load_model`), or a one-line ValueError."""
    from ..network.checkpoint import load_model

    return _model_option(load_model, path)


def model_weights_option(path: str | None):
    """The weights of ``--model PATH`` or of the default model (:func:`~ncjax.network.weights.read_weights`,
    no network built), or a one-line ValueError."""
    from ..network.weights import DEFAULT_MODEL_PATH, read_weights

    return read_weights(DEFAULT_MODEL_PATH) if path is None else _model_option(read_weights, path)


def _model_option(read, path):
    """``read(path)``, its one-line ValueError (a missing file too) said to be about ``--model``."""
    try:
        return read(path)
    except (ValueError, FileNotFoundError) as error:
        raise ValueError(f"--model {one_line(error)}") from None
