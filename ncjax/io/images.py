"""Reading panoramas from files for ``ncjax reconstruct``: every way a file can be wrong gets a clear message.

Accepted: anything OpenCV decodes (PNG, JPEG, TIFF, BMP, WebP, ...) as 8- or
16-bit greyscale, RGB or RGBA. 16-bit images are scaled to 8 bits
(``round(x / 257)``), greyscale is repeated into three channels and the alpha
channel is dropped (panoramas have no transparency; the colour is kept as
stored). A file's EXIF orientation is applied, as viewers apply it. Linear HDR
panoramas (Radiance ``.hdr``, OpenEXR ``.exr``, floating-point TIFF) are
developed to 8 bits as a 360-degree camera's HDR capture would be
(:func:`develop_hdr`), with a :class:`PanoramaDevelopedWarning`. The panorama
must be full (360 x 180 degrees, width = 2 x height).
Stitching tools often write a row or a column more or fewer: an image within
:data:`ASPECT_TOLERANCE` of 2:1 is resized to exactly 2:1 with a
:class:`PanoramaResizeWarning` (the rows then move by at most that fraction
of their elevation, under a pixel for rows within 45 degrees of the horizon at
512 rows). A file that goes all the way round but not up to the poles is padded
with black to the full sphere (:mod:`ncjax.io.photo_sphere`): where its XMP
GPano metadata places it (phone photo spheres, stitchers), or, asked to
(``assume_horizon_centred``), centred on the horizon. Any other shape is refused.
A panorama wider than :data:`MAX_WIDTH` is reconstructed at ``MAX_WIDTH x MAX_WIDTH / 2`` (the same warning): the
network reads 1024 x 512 anyway, 4096 columns gave no measurably smaller
room-height error than 2048 on our renders (``experiments/resolution.py``),
and memory and time grow with the image (a batch of four 4096 x 2048
panoramas peaks at 5.6 GB, four 2048 x 1024 at 2.4 GB; 4096 columns take
2.2-2.5 times as long). A resized panorama's layout is still exported in the
pixels of the file as given, a padded one's in those of its full panorama at the
file's scale: :func:`read_panorama_file` returns that size.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from typing import NamedTuple

import cv2
import jax.numpy as jnp
import numpy as np
from PIL import Image

from ..geometry.gravity import panorama_size_error
from .dual_fisheye import looks_dual_fisheye
from .photo_sphere import (
    ASPECT_TOLERANCE,  # relative departure of width / height from 2 that is resized instead of refused
    SphereCrop,
    SphereCropError,
    pad_to_sphere,
    source_name,
    sphere_crop,
    vertical_coverage,
)
from .tone_mapping import develop

MAX_WIDTH = 2048  # the widest panorama ncjax reconstruct works at
PANORAMA_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".hdr", ".exr")
# The factor on the log contrasts of an HDR panorama's large-scale light (tone_mapping.local_tone_mapping), as
# real-estate capture apps compress them (experiments/hdr_development.py).
HDR_LOCAL_COMPRESSION = 0.6
_JPEG_END = b"\xff\xd9"
_PNG_END = b"IEND\xaeB`\x82"
_EXR_MAGIC = b"\x76\x2f\x31\x01"
_OPENEXR_SWITCH = "OPENCV_IO_ENABLE_OPENEXR"
_EXIF_ORIENTATION = 0x0112
# EXIF orientation -> the stored pixels as shown (TIFF 6.0; Pillow's ImageOps.exif_transpose does the same)
_UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],  # mirrored left to right
    3: lambda a: a[::-1, ::-1],  # turned half a turn
    4: lambda a: a[::-1],  # mirrored top to bottom
    5: lambda a: np.swapaxes(a, 0, 1),  # mirrored about the main diagonal
    6: lambda a: np.rot90(a, -1),  # turned a quarter clockwise
    7: lambda a: np.swapaxes(a[::-1, ::-1], 0, 1),  # mirrored about the other diagonal
    8: lambda a: np.rot90(a, 1),  # turned a quarter anticlockwise
}
_CV2_REASON = re.compile(r"error: \([^)]*\)\s*(.*?)(?:\s+in function .*)?$")
_RC_IN_NAME = re.compile(r"_R(\d{5})(?:\D|$)")  # the rig's radius in a file name, 0.1 mm


class PanoramaError(ValueError):
    """A panorama file that cannot be used (the message says why)."""


class PanoramaResizeWarning(UserWarning):
    """A panorama file a little off 2:1, or wider than :data:`MAX_WIDTH`, was resized (the message gives both sizes)."""


class PanoramaPaddedWarning(PanoramaResizeWarning):
    """A panorama file that covers only part of the sphere was padded to all of it (the message says how)."""


class PanoramaDevelopedWarning(UserWarning):
    """A linear HDR panorama file was developed to 8 bits (:func:`develop_hdr`; the message says how)."""


def _truncation(data: bytes) -> str | None:
    """Why a JPEG or PNG file is cut short, or None (OpenCV may decode a truncated JPEG silently)."""
    if data.startswith(b"\xff\xd8") and not data.rstrip(b"\x00").endswith(_JPEG_END):
        return "the JPEG data ends before its end marker (truncated file?)"
    if data.startswith(b"\x89PNG") and not data.endswith(_PNG_END):
        return "the PNG data ends before its IEND chunk (truncated file?)"
    return None


def to_rgb8(image: np.ndarray) -> np.ndarray:
    """An OpenCV-decoded array (BGR order, 8/16 bit or floating point, 1/3/4 channels) as RGB uint8 (H, W, 3);
    floating point is linear HDR, developed by :func:`develop_hdr`."""
    if image.ndim == 2:
        image = image[..., None]
    channels = image.shape[-1]
    if channels not in (1, 3, 4):
        raise PanoramaError(f"unsupported number of channels: {channels}")
    rgb = np.repeat(image, 3, axis=-1) if channels == 1 else image[..., 2::-1]
    if image.dtype == np.uint8:
        return np.ascontiguousarray(rgb)
    if image.dtype == np.uint16:
        return np.round(rgb.astype(np.float32) / 257.0).astype(np.uint8)
    if image.dtype in (np.float32, np.float64):
        return develop_hdr(rgb)
    raise PanoramaError(f"unsupported pixel type {image.dtype} (8- or 16-bit, or floating-point HDR images only)")


def develop_hdr(radiance: np.ndarray) -> np.ndarray:
    """A linear HDR panorama (H, W, 3), any positive scale, developed to RGB uint8 as a 360-degree camera's HDR
    capture is (:func:`~ncjax.io.tone_mapping.develop`, as the training renders' camera model develops): its
    large-scale light compressed locally by :data:`HDR_LOCAL_COMPRESSION`, metered to render its log-average
    luminance at 18% grey, part of a grey-world white balance, the filmic tone curve and sRGB. Negative values (a
    resampled file's) count as black.

    A panorama wider than :data:`MAX_WIDTH` is developed at that width (its light averaged, as a smaller sensor's
    pixels would collect it) and the result brought back to its size: ncjax reconstructs it at that width anyway,
    and every step of the development is relative to the image's size, so at that width the image moves by a fraction
    of a grey level on average where the time and memory halve or better (benchmarks/bench_hdr_input.py).

    Raises:
        PanoramaError: a pixel is not a finite number.
    """
    bad = int(np.count_nonzero(~np.isfinite(radiance).all(axis=-1)))
    if bad:
        raise PanoramaError(f"{bad} pixels of the HDR image are not finite numbers (NaN or infinity)")
    height, width = radiance.shape[:2]
    # The development does not depend on the light's scale (the metering sets it): brought to a peak of 1 before
    # float32, light near float32's limits neither overflows nor underflows.
    peak = float(np.max(radiance))
    linear = radiance / peak if peak > 0 else radiance.copy()
    np.maximum(linear, 0.0, out=linear)
    if width > MAX_WIDTH:  # averaged after the normalisation: a block's float32 sum of bright light would overflow
        size = (MAX_WIDTH, max(1, round(height * MAX_WIDTH / width)))
        linear = cv2.resize(linear, size, interpolation=cv2.INTER_AREA)
    display = develop(jnp.asarray(linear, jnp.float32), HDR_LOCAL_COMPRESSION, 1.0, jnp.ones(3))
    developed = np.round(np.asarray(display) * 255).astype(np.uint8)
    if developed.shape[:2] != (height, width):
        # nearest, so that the reader's area resize to the working width gives back the developed image itself
        developed = cv2.resize(developed, (width, height), interpolation=cv2.INTER_NEAREST)
    return developed


def nearly_full_panorama(width: int, height: int) -> bool:
    """Whether a ``width x height`` image is within :data:`ASPECT_TOLERANCE` of 2:1 without being 2:1."""
    return width != 2 * height and height >= 32 and abs(width / (2 * height) - 1) <= ASPECT_TOLERANCE


def working_size(width: int, height: int) -> tuple[int, str] | None:
    """The width a panorama read from a file is resized to (its height is half) and why, or None to keep it.

    Near 2:1 images become exactly 2:1 (the width rounded to even), and
    nothing becomes wider than :data:`MAX_WIDTH`; other shapes are left for
    :func:`~ncjax.geometry.gravity.panorama_size_error` to refuse.
    """
    reasons = []
    if nearly_full_panorama(width, height):
        reasons.append("is not exactly 2:1")
    if width > MAX_WIDTH and (reasons or width == 2 * height):
        reasons.append(f"is wider than {MAX_WIDTH}")
    if not reasons:
        return None
    return min(2 * round(width / 2), MAX_WIDTH), " and ".join(reasons)


def read_image_file(path: str | os.PathLike) -> tuple[np.ndarray, bytes]:
    """Read an image file as RGB uint8 (H, W, 3) at its own size, and the file's bytes (for its metadata).

    Raises:
        PanoramaError: missing, unreadable, truncated, not an image, or an unsupported pixel format.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise PanoramaError(f"{path}: no such file")
    with open(path, "rb") as file:
        data = file.read()
    if not data:
        raise PanoramaError(f"{path}: the file is empty")
    truncated = _truncation(data)
    if truncated:
        raise PanoramaError(f"{path}: {truncated}")
    if data.startswith(_EXR_MAGIC):
        # OpenCV switches its OpenEXR reader off unless asked (opencv/opencv#21326: the decoder's exposure to crafted
        # files), and reads the request once, at its first EXR file: a file given as .exr asks for it, unless the
        # user has set the variable.
        os.environ.setdefault(_OPENEXR_SWITCH, "1")
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # its reasons become the one line below
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error as error:
        reason = one_line_cv2_error(error)
        if "OpenEXR codec is disabled" in reason:
            reason = f"OpenCV's OpenEXR reader is switched off ({_OPENEXR_SWITCH}={os.environ.get(_OPENEXR_SWITCH)})"
        raise PanoramaError(f"{path}: OpenCV cannot decode it: {reason}") from None
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise PanoramaError(f"{path}: not an image OpenCV can decode (corrupt or unsupported format)")
    try:
        rgb = to_rgb8(image)
    except PanoramaError as error:
        raise PanoramaError(f"{path}: {error}") from None
    rgb = upright(rgb, exif_orientation(data))
    if image.dtype.kind == "f":
        warnings.warn(
            f"{path}: a linear HDR image, developed to 8 bits: its light compressed locally by "
            f"{HDR_LOCAL_COMPRESSION}, metered to 18% grey, a filmic tone curve",
            PanoramaDevelopedWarning,
            stacklevel=2,
        )
    return rgb, data


def exif_orientation(data: bytes) -> int:
    """A file's EXIF orientation (TIFF tag 274: 1 as stored, 2-8 mirrored and/or turned for display; 1 without one).

    Read by Pillow from the file's header alone, without decoding its pixels. OpenCV's unchanged decoding, which
    keeps 16 bits and alpha, leaves the orientation to the caller.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # only the header is read
            with Image.open(io.BytesIO(data)) as header:
                orientation = header.getexif().get(_EXIF_ORIENTATION, 1)
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError):
        return 1  # a format Pillow does not read (HDR, EXR), or a file too large for it to open: none known
    return orientation if orientation in _UPRIGHT else 1


def upright(image: np.ndarray, orientation: int) -> np.ndarray:
    """An image (H, W, ...) as stored, turned as its EXIF ``orientation`` says it is shown (1 unchanged)."""
    return np.ascontiguousarray(_UPRIGHT[orientation](image))


def one_line_cv2_error(error: cv2.error) -> str:
    """The reason an OpenCV error gives (``OpenCV(version) file:line: error: (code:name) reason in function 'f'``),
    without its version, source file, code and function."""
    text = " ".join(str(error).split())
    match = _CV2_REASON.search(text)
    return (match.group(1) if match else text).strip() or type(error).__name__


def photo_sphere_crop(
    path: str | os.PathLike, data: bytes, width: int, height: int, assume_horizon_centred: bool = False
) -> SphereCrop | None:
    """Where a file's ``width x height`` image lies in its full panorama, if it is a photo sphere without its poles:
    wider than 2:1 (by more than :data:`ASPECT_TOLERANCE`) and placed by its XMP GPano metadata or, with
    ``assume_horizon_centred``, centred on the horizon (:func:`~ncjax.io.photo_sphere.sphere_crop`). None for any
    other file, whatever metadata it carries: a full panorama, or one near enough 2:1 to be resized to it.

    Raises:
        PanoramaError: its metadata cannot be used, or it does not go all the way round.
    """
    if width <= 2 * height or nearly_full_panorama(width, height):
        return None
    try:
        return sphere_crop(data, width, height, assume_horizon_centred)
    except SphereCropError as error:
        raise PanoramaError(f"{path}: {error}") from None


def read_panorama(path: str | os.PathLike, assume_horizon_centred: bool = False) -> np.ndarray:
    """Read a full panorama as RGB uint8 (H, W, 3), W = 2 H (:func:`read_panorama_file`'s image)."""
    return read_panorama_file(path, assume_horizon_centred).image


class PanoramaFile(NamedTuple):
    """A panorama read from a file (:func:`read_panorama_file`).

    Attributes:
        image: the full panorama to reconstruct, RGB uint8 (H, W, 3), W = 2 H.
        file_size: (W, H) of the panorama the file's pixels belong to: the file's own size, or for a photo sphere
            (``crop``) its full panorama's at the file's scale. The layout's exports give pixels of this size.
        crop: where the file's rows lie in that full panorama, or None for a file that is a full panorama.
    """

    image: np.ndarray
    file_size: tuple[int, int]
    crop: SphereCrop | None


def read_panorama_file(path: str | os.PathLike, assume_horizon_centred: bool = False) -> PanoramaFile:
    """Read a full panorama as RGB uint8 (H, W, 3), W = 2 H, and the size of the panorama its file's pixels belong to.

    A photo sphere without its poles (:func:`photo_sphere_crop`: placed by its XMP GPano metadata, or, with
    ``assume_horizon_centred``, any file wider than 2:1 taken as centred on the horizon) is padded with black to its
    full panorama (:func:`~ncjax.io.photo_sphere.pad_to_sphere`), with a :class:`PanoramaPaddedWarning`. The returned
    sizes differ when the file was resized or padded: the file's is the one whose pixels the layout's exports give,
    the image's the one the panorama is reconstructed at.

    Warns:
        PanoramaResizeWarning: the file is within :data:`ASPECT_TOLERANCE` of
            2:1 and was resized to exactly 2:1, or it was wider than
            :data:`MAX_WIDTH` and was resized to that width.
        PanoramaPaddedWarning: the file is a photo sphere without its poles and was padded to the full sphere.

    Raises:
        PanoramaError: missing, unreadable, truncated, not an image, an
            unsupported pixel format, unusable photo-sphere metadata, not the full circle, not 2:1, or an
            unstitched dual-fisheye image (:func:`~ncjax.io.dual_fisheye.looks_dual_fisheye`).
    """
    image, data = read_image_file(path)
    height, width = image.shape[:2]
    crop = photo_sphere_crop(path, data, width, height, assume_horizon_centred)
    if crop is not None:
        padded = pad_to_sphere(image, crop, min(2 * (crop.full_width // 2), MAX_WIDTH))
        size_error = panorama_size_error(*padded.shape[1::-1])
        if size_error:
            raise PanoramaError(f"{path}: padded to the full sphere, {size_error}")
        top, bottom = vertical_coverage(crop)
        warnings.warn(
            f"{path}: {width} x {height} pixels cover elevations {top:+.0f} to {bottom:+.0f} degrees of a "
            f"{crop.full_width} x {crop.full_height} panorama ({source_name(crop)}); padded with black to the full "
            f"sphere, reconstructed at {padded.shape[1]} x {padded.shape[0]}",
            PanoramaPaddedWarning,
            stacklevel=2,
        )
        return PanoramaFile(padded, (crop.full_width, crop.full_height), crop)
    file_size = (width, height)
    resize = working_size(*file_size)
    if resize is not None:
        working_width, reason = resize
        resized = cv2.resize(image, (working_width, working_width // 2), interpolation=cv2.INTER_AREA)
        warnings.warn(
            f"{path}: {width} x {height} pixels {reason}; "
            f"resized to {resized.shape[1]} x {resized.shape[0]} as a full 360 x 180 degree panorama",
            PanoramaResizeWarning,
            stacklevel=2,
        )
        image = resized
    if looks_dual_fisheye(image):
        raise PanoramaError(
            f"{path}: two fisheye discs on black, not an equirectangular panorama (a 360-degree camera's unstitched "
            "dual-fisheye image?); export it stitched, as an equirectangular panorama, from the camera's app"
        )
    size_error = panorama_size_error(*image.shape[1::-1])
    if size_error:
        hint = (
            "; one that goes all the way round and is centred on the horizon can be padded to the full sphere "
            "(ncjax reconstruct --pad-to-sphere)"
            if image.shape[1] > 2 * image.shape[0]
            else ""
        )
        raise PanoramaError(f"{path}: {size_error}{hint}")
    return PanoramaFile(image, file_size, None)


def check_rgb(image) -> np.ndarray:
    """``image`` as a numpy array, or a ValueError unless it is an RGB uint8 image (H, W, 3)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 image (H, W, 3), got {image.dtype} {image.shape}")
    return image


def rc_from_name(name: str) -> float | None:
    """The rc the authors encode in file names (``L101_R06101`` -> 0.6101 m), or None."""
    match = _RC_IN_NAME.search(os.path.basename(name))
    return int(match.group(1)) / 1e4 if match else None
