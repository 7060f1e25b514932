"""Panoramas that cover the full circle but not the whole sphere: where they lie in it, and padding them to it.

Phone "photo spheres" and many stitchers store only the rows they captured: an image wider than 2:1
whose XMP (Google's GPano namespace, https://developers.google.com/streetview/spherical-metadata) says
where it lies in the full equirectangular panorama (``FullPanoWidthPixels``, ``FullPanoHeightPixels``,
``CroppedAreaLeftPixels``, ``CroppedAreaTopPixels``, ``CroppedAreaImageWidthPixels``,
``CroppedAreaImageHeightPixels``). :func:`sphere_crop` reads that place (scaled to the file's pixels
when the file was resized after its metadata was written), or, for a file without it, assumes the
rows are centred on the horizon with square pixels when asked to (``--pad-to-sphere``).
:func:`pad_to_sphere` puts the rows into a full 2:1 panorama, black elsewhere: the network was trained
with black bands at the poles (:mod:`ncjax.synth.augment`), and rows that are not there stay unknown.

A panorama that does not go all the way round is refused: a room's layout needs every wall.
"""

from __future__ import annotations

import re
import struct
import zlib
from typing import NamedTuple

import cv2
import numpy as np

_XMP_PACKET = re.compile(rb"<x:xmpmeta.*?</x:xmpmeta>", re.DOTALL)
_GPANO_ATTRIBUTE = re.compile(r"GPano:(\w+)\s*=\s*[\"']([^\"']*)[\"']")
_GPANO_ELEMENT = re.compile(r"<GPano:(\w+)>\s*([^<]*?)\s*</GPano:\1>")
_SIZE_TOLERANCE = 0.01  # relative mismatch between the file's and the metadata's crop shape that is refused


class SphereCrop(NamedTuple):
    """Where an image's pixels lie in the full panorama, in the image's own pixel scale.

    Attributes:
        full_width, full_height: the full panorama's size (``full_width = 2 full_height``; ``full_width`` is the
            image's width: it covers the full circle).
        left, top: the full panorama's column and row of the image's pixel (0, 0).
        width, height: the image's size.
        source: where this came from, for messages (``"XMP GPano"`` or ``"--pad-to-sphere"``).
    """

    full_width: int
    full_height: int
    left: int
    top: int
    width: int
    height: int
    source: str


class SphereCropError(ValueError):
    """Photo-sphere metadata that cannot be used, or a panorama that does not cover the full circle."""


def gpano_fields(data: bytes) -> dict[str, str]:
    """The GPano fields of a file's XMP packet (attribute or element form), empty when there are none."""
    packet = _XMP_PACKET.search(data)
    if packet is None:
        return {}
    text = packet.group(0).decode("utf-8", errors="replace")
    return dict(_GPANO_ATTRIBUTE.findall(text)) | dict(_GPANO_ELEMENT.findall(text))


def _integer(fields: dict[str, str], name: str, default: int | None = None) -> int:
    value = fields.get(name)
    if value is None:
        if default is None:
            raise SphereCropError(f"its XMP GPano metadata has no {name}")
        return default
    try:
        number = round(float(value))
    except ValueError:
        raise SphereCropError(f"its XMP GPano {name} is not a number: {value!r}") from None
    if number < 0:
        raise SphereCropError(f"its XMP GPano {name} is negative: {number}")
    return number


def gpano_crop(fields: dict[str, str], width: int, height: int) -> SphereCrop | None:
    """The place of a ``width x height`` image in its full panorama from its GPano ``fields``
    (:func:`gpano_fields`), None when they do not describe one.

    Raises:
        SphereCropError: the metadata is not equirectangular, contradicts the image's shape, lies outside its
            full panorama, or the image does not cover the full circle.
    """
    if "FullPanoWidthPixels" not in fields:
        return None
    projection = fields.get("ProjectionType", "equirectangular").strip().lower()
    if projection != "equirectangular":
        raise SphereCropError(f"its XMP GPano projection is {projection!r}, not equirectangular")
    full_width = _integer(fields, "FullPanoWidthPixels")
    full_height = _integer(fields, "FullPanoHeightPixels")
    crop_width = _integer(fields, "CroppedAreaImageWidthPixels", full_width)
    crop_height = _integer(fields, "CroppedAreaImageHeightPixels", full_height)
    left = _integer(fields, "CroppedAreaLeftPixels", 0)
    top = _integer(fields, "CroppedAreaTopPixels", 0)
    if min(full_width, full_height, crop_width, crop_height) == 0:
        raise SphereCropError("its XMP GPano sizes include a zero")
    if abs(full_width - 2 * full_height) > max(2.0, _SIZE_TOLERANCE * full_width):
        raise SphereCropError(
            f"its XMP GPano full panorama is {full_width} x {full_height} pixels, not 360 x 180 degrees (2:1)"
        )
    if crop_width < full_width:
        raise SphereCropError(
            f"it covers {360 * crop_width / full_width:.0f} of 360 degrees around (XMP GPano); a room's layout needs "
            "the full circle"
        )
    if top + crop_height > full_height:
        raise SphereCropError(
            f"its XMP GPano rows {top}-{top + crop_height} lie outside its full panorama's {full_height} rows"
        )
    if crop_height == full_height:
        return None  # the full panorama itself
    scale = width / crop_width  # the file may have been resized after its metadata was written
    if abs(height - scale * crop_height) > max(1.0, _SIZE_TOLERANCE * height):
        raise SphereCropError(
            f"its XMP GPano crop is {crop_width} x {crop_height} pixels, which a {width} x {height} image is not "
            "at any one scale"
        )
    full_height_here = width // 2
    top_here = min(round(top * scale), max(full_height_here - height, 0))
    return SphereCrop(width, full_height_here, round(left * scale) % width, top_here, width, height, "XMP GPano")


