"""The files of one reconstructed image (JSON, meshes, 3D viewer, overlay, plan, layout formats), written together."""

from __future__ import annotations

import concurrent.futures
import functools
import importlib
import math
import os
import sys
import threading
from typing import NamedTuple

import numpy as np

from ..io.photo_sphere import SphereCrop, photographed_pixels
from ..pipeline.types import LayoutStatus


@functools.cache
def _scale_conflict():
    """:func:`~ncjax.pipeline.prior.scale_conflict` as one compiled program (kept in the CLI's compilation cache),
    not a compilation per operation."""
    import jax

    from ..pipeline.prior import scale_conflict

    return jax.jit(scale_conflict)


def scale_fields(result, prior) -> dict:
    """The JSON record's keys on the scale: where it came from, the prior, and what the geometry measured."""
    from ..io.export import status_has_geometry
    from ..reconstruction import SCALE_SOURCES

    source, geometry = result[4:6]
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
        # the geometry's own layout is kept only where a prior was given (Reconstruction.geometry)
        fields["geometry_measured"]["prior_conflict_sigmas"] = round(float(_scale_conflict()(geometry, prior)), 2)
    return fields


MESH_SUFFIXES = ("obj", "ply", "glb")
# A rig's panorama is levelled only when its tilt reaches this (degrees): level renders read 0.02 degrees at the median
# and 0.07 at most, a rig tilted by 0.1 degrees loses 0.1% of its room height (experiments/rig_tilt.py), and
# resampling a rig's image is itself approximate (RESULTS.md, "Levelling tilted panoramas").
MIN_RIG_TILT = 0.1


def output_names(name: str) -> tuple[str, ...]:
    """The names of every file :func:`write_outputs` can write for the image ``name`` (JSON first)."""
    from ..io.formats import FORMATS, SUFFIXES

    return (
        f"{name}.json",
        *(f"{name}.{suffix}" for suffix in MESH_SUFFIXES),
        f"{name}.html",
        f"{name}_overlay.png",
        f"{name}_plan.png",
        *(f"{name}{SUFFIXES[format]}" for format in FORMATS),
    )


class ReconstructedImage(NamedTuple):
    """One image's results, what :func:`write_outputs` writes of it.

    Attributes:
        name: the stem of its files (``<name>.json``, ...).
        image: the panorama the layout was found on (levelled where ``gravity`` says so), RGB uint8.
        result: its unbatched :func:`~ncjax.reconstruction.reconstruct_batch` result: the layout, the ceiling
            and floor rows, the corner probability, the scale source, the geometry's own layout and, optionally,
            whether the network was adapted to it.
        rc: the radius of its circle of optical centres, metres.
        gravity: how it was levelled (:func:`align_to_gravity`), or None.
        file_size: (W, H) of the image file as given, when it was resized to ``image`` (None: ``image``'s size), or
            of its full panorama at the file's scale when it was padded to it (``sphere_crop``): the pixels of the
            exports (:func:`write_outputs`).
        sphere_crop: where the file's pixels lie in its full panorama
            (:class:`~ncjax.io.photo_sphere.SphereCrop`), or None when the file is the full panorama.
    """

    name: str
    image: np.ndarray
    result: tuple
    rc: float
    gravity: dict | None = None
    file_size: tuple[int, int] | None = None
    sphere_crop: SphereCrop | None = None


# what writing the meshes and the viewer imports (trimesh and shapely: 0.6 s on 2 cores)
MESH_MODULES = ("shapely", "trimesh")


def import_mesh_modules_in_background() -> None:
    """Import :data:`MESH_MODULES` in a thread, while the reconstruction loads its programs and runs (XLA releases
    the interpreter meanwhile), so that the first image's files do not wait for them."""

    def import_all():
        for name in MESH_MODULES:
            importlib.import_module(name)

    threading.Thread(target=import_all, name="ncjax-import-mesh-modules", daemon=True).start()


