"""Linear HDR panorama files (Radiance .hdr, OpenEXR, floating-point TIFF): read, developed to 8 bits as
``ncjax.io.images.develop_hdr`` says, refused with one line when a pixel is not a number."""

import warnings

import cv2
import numpy as np
import pytest

from ncjax.io.images import (
    PANORAMA_SUFFIXES,
    PanoramaDevelopedWarning,
    PanoramaError,
    develop_hdr,
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


def test_development_keeps_the_walls_order_and_compresses_the_window():
    radiance = _radiance()
    assert develop_hdr(radiance).dtype == np.uint8
    image = develop_hdr(radiance).astype(np.float64)
    walls = np.ones((HEIGHT, WIDTH), bool)
    walls[8:14, 20:28] = False
    # brighter light, brighter pixel, across the walls (the tone curve is monotonic; the local compression keeps
    # the order of neighbours of the same large-scale light)
    light, shown = radiance[walls].mean(-1), image[walls].mean(-1)
    order = np.argsort(light)
    assert np.corrcoef(light[order], shown[order])[0, 1] > 0.9
    assert image[8:14, 20:28].mean() > 240  # the window blows out, as in a photograph
    np.testing.assert_array_equal(develop_hdr(radiance), develop_hdr(radiance.copy()))  # deterministic


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


def test_a_corrupt_exr_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "room.exr"
    path.write_bytes(b"\x76\x2f\x31\x01" + bytes(64))  # OpenEXR's magic number, then nothing it can read
    with pytest.raises(PanoramaError, match=r"room\.exr: ") as error:
        read_image_file(path)
    assert "\n" not in str(error.value)
