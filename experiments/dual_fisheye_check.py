"""Does ``ncjax reconstruct`` tell unstitched dual-fisheye images from equirectangular panoramas?

A 360-degree camera's unstitched file is two fisheye discs side by side in a 2:1 frame
(``ncjax.io.dual_fisheye.looks_dual_fisheye``). This counts, over every panorama of the given folders, the
equirectangular panoramas taken for dual-fisheye images (false alarms) and, made from each of them, the dual-fisheye
images of two back-to-back equidistant fisheye lenses (:func:`dual_fisheye_view`, the lenses' fields of view
``--fovs``) that are not (misses).

    uv run python experiments/dual_fisheye_check.py ../shared/data/real-dev ../shared/data/cc0-hdri \
        ../shared/data/noncentral-real [--fovs 180 190 200]
"""

from __future__ import annotations

import argparse
import pathlib
import warnings

import cv2
import numpy as np

from ncjax.io.dual_fisheye import looks_dual_fisheye
from ncjax.io.images import PANORAMA_SUFFIXES, read_image_file, working_size


def dual_fisheye_view(panorama: np.ndarray, fov_degrees: float = 190.0) -> np.ndarray:
    """The dual-fisheye image (H, 2H, 3) of an equirectangular panorama (H, 2H, 3): two equidistant fisheye lenses
    of ``fov_degrees``, back to back along the panorama's centre column, each disc inscribed in its square half,
    black around it."""
    height = panorama.shape[0]
    centres = (np.arange(height) + 0.5) / height * 2 - 1  # -1 .. 1 across a half
    x, y = np.meshgrid(centres, centres)
    radius = np.hypot(x, y)
    off_axis = radius * np.radians(fov_degrees) / 2  # equidistant: angle from the lens axis grows with the radius
    around = np.arctan2(-y, x)
    halves = []
    for facing in (1.0, -1.0):  # the front lens, then the back one, facing the other way
        forward = facing * np.cos(off_axis)
        right, up = facing * np.sin(off_axis) * np.cos(around), np.sin(off_axis) * np.sin(around)
        azimuth, elevation = np.arctan2(right, forward), np.arcsin(np.clip(up, -1, 1))
        columns = (azimuth / (2 * np.pi) + 0.5) * 2 * height - 0.5
        rows = (0.5 - elevation / np.pi) * height - 0.5
        half = cv2.remap(panorama, columns.astype(np.float32), rows.astype(np.float32), cv2.INTER_LINEAR, None,
                         cv2.BORDER_WRAP)  # fmt: skip
        half[radius > 1] = 0
        halves.append(half)
    return np.concatenate(halves, axis=1)


def full_panorama(path: pathlib.Path) -> np.ndarray | None:
    """A panorama file as ``ncjax reconstruct`` checks it: 2:1 RGB uint8 at its working size (a near-2:1 one made
    2:1, a wide one brought to 2048 columns), or None for another shape."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # HDR files' development notes
        image, _ = read_image_file(path)
    height, width = image.shape[:2]
    if abs(width / (2 * height) - 1) > 0.01:
        return None
    resize = working_size(width, height)
    if resize is None:
        return image
    return cv2.resize(image, (resize[0], resize[0] // 2), interpolation=cv2.INTER_AREA)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", type=pathlib.Path, nargs="+", help="folders of equirectangular panoramas")
    parser.add_argument("--fovs", type=float, nargs="+", default=[180.0, 190.0, 200.0])
    args = parser.parse_args(argv)
    paths = [p for folder in args.folders for p in sorted(folder.iterdir()) if p.suffix.lower() in PANORAMA_SUFFIXES]
    panoramas = {p: image for p in paths if (image := full_panorama(p)) is not None}
    false_alarms = [p.name for p, image in panoramas.items() if looks_dual_fisheye(image)]
    print(f"{len(panoramas)} equirectangular panoramas: {len(false_alarms)} taken for dual-fisheye {false_alarms}")
    for fov in args.fovs:
        misses = [p.name for p, image in panoramas.items() if not looks_dual_fisheye(dual_fisheye_view(image, fov))]
        print(f"their dual-fisheye images at {fov:g} degrees: {len(misses)} of {len(panoramas)} missed {misses}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
