"""Linear HDR panorama files (Radiance .hdr, OpenEXR, floating-point TIFF): read, developed to 8 bits as
``ncjax.io.images.develop_hdr`` says, refused with one line when a pixel is not a number."""

import os
import subprocess
import sys
import warnings

import cv2
import numpy as np
import pytest

from ncjax.io import images
from ncjax.io.images import (
    PANORAMA_SUFFIXES,
    PanoramaDevelopedWarning,
    PanoramaError,
    develop_hdr,
    one_line_cv2_error,
    read_image_file,
    read_panorama_file,
    to_rgb8,
)
from ncjax.io.tone_mapping import srgb_encode

HEIGHT, WIDTH = 32, 64


def _radiance(seed: int = 0) -> np.ndarray:
    """A linear RGB panorama (H, W, 3): walls of a few levels of light, a window 200 times brighter."""
    rng = np.random.default_rng(seed)
    image = np.repeat(rng.uniform(0.02, 0.2, (HEIGHT, WIDTH // 8, 3)), 8, axis=1).astype(np.float32)
    image[8:14, 20:28] = 30.0
    return image


def test_a_uniform_room_develops_to_middle_grey_whatever_the_scale_of_its_light():
    grey = np.full((HEIGHT, WIDTH, 3), 0.37, np.float32)
    expected = round(255 * float(srgb_encode(0.18)))  # the metering's 18% grey through the sRGB encoding
    for scale in (1.0, 1e-3, 1e4):
        np.testing.assert_array_equal(develop_hdr(scale * grey), np.full((HEIGHT, WIDTH, 3), expected, np.uint8))


def _ranks(values: np.ndarray) -> np.ndarray:
    return np.argsort(np.argsort(values, kind="stable"), kind="stable").astype(np.float64)


def test_development_keeps_the_walls_order_and_blows_the_window_out():
    radiance = _radiance()
    assert develop_hdr(radiance).dtype == np.uint8
    image = develop_hdr(radiance).astype(np.float64)
    walls = np.ones((HEIGHT, WIDTH), bool)
    walls[8:14, 20:28] = False
    # brighter light, brighter pixel, across the walls, nearly: the tone curve is monotonic, the local compression
    # changes the large-scale light smoothly and the 8 bits tie close levels (rank correlation measured 0.92; 1 is
    # the same order, an inverted or channel-swapped development is far below)
    light, shown = radiance[walls].mean(-1), image[walls].mean(-1)
    assert np.corrcoef(_ranks(light), _ranks(shown))[0, 1] > 0.9
    assert image[8:14, 20:28].mean() > 240  # the window blows out, as in a photograph
    np.testing.assert_array_equal(develop_hdr(radiance), develop_hdr(radiance.copy()))  # deterministic


def test_a_panorama_wider_than_ncjax_works_at_develops_as_it_would_at_its_own_size(monkeypatch):
    # developed at the working width and brought back: what ncjax reconstructs (the working width) is what the
    # development at the file's own size gives there, to a grey level or two
    radiance = cv2.resize(_radiance(), (8 * WIDTH, 8 * HEIGHT), interpolation=cv2.INTER_LINEAR)
    full = develop_hdr(radiance)
    monkeypatch.setattr(images, "MAX_WIDTH", 2 * WIDTH)
    reduced = develop_hdr(radiance)
    assert reduced.shape == full.shape == radiance.shape
    working = [
        cv2.resize(x, (2 * WIDTH, 2 * HEIGHT), interpolation=cv2.INTER_AREA).astype(float) for x in (full, reduced)
    ]
    assert np.abs(working[0] - working[1]).mean() < 2.0
    assert np.abs(full.astype(float) - reduced).max() > 0  # it did develop smaller


@pytest.mark.parametrize("max_width", [None, WIDTH // 4])
def test_light_near_the_limits_of_float32_develops_as_any_other(max_width, monkeypatch):
    if max_width is not None:  # developed smaller: its light averaged as well
        monkeypatch.setattr(images, "MAX_WIDTH", max_width)
    radiance = _radiance().astype(np.float64)
    for scale in (1e40, 1e-40, 1e37):  # beyond float32 both ways, and a float32 sum's overflow
        np.testing.assert_array_equal(develop_hdr(scale * radiance), develop_hdr(radiance))
    # a float32 file's light of 1e37 (an area average of 16 such pixels would overflow in float32)
    np.testing.assert_array_equal(develop_hdr((1e37 * radiance).astype(np.float32)), develop_hdr(radiance))


def test_negative_light_counts_as_black_and_not_a_number_is_refused():
    radiance = _radiance()
    negative = radiance.copy()
    negative[0, :8] = -5.0
    blacked = radiance.copy()
    blacked[0, :8] = 0.0
    np.testing.assert_array_equal(develop_hdr(negative), develop_hdr(blacked))
    for bad in (np.nan, np.inf):
        broken = radiance.copy()
        broken[3, 5, 1] = bad
        broken[4, 6] = bad
        with pytest.raises(PanoramaError, match="^2 pixels of the HDR image are not finite numbers"):
            develop_hdr(broken)


def test_float_images_of_one_or_four_channels_are_developed_as_rgb():
    radiance = _radiance()
    bgr = np.ascontiguousarray(radiance[..., ::-1])
    np.testing.assert_array_equal(to_rgb8(bgr), develop_hdr(radiance))
    bgra = np.dstack([bgr, np.ones((HEIGHT, WIDTH), np.float32)])
    np.testing.assert_array_equal(to_rgb8(bgra), develop_hdr(radiance))
    grey = radiance[..., 1]
    np.testing.assert_array_equal(to_rgb8(grey), develop_hdr(np.repeat(grey[..., None], 3, -1)))
    with pytest.raises(PanoramaError, match="unsupported pixel type int32"):
        to_rgb8(np.zeros((HEIGHT, WIDTH, 3), np.int32))


@pytest.mark.parametrize("suffix", [".hdr", ".exr", ".tif"])
def test_hdr_files_are_read_developed_with_a_warning(suffix, tmp_path, monkeypatch):
    monkeypatch.setenv("OPENCV_IO_ENABLE_OPENEXR", "1")  # for cv2.imwrite; the reader asks for it itself
    radiance = _radiance(1)
    path = tmp_path / f"room{suffix}"
    assert cv2.imwrite(str(path), np.ascontiguousarray(radiance[..., ::-1]))
    assert suffix in PANORAMA_SUFFIXES
    with pytest.warns(PanoramaDevelopedWarning, match=f"room{suffix}: a linear HDR image, developed to 8 bits"):
        image, data = read_image_file(path)
    assert data == path.read_bytes()
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[..., ::-1]  # Radiance's RGBE rounds the light
    np.testing.assert_array_equal(image, develop_hdr(stored))
    if suffix != ".hdr":
        np.testing.assert_array_equal(image, develop_hdr(radiance))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PanoramaDevelopedWarning)
        panorama = read_panorama_file(path)
    assert panorama.file_size == (WIDTH, HEIGHT) and panorama.crop is None
    np.testing.assert_array_equal(panorama.image, image)


def test_an_hdr_file_with_a_pixel_that_is_not_a_number_is_refused_in_one_line(tmp_path):
    radiance = _radiance()
    radiance[2, 2] = np.nan
    path = tmp_path / "broken.tif"
    assert cv2.imwrite(str(path), np.ascontiguousarray(radiance[..., ::-1]))
    with pytest.raises(PanoramaError, match=r"broken\.tif: 1 pixels of the HDR image are not finite") as error:
        read_image_file(path)
    assert "\n" not in str(error.value)


def test_opencv_errors_are_told_by_their_reason():
    message = (
        "OpenCV(4.14.0) /io/opencv/modules/imgcodecs/src/grfmt_exr.cpp:103: error: (-213:The function/feature is "
        "not implemented) imgcodecs: OpenEXR codec is disabled. You can enable it via 'OPENCV_IO_ENABLE_OPENEXR' "
        "option. Refer for details and cautions here: https://github.com/opencv/opencv/issues/21326 in function "
        "'initOpenEXR'\n"
    )
    assert one_line_cv2_error(cv2.error(message)) == (
        "imgcodecs: OpenEXR codec is disabled. You can enable it via 'OPENCV_IO_ENABLE_OPENEXR' option. Refer for "
        "details and cautions here: https://github.com/opencv/opencv/issues/21326"
    )
    assert one_line_cv2_error(cv2.error("something\nelse")) == "something else"  # not OpenCV's form: kept whole


_READ_IN_A_FRESH_PROCESS = """
import sys
from ncjax.io.images import PanoramaError, read_image_file
try:
    image, _ = read_image_file(sys.argv[1])
    print("read", image.shape)
except PanoramaError as error:
    print("refused:", error)
"""


@pytest.mark.parametrize("switch", [None, "0"], ids=["unset", "switched off"])
def test_the_reader_asks_opencv_for_its_openexr_reader_unless_the_user_said_no(switch, tmp_path, monkeypatch):
    """In a fresh process (OpenCV reads the switch once): an .exr file is read without the user setting anything;
    one who switched OpenEXR off gets one line that says so."""
    monkeypatch.setenv("OPENCV_IO_ENABLE_OPENEXR", "1")  # for cv2.imwrite here
    path = tmp_path / "room.exr"
    assert cv2.imwrite(str(path), np.ascontiguousarray(_radiance()[..., ::-1]))
    env = {k: v for k, v in os.environ.items() if k != "OPENCV_IO_ENABLE_OPENEXR"}
    if switch is not None:
        env["OPENCV_IO_ENABLE_OPENEXR"] = switch
    command = [sys.executable, "-c", _READ_IN_A_FRESH_PROCESS, str(path)]
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120, check=True)
    if switch is None:
        assert result.stdout.strip() == f"read ({HEIGHT}, {WIDTH}, 3)", result
    else:
        assert result.stdout.strip() == (
            f"refused: {path}: OpenCV cannot decode it: OpenCV's OpenEXR reader is switched off "
            "(OPENCV_IO_ENABLE_OPENEXR=0)"
        ), result
        assert "WARN" not in result.stderr, result.stderr  # OpenCV's own log line silenced


def test_a_corrupt_exr_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "room.exr"
    path.write_bytes(b"\x76\x2f\x31\x01" + bytes(64))  # OpenEXR's magic number, then nothing it can read
    with pytest.raises(PanoramaError, match=r"room\.exr: ") as error:
        read_image_file(path)
    assert "\n" not in str(error.value)
