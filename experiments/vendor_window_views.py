"""Ship the outdoor CC0 HDR panoramas that windows show in path-traced training rooms (run once).

Reads the outdoor photographs of ``../shared/data/cc0-hdri`` (Poly Haven's HDRIs, CC0 1.0; the night left out: its
windows would be black), greys the sun texels two of them store as blue alone, shrinks each to 96 x 192 with
pixel-area averaging (a window spans about a tenth of the panorama: 19 texels), clamps the texels that the source's
resampling left below 0, and writes them as one float16 array ``(N, 96, 192, 3)``, linear RGB in the panorama's
pixel<->angle convention, to ``ncjax/data/window_views/outdoor.npz`` with their names, beside the licence and a
README that names the source.

    uv run python experiments/vendor_window_views.py
"""

import os

# OpenCV reads OpenEXR only when asked to before it is imported.
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import shutil
from pathlib import Path

import cv2
import numpy as np

SOURCE = Path(__file__).parents[2] / "shared" / "data" / "cc0-hdri"
TARGET = Path(__file__).parents[1] / "ncjax" / "data" / "window_views"
OUTDOOR = ("bridge", "city", "dawn", "esplanade", "forest", "park", "sky", "sunrise", "sunset", "venice")
HEIGHT, WIDTH = 96, 192

README = """# What windows show: real outdoor HDR panoramas, CC0

`outdoor.npz`: `views`, float16 (N, 96, 192, 3), linear RGB equirectangular panoramas (ncjax's pixel<->angle
convention: the top row looks up), and `names`. They are {names}: Poly Haven's HDRIs as the npm package
`@pmndrs/assets` 1.7.0 ships them (`hdri/*.exr.js`), public domain (CC0 1.0, `LICENSE`), shrunk from
512 x 256 with pixel-area averaging and clamped at 0 (the sun texels park and sunrise store as blue alone made
grey) by `experiments/vendor_window_views.py`.

`ncjax.synth.photoreal` shows them through the windows of path-traced rooms and lights the rooms with them.
"""


def _neutral_where_only_blue(image: np.ndarray) -> np.ndarray:
    """Two sources (park, sunrise) store their sun's texels as blue alone, red and green under 1% of it (their
    encoding lost them): those bright texels become grey at their blue, so that the sun they make is not blue."""
    red, green, blue = image[..., 0], image[..., 1], image[..., 2]
    only_blue = (blue > 10 * np.median(image.max(-1))) & (np.maximum(red, green) < 0.01 * blue)
    return np.where(only_blue[..., None], blue[..., None], image)


def main():
    views = []
    for name in OUTDOOR:
        image = cv2.imread(str(SOURCE / f"{name}.exr"), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise FileNotFoundError(f"cannot read {SOURCE / name}.exr")
        image = np.maximum(image[..., ::-1].astype(np.float32), 0.0)
        image = _neutral_where_only_blue(image)
        views.append(np.maximum(cv2.resize(image, (WIDTH, HEIGHT), interpolation=cv2.INTER_AREA), 0.0))
    TARGET.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(TARGET / "outdoor.npz", views=np.stack(views).astype(np.float16), names=np.array(OUTDOOR))
    shutil.copyfile(SOURCE / "LICENSE", TARGET / "LICENSE")
    (TARGET / "README.md").write_text(README.format(names=", ".join(OUTDOOR)))
    print(f"wrote {TARGET / 'outdoor.npz'} ({(TARGET / 'outdoor.npz').stat().st_size / 1e6:.2f} MB)")


if __name__ == "__main__":
    main()
