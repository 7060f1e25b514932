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

import math
import re
import struct
import zlib
from typing import NamedTuple

import cv2
import numpy as np

_XMP_PACKET = re.compile(rb"<x:xmpmeta.*?</x:xmpmeta>", re.DOTALL)
_XMP_KEYWORD = b"XML:com.adobe.xmp"  # the PNG text chunk that holds XMP
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_MAX_XMP_BYTES = 1 << 22  # an XMP packet is kilobytes; a chunk that inflates beyond this is not one
_GPANO_NAMESPACE = "http://ns.google.com/photos/1.0/panorama/"
_PREFIX = re.compile(r"xmlns:([\w.-]+)\s*=\s*[\"']" + re.escape(_GPANO_NAMESPACE) + r"[\"']")
ASPECT_TOLERANCE = 0.005  # relative departure of a panorama's sizes from 2:1 taken as a stitcher's rounding
XMP_GPANO = "xmp_gpano"  # SphereCrop.source: placed by the file's XMP GPano metadata
HORIZON_CENTRED = "horizon_centred"  # SphereCrop.source: taken as centred on the horizon (--pad-to-sphere)
_SOURCE_NAMES = {XMP_GPANO: "XMP GPano", HORIZON_CENTRED: "--pad-to-sphere"}


class SphereCrop(NamedTuple):
    """Where an image's rows lie in the full panorama, in the image's own pixel scale.

    The image goes all the way round: its columns are the full panorama's (a turn about the vertical, which
    GPano's ``CroppedAreaLeftPixels`` of a full circle would be, changes no layout and is left out).

    Attributes:
        full_width, full_height: the full panorama's size: the image's width, and half of it (rounded down).
        top: the full panorama's row of the image's first row.
        width: the image's width.
        height: the full panorama's rows the image spans: its own height, unless its pixels are not quite square
            (a file resized after its metadata was written; it is resized to this).
        source: :data:`XMP_GPANO` or :data:`HORIZON_CENTRED`.
    """

    full_width: int
    full_height: int
    top: int
    width: int
    height: int
    source: str


class SphereCropError(ValueError):
    """Photo-sphere metadata that cannot be used, or a panorama that does not cover the full circle."""


def png_compressed_xmp(data: bytes) -> list[bytes]:
    """The text of a PNG file's zlib-compressed XMP chunks (iTXt, keyword ``XML:com.adobe.xmp``), which a search
    of the file's bytes cannot see; empty for any other file, or a chunk that does not decompress."""
    texts, offset = [], len(_PNG_SIGNATURE)
    if not data.startswith(_PNG_SIGNATURE):
        return texts
    while offset + 8 <= len(data):
        (length,), kind = struct.unpack(">I", data[offset : offset + 4]), data[offset + 4 : offset + 8]
        start, offset = offset + 8, offset + 12 + length
        if kind != b"iTXt":
            continue
        keyword, _, rest = data[start : start + length].partition(b"\0")
        if keyword != _XMP_KEYWORD or rest[:2] != b"\x01\x00":  # compressed, with zlib
            continue
        text = rest[2:].split(b"\0", 2)[-1]  # after the language tag and the translated keyword
        inflater = zlib.decompressobj()
        try:
            packet = inflater.decompress(text, _MAX_XMP_BYTES)
        except zlib.error:
            continue
        if inflater.eof and not inflater.unconsumed_tail:  # a cut stream, or one beyond any XMP's size: left out
            texts.append(packet)
    return texts


def gpano_fields(data: bytes) -> dict[str, str]:
    """The GPano fields of a file's XMP packets, compressed PNG ones included (attribute or element form, under
    whatever prefix the packet binds to the GPano namespace), empty when there are none."""
    fields = {}
    packets = [match for text in (data, *png_compressed_xmp(data)) for match in _XMP_PACKET.finditer(text)]
    for packet in packets:
        text = packet.group(0).decode("utf-8", errors="replace")
        for prefix in set(_PREFIX.findall(text)) | {"GPano"}:
            name = re.escape(prefix)
            fields |= dict(re.findall(rf"\b{name}:(\w+)\s*=\s*[\"']([^\"']*)[\"']", text))
            fields |= dict(re.findall(rf"<{name}:(\w+)(?:\s[^>]*)?>\s*([^<]*?)\s*</{name}:\1>", text))
    return fields


def _integer(fields: dict[str, str], name: str, default: int | None = None) -> int:
    value = fields.get(name)
    if value is None:
        if default is None:
            raise SphereCropError(f"its XMP GPano metadata has no {name}")
        return default
    try:
        number = float(value)
    except ValueError:
        raise SphereCropError(f"its XMP GPano {name} is not a number: {value!r}") from None
    if not math.isfinite(number) or number < 0:
        raise SphereCropError(f"its XMP GPano {name} is not a size in pixels: {value!r}")
    return round(number)


def _near(a: float, b: float, tolerance: float = ASPECT_TOLERANCE) -> bool:
    return abs(a - b) <= max(2.0, tolerance * max(a, b))


