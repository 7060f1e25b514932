"""The product: reading panoramas, ``ncjax reconstruct`` (outputs, bad input, exit codes) and ``ncjax demo``."""

import json
import os
import pathlib

import cv2
import numpy as np
import pytest

import ncjax
from ncjax import cli
from ncjax._app import DEMO_DIR
from ncjax._images import PanoramaError, read_panorama

DEMO_TRUTH = json.loads((DEMO_DIR / "ground_truth.json").read_text())
SMALL = (512, 256)  # (W, H) of the small reconstruct tests: one compilation for all of them


def demo_image(size=None):
    image = cv2.imread(str(DEMO_DIR / DEMO_TRUTH["image"]), cv2.IMREAD_COLOR)[..., ::-1]
    return image if size is None else cv2.resize(image, size, interpolation=cv2.INTER_AREA)


def write_png(path, image_rgb_or_grey):
    array = image_rgb_or_grey
    if array.ndim == 3 and array.shape[-1] == 3:
        array = array[..., ::-1]
    elif array.ndim == 3 and array.shape[-1] == 4:
        array = array[..., [2, 1, 0, 3]]
    assert cv2.imwrite(str(path), array)
    return str(path)


# ----------------------------------------------------------------------------- reading files


def test_pixel_formats_become_rgb8(tmp_path):
    rgb = demo_image(SMALL)
    assert np.array_equal(read_panorama(write_png(tmp_path / "rgb.png", rgb)), rgb)
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 7, np.uint8)], -1)
    assert np.array_equal(read_panorama(write_png(tmp_path / "rgba.png", rgba)), rgb)
    grey = rgb[..., 1]
    read = read_panorama(write_png(tmp_path / "grey.png", grey))
    assert read.shape == rgb.shape and all(np.array_equal(read[..., c], grey) for c in range(3))
    # 16 bit: x / 257 rounds back to the 8-bit value
    deep = (rgb.astype(np.uint16) * 257 + np.where(rgb < 255, 100, 0)).astype(np.uint16)
    assert np.array_equal(read_panorama(write_png(tmp_path / "deep.png", deep)), rgb)


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.write_text("not a picture"), "not an image"),
        (lambda p: p.write_bytes(b""), "empty"),
        (lambda p: p.write_bytes(cv2.imencode(".png", demo_image(SMALL))[1].tobytes()[:5000]), "truncated"),
        (lambda p: p.write_bytes(cv2.imencode(".jpg", demo_image(SMALL))[1].tobytes()[:5000]), "truncated"),
        (lambda p: p.write_bytes(cv2.imencode(".png", demo_image((400, 300)))[1].tobytes()), "360 x 180"),
        (lambda p: None, "no such file"),
    ],
    ids=["text", "empty", "truncated-png", "truncated-jpeg", "aspect", "missing"],
)
def test_unusable_files_give_clear_errors(tmp_path, make, message):
    path = tmp_path / "pano.png"
    make(path)
    with pytest.raises(PanoramaError, match=message):
        read_panorama(path)


# ----------------------------------------------------------------------------- ncjax reconstruct


@pytest.mark.parametrize("rc", ["0", "-0.5", "50", "abc", "nan"])
def test_bad_rc_is_refused_before_anything_is_written(tmp_path, capsys, rc):
    out = tmp_path / "out"
    image = write_png(tmp_path / "room.png", demo_image(SMALL))
    assert cli.main(["reconstruct", image, "--rc", rc, "--out", str(out)]) == 2
    assert "--rc" in capsys.readouterr().err and not out.exists()


def test_images_that_would_overwrite_each_other_are_refused(tmp_path, capsys):
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    images = [write_png(tmp_path / folder / "room.png", demo_image(SMALL)) for folder in "ab"]
    assert cli.main(["reconstruct", *images, "--rc", "0.5", "--out", str(tmp_path / "out")]) == 2
    assert "room" in capsys.readouterr().err
