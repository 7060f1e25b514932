"""Do photographs read better changed at the pixel level? The network on each panorama blurred, resampled or relit.

If what keeps the network's rows off on photographs were the pixels' statistics (the sensor's fine texture that
renders lack, the exposure, the contrast, the colour), a change of the input that brings them towards the renders'
would move the rows. Each transform below is applied to every labelled panorama of ``--data`` before the network
(4 views, edge snap on the changed image), which ``benchmarks/real_panoramas.py`` then scores as it scores the
originals (its ``run`` with a transform); the table gives its means (rows in px of a 512-row image).

    uv run python experiments/input_transforms.py --data DIR [--transforms none blur1 ...] [--out DIR]
"""

from __future__ import annotations

import argparse
import pathlib
from collections.abc import Callable

import cv2
import numpy as np

from common import benchmark_module, csv_means, quietly

real_panoramas = benchmark_module("real_panoramas")  # the benchmark, run with a transform

OUT = pathlib.Path(__file__).resolve().parent / "out" / "input_transforms"


def gaussian_blur(sigma: float) -> Callable[[np.ndarray], np.ndarray]:
    """Blur by a Gaussian of ``sigma`` pixels: the fine texture of carpets and sensor noise gone."""
    return lambda image: cv2.GaussianBlur(image, (0, 0), sigma)


def resampled(factor: int) -> Callable[[np.ndarray], np.ndarray]:
    """Shrink by ``factor`` (area) and enlarge back (linear): the detail of a ``factor`` times smaller panorama."""

    def transform(image: np.ndarray) -> np.ndarray:
        height, width = image.shape[:2]
        small = cv2.resize(image, (width // factor, height // factor), interpolation=cv2.INTER_AREA)
        return cv2.resize(small, (width, height), interpolation=cv2.INTER_LINEAR)

    return transform


def tone(gain: float = 1.0, gamma: float = 1.0) -> Callable[[np.ndarray], np.ndarray]:
    """``clip(gain * x) ** gamma`` on [0, 1] values: brighter or darker, more or less contrast in the shadows."""

    def transform(image: np.ndarray) -> np.ndarray:
        values = np.clip(gain * image.astype(np.float32) / 255.0, 0.0, 1.0) ** gamma
        return (255.0 * values + 0.5).astype(np.uint8)

    return transform


def local_contrast(image: np.ndarray) -> np.ndarray:
    """CLAHE on the lightness (clip 2, 8 x 16 tiles): every region's contrast stretched."""
    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB)
    lab[..., 0] = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 16)).apply(lab[..., 0])
    return cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)


def greyscale(image: np.ndarray) -> np.ndarray:
    """The channels' mean in all three: no colour."""
    return np.repeat(image.mean(axis=-1, keepdims=True), 3, axis=-1).round().astype(np.uint8)


TRANSFORMS: dict[str, tuple[str, Callable[[np.ndarray], np.ndarray] | None]] = {
    "none": ("the photographs as they are", None),
    "blur1": ("Gaussian blur, sigma 1 px", gaussian_blur(1.0)),
    "blur2": ("Gaussian blur, sigma 2 px", gaussian_blur(2.0)),
    "half": ("the detail of 512 x 256 (shrunk 2 times and back)", resampled(2)),
    "gain1.5": ("1.5 times brighter (the renders' mean grey level, 0.62 against 0.42)", tone(gain=1.5)),
    "gamma0.7": ("gamma 0.7 (shadows lifted)", tone(gamma=0.7)),
    "clahe": ("local contrast stretched (CLAHE on the lightness)", local_contrast),
    "grey": ("greyscale", greyscale),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--transforms", nargs="+", choices=list(TRANSFORMS), default=list(TRANSFORMS))
    parser.add_argument("--out", type=pathlib.Path, default=OUT, help=f"the benchmark's outputs (default {OUT})")
    args = parser.parse_args(argv)
    print("| input | ceiling px | floor px | floor signed px | P / R 1% | raw 3D IoU | closed: ceiling / floor px |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for name in args.transforms:
        description, transform = TRANSFORMS[name]
        out = args.out / name
        benchmark_args = real_panoramas.parse_arguments(["--data", str(args.data), "--out", str(out)])
        try:
            quietly(real_panoramas.run, benchmark_args, transform)
        except real_panoramas.InputError as error:
            parser.error(str(error))
        means = {name.split(" (")[0]: row for name, row in csv_means(out / real_panoramas.CSV_NAME).items()}
        every, closed = means["mean"], means.get("mean closed")
        closed_rows = "-" if closed is None else f"{float(closed['ceiling_error_px']):.1f}"
        closed_rows += "" if closed is None else f" / {float(closed['floor_error_px']):.1f}"
        cells = [
            f"{float(every['ceiling_error_px']):.1f}",
            f"{float(every['floor_error_px']):.1f}",
            f"{float(every['floor_signed_error_px']):+.1f}",
            f"{float(every['precision_1pct']):.2f} / {float(every['recall_1pct']):.2f}",
            f"{float(every['iou_3d']):.3f}",
            closed_rows,
        ]
        print(f"| {description} | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
