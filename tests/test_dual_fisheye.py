"""Unstitched dual-fisheye images (two fisheye discs on black in a 2:1 frame) told from equirectangular panoramas,
and refused in one line; the demo panorama, one with black poles and a dark one are not taken for one."""

import json

import cv2
import numpy as np
import pytest
from _scripts import script_module

from ncjax.cli.demo import DEMO_DIR
from ncjax.io.dual_fisheye import looks_dual_fisheye
from ncjax.io.images import PanoramaError, read_panorama_file

dual_fisheye_view = script_module("experiments", "dual_fisheye_check").dual_fisheye_view


@pytest.fixture(scope="module")
def demo():
    name = json.loads((DEMO_DIR / "ground_truth.json").read_text())["image"]
    return cv2.imread(str(DEMO_DIR / name), cv2.IMREAD_COLOR)[..., ::-1].copy()


@pytest.mark.parametrize("fov", [180.0, 200.0])
def test_the_dual_fisheye_image_of_a_panorama_is_one_and_the_panorama_is_not(demo, fov):
    fisheyes = dual_fisheye_view(demo, fov)
    assert fisheyes.shape == demo.shape
    assert looks_dual_fisheye(fisheyes) and not looks_dual_fisheye(demo)


def test_black_poles_a_dark_room_and_other_shapes_are_not_dual_fisheye(demo):
    poles = demo.copy()
    poles[: len(demo) // 3] = 0  # a stitcher's black fill above 30 degrees of elevation and below -30
    poles[-len(demo) // 3 :] = 0
    assert not looks_dual_fisheye(poles)
    dark = (demo // 16).astype(np.uint8)  # a dark room: its corners are dark too
    assert not looks_dual_fisheye(dark)
    # ... with two ceiling lamps about 72 degrees up, above the middle of each half (where a fisheye's disc is lit)
    for column in (256, 768):
        cv2.circle(dark, (column, 51), 20, (255, 255, 240), -1)
    assert not looks_dual_fisheye(dark)
    assert not looks_dual_fisheye(np.zeros_like(demo))
    assert not looks_dual_fisheye(dual_fisheye_view(demo)[:, :-2])  # not 2:1


@pytest.mark.parametrize("height", [513, 769, 1000])
def test_sizes_whose_view_is_subsampled_unevenly_are_told_too(demo, height):
    """Heights the 256-row view does not divide: both halves are read whole, none a column short."""
    panorama = cv2.resize(demo, (2 * height, height), interpolation=cv2.INTER_AREA)
    assert looks_dual_fisheye(dual_fisheye_view(panorama)) and not looks_dual_fisheye(panorama)


def test_a_dual_fisheye_file_is_refused_in_one_line(demo, tmp_path):
    path = tmp_path / "IMG_0001.png"
    assert cv2.imwrite(str(path), dual_fisheye_view(demo)[..., ::-1])
    with pytest.raises(PanoramaError, match=r"IMG_0001\.png: two fisheye discs on black, not an equirectangular") as e:
        read_panorama_file(path)
    assert "\n" not in str(e.value)
    assert cv2.imwrite(str(path), demo[..., ::-1])
    assert read_panorama_file(path).image.shape == demo.shape
