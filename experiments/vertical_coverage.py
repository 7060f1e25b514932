"""How much of the sphere a panorama needs: labelled panoramas cut to photo spheres without their poles.

Each labelled panorama of ``--data`` (as ``benchmarks/real_panoramas.py`` reads them) is cut to the rows within
``+-coverage / 2`` degrees of the horizon and written as a PNG with the XMP GPano metadata a phone's photo sphere
carries (its place in the full panorama), beside a copy of its label (the full panorama's pixels). Both benchmarks
then run on each such folder as on the originals: ``benchmarks/real_panoramas.py`` (the network's rows and
corners; the photo sphere padded with black to its full panorama, :mod:`ncjax.io.photo_sphere`) and
``benchmarks/central_layouts.py`` (``ncjax reconstruct --rc 0``, which pads it the same way, its label_cor exported
in the full panorama's pixels). A row whose label lies in the cut-off part is still scored: the network has to
guess it.

    uv run python experiments/vertical_coverage.py --data DIR [--coverages 180 150 120 100 90] [--out DIR]
"""

from __future__ import annotations

import argparse
import pathlib
import shutil

from ncjax.evaluation.panorama_labels import labelled_image_paths, read_labelled_image
from ncjax.io.photo_sphere import XMP_GPANO, SphereCrop, gpano_packet, png_with_xmp

from common import benchmark_module, csv_means, quietly

OUT = pathlib.Path(__file__).resolve().parent / "out" / "vertical_coverage"


def photo_spheres(data: pathlib.Path, coverage: float, folder: pathlib.Path) -> None:
    """Every labelled panorama of ``data`` cut to ``coverage`` degrees about the horizon, into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    for image_path, label_path in labelled_image_paths(data):
        image = read_labelled_image(image_path)
        height, width = image.shape[:2]
        rows = 2 * round(height * coverage / 360)
        top = (height - rows) // 2
        crop = SphereCrop(width, height, top, width, rows, XMP_GPANO)
        (folder / f"{image_path.stem}.png").write_bytes(png_with_xmp(image[top : top + rows], gpano_packet(crop)))
        shutil.copy(label_path, folder / label_path.name)
        tags = image_path.with_suffix(".json")
        if tags.is_file():
            shutil.copy(tags, folder / tags.name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--coverages", type=float, nargs="+", default=[180, 150, 120, 100, 90], help="degrees")
    parser.add_argument("--out", type=pathlib.Path, default=OUT, help=f"work and output folder (default {OUT})")
    args = parser.parse_args(argv)
    if not labelled_image_paths(args.data):
        parser.error(f"{args.data}: no panorama with a label_cor <stem>.txt")
    if not all(0 < coverage <= 180 for coverage in args.coverages):
        parser.error(f"--coverages: each in (0, 180] degrees, got {args.coverages}")
    print("| vertical coverage | ceiling px | floor px | P / R 1% | raw 3D IoU | closed: floor px | central layouts |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for coverage in args.coverages:
        name = f"{coverage:g}"
        if coverage == 180:
            images = args.data
        else:
            images = args.out / f"spheres_{name}"
            photo_spheres(args.data, coverage, images)
        rows_out, layouts_out = args.out / f"rows_{name}", args.out / f"layouts_{name}"
        for benchmark, out in (("real_panoramas", rows_out), ("central_layouts", layouts_out)):
            code = quietly(benchmark_module(benchmark).main, ["--data", str(images), "--out", str(out)])
            if code != 0:
                raise SystemExit(f"vertical_coverage: {benchmark} exited with code {code}")
        means = csv_means(rows_out / "real_panoramas.csv")
        everything = next(row for key, row in means.items() if key.startswith("mean ("))
        closed = next((row for key, row in means.items() if key.startswith("mean closed")), None)
        layouts = next(iter(csv_means(layouts_out / "central_layouts.csv").values()))
        cells = [
            f"{float(everything['ceiling_error_px']):.1f}",
            f"{float(everything['floor_error_px']):.1f}",
            f"{float(everything['precision_1pct']):.2f} / {float(everything['recall_1pct']):.2f}",
            f"{float(everything['iou_3d']):.3f}",
            "-" if closed is None else f"{float(closed['floor_error_px']):.1f}",
            f"{float(layouts['iou3d']):.3f}",
        ]
        print(f"| {name} degrees | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
