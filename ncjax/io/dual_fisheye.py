"""Telling a 360-degree camera's unstitched dual-fisheye image from an equirectangular panorama.

A consumer 360-degree camera records two fisheye images side by side (Insta360's ``.insp``, Ricoh Theta's and
Samsung Gear 360's dual-fisheye files): two discs on black, in a 2:1 frame, the very shape of an equirectangular
panorama. Read as one, it gives a room from nonsense rows without a word. :func:`looks_dual_fisheye` recognises it
by what only it has: in each square half, the corners outside the disc inscribed in the half are black, while inside
the disc, also near the top, the picture is lit. An equirectangular panorama's corners are the ceiling and floor
near the poles, seen along whole rows: where a stitcher filled the poles with black, the middle of its top rows is
black too.
"""

from __future__ import annotations

import numpy as np

DARK_LEVEL = 16  # 8-bit level below which a pixel counts as black (a fisheye's surround, JPEG-noisy)
DARK_SHARE = 0.97  # the share of the corners' pixels that must be black
LIT_LEVEL = 24  # the mean 8-bit level the disc's top band must exceed


def _half_masks(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Of a ``size x size`` half: its corners outside a disc of 0.53 of its size in radius (a fisheye's disc may
    touch the frame or be cropped by it a little), and the band of its top sixth inside a disc of 0.4 of its size."""
    centres = np.arange(size) + 0.5 - size / 2
    radius = np.hypot(centres[:, None], centres[None, :]) / size
    top = (np.arange(size) < size / 6)[:, None]
    return radius > 0.53, (radius < 0.4) & top


def looks_dual_fisheye(image: np.ndarray) -> bool:
    """Whether an RGB uint8 image (H, W, 3), W = 2 H, is two fisheye discs side by side rather than an
    equirectangular panorama: in both square halves the corners are black (:data:`DARK_SHARE` of them below
    :data:`DARK_LEVEL`) and the top of the disc is lit (its mean above :data:`LIT_LEVEL`). False for any other
    shape."""
    height, width = image.shape[:2]
    if width != 2 * height or height < 32:
        return False
    step = max(1, height // 256)  # a 256-row view decides as well as the full image
    grey = np.asarray(image[::step, ::step], np.float32).mean(axis=-1)
    size = grey.shape[0]
    corners, top = _half_masks(size)
    for half in (grey[:, :size], grey[:, size : 2 * size]):
        if np.mean(half[corners] < DARK_LEVEL) < DARK_SHARE or half[top].mean() <= LIT_LEVEL:
            return False
    return True