def horizon_centred_crop(width: int, height: int) -> SphereCrop:
    """The place of a ``width x height`` image (wider than 2:1) in its full panorama, assuming it goes all the way
    round, its pixels are square and its rows are centred on the horizon."""
    full_height = width // 2
    return SphereCrop(width, full_height, 0, (full_height - height) // 2, width, height, "--pad-to-sphere")


def sphere_crop(data: bytes, width: int, height: int, assume_horizon_centred: bool) -> SphereCrop | None:
    """Where a file's ``width x height`` image lies in its full panorama, None when it is the full panorama.

    Its XMP GPano metadata decides when it has some; otherwise an image wider than 2:1 is taken as centred on the
    horizon when ``assume_horizon_centred`` (:func:`horizon_centred_crop`).

    Raises:
        SphereCropError: as :func:`gpano_crop`.
    """
    crop = gpano_crop(gpano_fields(data), width, height)
    if crop is None and assume_horizon_centred and width > 2 * height:
        crop = horizon_centred_crop(width, height)
    if crop is None or (crop.full_height == height and crop.top == 0 and crop.left == 0):
        return None
    return crop


def vertical_coverage(crop: SphereCrop) -> tuple[float, float]:
    """The elevations (degrees, +90 at the zenith) of the top edge of the image's first row and the bottom edge of
    its last."""
    degrees_per_row = 180.0 / crop.full_height
    return 90.0 - crop.top * degrees_per_row, 90.0 - (crop.top + crop.height) * degrees_per_row


def padded_rows(crop: SphereCrop, width: int) -> tuple[int, int]:
    """The first row and the number of rows the image of ``crop`` takes in its full panorama at ``width`` columns."""
    factor = width / crop.full_width
    rows = max(1, min(round(crop.height * factor), width // 2))
    return min(round(crop.top * factor), width // 2 - rows), rows


def pad_to_sphere(image: np.ndarray, crop: SphereCrop, width: int) -> np.ndarray:
    """``image`` (H, W, C) put into its full panorama at ``width`` columns (``width / 2`` rows), black elsewhere.

    The image is resized by ``width / crop.full_width`` (area interpolation when shrinking) and turned to the full
    panorama's first column; its rows are placed at :func:`padded_rows`.
    """
    factor = width / crop.full_width
    top, rows = padded_rows(crop, width)
    interpolation = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
    resized = cv2.resize(image, (width, rows), interpolation=interpolation) if factor != 1 else image
    resized = np.roll(resized, round(crop.left * factor), axis=1)
    full = np.zeros((width // 2, width, *image.shape[2:]), image.dtype)
    full[top : top + rows] = resized
    return full


def photographed_pixels(crop: SphereCrop, width: int) -> np.ndarray:
    """Where the full panorama of ``crop`` at ``width`` columns holds the image (:func:`pad_to_sphere`), (H, W) bool."""
    top, rows = padded_rows(crop, width)
    photographed = np.zeros((width // 2, width), bool)
    photographed[top : top + rows] = True
    return photographed


def gpano_packet(crop: SphereCrop) -> bytes:
    """The XMP packet (GPano attributes) that places an image as ``crop`` says: what :func:`gpano_crop` reads back."""
    fields = {
        "ProjectionType": "equirectangular",
        "FullPanoWidthPixels": crop.full_width,
        "FullPanoHeightPixels": crop.full_height,
        "CroppedAreaImageWidthPixels": crop.width,
        "CroppedAreaImageHeightPixels": crop.height,
        "CroppedAreaLeftPixels": crop.left,
        "CroppedAreaTopPixels": crop.top,
    }
    attributes = " ".join(f'GPano:{name}="{value}"' for name, value in fields.items())
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        f'<rdf:Description rdf:about="" xmlns:GPano="http://ns.google.com/photos/1.0/panorama/" {attributes}/>'
        "</rdf:RDF></x:xmpmeta>"
    ).encode()


def png_with_xmp(rgb: np.ndarray, packet: bytes) -> bytes:
    """A PNG file of ``rgb`` (H, W, 3) carrying the XMP ``packet`` (an uncompressed iTXt chunk before its end, as
    image editors write it): e.g. a photo sphere with :func:`gpano_packet`."""
    png = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))[1].tobytes()
    data = b"XML:com.adobe.xmp\x00\x00\x00\x00\x00" + packet
    chunk = struct.pack(">I", len(data)) + b"iTXt" + data + struct.pack(">I", zlib.crc32(b"iTXt" + data))
    end = png.rindex(b"IEND") - 4  # before the IEND chunk's length
    return png[:end] + chunk + png[end:]