def gpano_crop(fields: dict[str, str], width: int, height: int) -> SphereCrop | None:
    """The place of a ``width x height`` image, wider than 2:1, in its full panorama from its GPano ``fields``
    (:func:`gpano_fields`), None when they do not describe one.

    Raises:
        SphereCropError: the metadata is not equirectangular, contradicts the image's shape, lies outside its
            full panorama, or the image does not cover the full circle exactly.
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
    top = _integer(fields, "CroppedAreaTopPixels", 0)
    for name, value in (("FullPanoWidthPixels", full_width), ("FullPanoHeightPixels", full_height)):
        if value == 0:
            raise SphereCropError(f"its XMP GPano {name} is 0")
    if not _near(full_width, 2 * full_height):
        raise SphereCropError(
            f"its XMP GPano full panorama is {full_width} x {full_height} pixels, not 360 x 180 degrees (2:1)"
        )
    if not _near(crop_width, full_width):
        raise SphereCropError(
            f"it covers {360 * crop_width / full_width:.1f} of 360 degrees around ({crop_width} of its full "
            f"panorama's {full_width} columns, XMP GPano); a room's layout needs exactly the full circle"
        )
    if crop_height == 0 or top + crop_height > full_height:
        raise SphereCropError(
            f"its XMP GPano rows {top}-{top + crop_height} are not within its full panorama's {full_height} rows"
        )
    scale = width / crop_width  # the file may have been resized after its metadata was written
    if not _near(height, scale * crop_height, 2 * ASPECT_TOLERANCE):
        raise SphereCropError(
            f"its XMP GPano crop is {crop_width} x {crop_height} pixels, but the image is {width} x {height}: not "
            "that shape at any scale"
        )
    full_height_here = width // 2
    rows = min(max(1, round(crop_height * full_height_here / full_height)), full_height_here)
    top_here = min(round(top * full_height_here / full_height), full_height_here - rows)
    return SphereCrop(width, full_height_here, top_here, width, rows, XMP_GPANO)


def horizon_centred_crop(width: int, height: int) -> SphereCrop:
    """The place of a ``width x height`` image (wider than 2:1) in its full panorama, assuming it goes all the way
    round, its pixels are square and its rows are centred on the horizon."""
    full_height = width // 2
    return SphereCrop(width, full_height, (full_height - height) // 2, width, height, HORIZON_CENTRED)


def sphere_crop(data: bytes, width: int, height: int, assume_horizon_centred: bool) -> SphereCrop | None:
    """Where a file's ``width x height`` image, wider than 2:1, lies in its full panorama, or None when nothing
    says.

    Its XMP GPano metadata decides when it has some; otherwise the image is taken as centred on the horizon when
    ``assume_horizon_centred`` (:func:`horizon_centred_crop`).

    Raises:
        SphereCropError: as :func:`gpano_crop`.
    """
    crop = gpano_crop(gpano_fields(data), width, height)
    if crop is None and assume_horizon_centred:
        return horizon_centred_crop(width, height)
    return crop


def source_name(crop: SphereCrop) -> str:
    """How ``crop`` was found, for messages: "XMP GPano" or "--pad-to-sphere"."""
    return _SOURCE_NAMES[crop.source]


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

    The image is resized to ``width`` columns and :func:`padded_rows` rows (area interpolation when shrinking) and
    placed at the first of them.
    """
    top, rows = padded_rows(crop, width)
    interpolation = cv2.INTER_AREA if width < crop.full_width else cv2.INTER_LINEAR
    if image.shape[:2] != (rows, width):
        image = cv2.resize(image, (width, rows), interpolation=interpolation)
    full = np.zeros((width // 2, width, *image.shape[2:]), image.dtype)
    full[top : top + rows] = image
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
        "CroppedAreaLeftPixels": 0,
        "CroppedAreaTopPixels": crop.top,
    }
    attributes = " ".join(f'GPano:{name}="{value}"' for name, value in fields.items())
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        f'<rdf:Description rdf:about="" xmlns:GPano="{_GPANO_NAMESPACE}" {attributes}/>'
        "</rdf:RDF></x:xmpmeta>"
    ).encode()


def png_with_xmp(rgb: np.ndarray, packet: bytes, compressed: bool = False) -> bytes:
    """A PNG file of ``rgb`` (H, W, 3) carrying the XMP ``packet`` (an iTXt chunk before its end, as image editors
    write it; zlib-compressed if ``compressed``): e.g. a photo sphere with :func:`gpano_packet`."""
    png = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))[1].tobytes()
    # keyword, compression flag and method, empty language tag and translated keyword, text
    flag = b"\x01\x00" if compressed else b"\x00\x00"
    data = _XMP_KEYWORD + b"\x00" + flag + b"\x00\x00" + (zlib.compress(packet) if compressed else packet)
    chunk = struct.pack(">I", len(data)) + b"iTXt" + data + struct.pack(">I", zlib.crc32(b"iTXt" + data))
    end = png.rindex(b"IEND") - 4  # before the IEND chunk's length
    return png[:end] + chunk + png[end:]
