"""A panorama file's EXIF orientation is applied as viewers apply it (Pillow's exif_transpose is the reference):
a panorama stored sideways or upside down is read upright."""

import numpy as np
import pytest
from PIL import Image, ImageOps

from ncjax.io.images import exif_orientation, read_image_file, read_panorama_file, upright


def _stored(height: int = 24, width: int = 48) -> np.ndarray:
    """An image no turn or mirror leaves unchanged: a ramp along each axis and a mark near one corner."""
    v, u = np.mgrid[0:height, 0:width]
    image = np.stack([5 * v, 5 * u % 256, np.full_like(u, 90)], axis=-1).astype(np.uint8)
    image[2:5, 3:7] = (255, 0, 255)
    return image


def _write(path, image: np.ndarray, orientation: int, **options) -> None:
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(image).save(path, exif=exif, **options)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_each_orientation_is_read_as_viewers_show_it(orientation, tmp_path):
    path = tmp_path / "pano.png"  # lossless: the same pixels for Pillow and OpenCV
    _write(path, _stored(), orientation)
    with Image.open(path) as file:
        shown = np.asarray(ImageOps.exif_transpose(file).convert("RGB"))
    image, data = read_image_file(path)
    assert exif_orientation(data) == orientation
    np.testing.assert_array_equal(image, shown)
    np.testing.assert_array_equal(upright(_stored(), orientation), shown)


def test_a_panorama_stored_sideways_is_read_upright_and_a_file_without_exif_as_stored(tmp_path):
    panorama = _stored(64, 128)
    sideways = tmp_path / "sideways.jpg"
    # stored a quarter turn anticlockwise, as a camera held sideways stores it
    _write(sideways, np.ascontiguousarray(np.rot90(panorama, 1)), 6, quality=100, subsampling=0)
    file = read_panorama_file(sideways)
    assert file.image.shape == (64, 128, 3) and file.file_size == (128, 64)
    assert np.abs(file.image.astype(int) - panorama.astype(int)).mean() < 1.5  # JPEG's loss
    plain = tmp_path / "plain.png"
    Image.fromarray(panorama).save(plain)
    image, data = read_image_file(plain)
    assert exif_orientation(data) == 1 and np.array_equal(image, panorama)
    assert exif_orientation(b"#?RADIANCE\n") == 1  # a format Pillow does not read