def write_outputs(
    out: str,
    reconstructed: ReconstructedImage,
    world: str,
    export: tuple[str, ...] = (),
    prior=None,
    texture_size: int | None = None,
) -> dict:
    """All files of one image, which appear together or not at all; returns the JSON record.

    The files are written into a hidden staging folder inside ``out`` and renamed into
    ``out`` at the end, ``<name>.json`` last (:func:`ncjax.io.files.replace_together`):
    an error or a Ctrl-C before the renames leaves nothing of this run in ``out``. Every
    earlier output of ``name`` is replaced or removed: the meshes, the viewer and the layout
    formats exist only when the layout has geometry, and a format only when ``export`` names it.
    The GLB is the room with the panorama on its walls, floor and ceiling (a square texture of
    ``texture_size`` texels a side, None: the image's width), and ``<name>.html`` shows it in a browser.

    ``export`` names layout formats (:data:`ncjax.io.formats.FORMATS`) written beside the
    JSON when the layout has geometry. ``reconstructed.gravity`` says how the image was
    levelled: the JSON, the mesh and the metric formats are in the levelled frame (z up), the
    corner pixels of label_cor and HorizonNet's json in the input image's. Every pixel the JSON and the
    formats give is one of the image file as given (``reconstructed.file_size``), also for a file that was
    resized before the reconstruction; the overlay shows the panorama at the size it was reconstructed at.
    """
    from ..geometry.camera import NonCentralPanorama
    from ..io.export import has_geometry, layout_record, write_json, write_png
    from ..io.files import replace_together
    from ..io.formats import write_layout_formats
    from ..io.mesh import write_mesh
    from ..viz.overlay import draw_overlay
    from ..viz.plan import draw_plan
    from ..viz.room_texture import textured_room
    from ..viz.viewer import write_viewer

    name, image, result, rc, gravity, file_size, crop = reconstructed
    layout, ceiling_v, floor_v, corner_prob, *_ = result
    cam = NonCentralPanorama(image.shape[1], image.shape[0], rc=rc)
    file_cam = cam if file_size is None else NonCentralPanorama(*file_size, rc=rc)
    sphere_crop = None if crop is None else crop._asdict()
    adapted = result[6] if len(result) > 6 else None  # Reconstruction.adapted
    extra = scale_fields(result, prior) | {
        "gravity": gravity,
        "sphere_crop": sphere_crop,
        "adapted": None if adapted is None else bool(adapted),
    }
    record = layout_record(layout, cam, name=name, world=world, extra=extra, image_size=file_size)

    def write_pictures(stem: str) -> None:
        overlay = draw_overlay(image, layout, cam, ceiling_v=ceiling_v, floor_v=floor_v, corner_prob=corner_prob)
        write_png(f"{stem}_overlay.png", overlay)
        write_png(f"{stem}_plan.png", draw_plan(layout, title=name, rc=rc))

    with (
        replace_together(out, owned=output_names(name), last=f"{name}.json") as staging,
        concurrent.futures.ThreadPoolExecutor(1) as pictures,
    ):
        stem = os.path.join(staging, name)
        # the pictures are drawn beside the room's texture and meshes (both mostly outside the interpreter)
        drawn = pictures.submit(write_pictures, stem)
        write_json(f"{stem}.json", record)
        if has_geometry(layout):
            room = textured_room(layout, image, cam, texture_size, photographed_part(image, crop, gravity))
            write_mesh(stem, layout, room)
            write_viewer(f"{stem}.html", room, record)
            try:
                if export:
                    rotation = None if gravity is None or gravity["rotation"] is None else np.array(gravity["rotation"])
                    write_layout_formats(stem, record, file_cam, export, rotation=rotation)
            except ValueError as error:  # a corner no ray sees: the other outputs still describe the layout
                print(f"{name}: layout formats not written ({error})", file=sys.stderr)
        drawn.result()  # its error, if any, is this image's: nothing is renamed into out
    return record


def photographed_part(image: np.ndarray, crop: SphereCrop | None, gravity: dict | None) -> np.ndarray | None:
    """Where ``image``, a photo sphere padded to the full sphere (``crop``) and maybe levelled (``gravity``), holds
    the photograph, (H, W) bool; None for a file that was the full panorama."""
    if crop is None:
        return None
    photographed = photographed_pixels(crop, image.shape[1])
    if gravity is None or gravity["rotation"] is None:
        return photographed
    from ..geometry.levelling import level_panorama

    return level_panorama(photographed.astype(np.uint8), np.array(gravity["rotation"]), "nearest").astype(bool)


def align_to_gravity(image: np.ndarray, min_tilt: float = 0.0) -> tuple[np.ndarray, dict]:
    """A panorama levelled (:mod:`ncjax.geometry.levelling`), and the JSON record of its tilt.

    A central panorama is levelled exactly. A non-central rig's optical centres stay on its tilted circle, moved by
    at most ``rc`` times the tilt: resampling leaves about ``rc / range`` of the tilt (experiments/rig_tilt.py).
    An image whose vertical the line segments do not fix reliably (``reliable`` false), or whose tilt is under
    ``min_tilt`` degrees (:data:`MIN_RIG_TILT` for a rig's), is kept as it is (``rotation`` null).

    Args:
        image: RGB uint8 (H, W, 3), W = 2 H.
        min_tilt: the smallest tilt (degrees, roll and pitch together) that is undone.

    Returns:
        ``(image, record)``: the levelled image (or ``image`` itself), and the JSON's ``gravity`` record:
        ``reliable``, ``segments``, ``roll_deg`` and ``pitch_deg`` (null when unreliable), ``rotation`` (the
        input -> levelled rotation, null where the image was kept).
    """
    from ..geometry.levelling import estimate_tilt, level_panorama

    estimate = estimate_tilt(image)
    record = {"reliable": estimate.reliable, "segments": int(estimate.segments), "roll_deg": None, "pitch_deg": None}
    if not estimate.reliable:
        return image, record | {"rotation": None}
    record |= {"roll_deg": round(float(estimate.roll), 3), "pitch_deg": round(float(estimate.pitch), 3)}
    if math.hypot(estimate.roll, estimate.pitch) < min_tilt:
        return image, record | {"rotation": None}
    rotation = np.asarray(estimate.rotation)
    levelled = level_panorama(image, rotation)
    return levelled, record | {"rotation": np.round(rotation, 8).tolist()}
