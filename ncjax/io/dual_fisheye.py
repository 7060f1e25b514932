"""Telling a 360-degree camera's unstitched dual-fisheye image from an equirectangular panorama.

A consumer 360-degree camera records two fisheye images side by side (Insta360's ``.insp``, Ricoh Theta's and
Samsung Gear 360's dual-fisheye files): two discs on black, in a 2:1 frame, the very shape of an equirectangular
panorama. Read as one, it gives a room from nonsense rows without a word. :func:`looks_dual_fisheye` recognises it
by what only it has: in each square half, the corners outside the disc are black while the picture inside the disc
is lit all the way round its edge. An equirectangular panorama's corners are the ceiling and floor near the poles,
seen along whole rows: where a stitcher filled the poles with black, or the room is dark, the disc's edge is dark too
over much of its round.
"""

from __future__ import annotations

import numpy as np

DARK_LEVEL = 16  # 8-bit level below which a pixel counts as black (a fisheye's surround, JPEG-noisy)
DARK_SHARE = 0.97  # the share of the corners' pixels that must be black
LIT_LEVEL = 24  # the mean 8-bit level above which a sector of the disc's edge counts as lit
SECTORS = 12  # the disc's edge in sectors of 30 degrees
LIT_SECTORS = 9  # how many of them must be lit


def _half_masks(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Of a ``size x size`` half: its corners outside a disc of 0.53 of its size in radius (a fisheye's disc may
    touch the frame or be cropped by it a little), and the sector (0 to :data:`SECTORS` - 1, -1 elsewhere) of each
    pixel of the ring just inside the disc's edge, 0.38 to 0.47 of its size from the centre."""
    centres = np.arange(size) + 0.5 - size / 2
    radius = np.hypot(centres[:, None], centres[None, :]) / size
    around = np.arctan2(centres[:, None], centres[None, :]) % (2 * np.pi)
    sector = np.minimum((around / (2 * np.pi) * SECTORS).astype(int), SECTORS - 1)
    return radius > 0.53, np.where((radius > 0.38) & (radius < 0.47), sector, -1)


def looks_dual_fisheye(image: np.ndarray) -> bool:
    """Whether an RGB uint8 image (H, W, 3), W = 2 H, is two fisheye discs side by side rather than an
    equirectangular panorama: in both square halves the corners are black (:data:`DARK_SHARE` of them below
    :data:`DARK_LEVEL`) and the ring inside the disc's edge is lit (:data:`LIT_SECTORS` of its :data:`SECTORS`
    above :data:`LIT_LEVEL` on average). False for any other shape."""
    height, width = image.shape[:2]
    if width != 2 * height or height < 32:
        return False
    step = max(1, height // 256)  # a 256-row view decides as well as the full image
    halves = [
        np.asarray(image[::step, start : start + height : step], np.float32).mean(axis=-1) for start in (0, height)
    ]
    corners, ring = _half_masks(halves[0].shape[0])
    for half in halves:
        lit = [half[ring == k].mean() > LIT_LEVEL for k in range(SECTORS)]
        if np.mean(half[corners] < DARK_LEVEL) < DARK_SHARE or sum(lit) < LIT_SECTORS:
            return False
    return True
