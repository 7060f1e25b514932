"""What in the photoreal renders moves a head's floor rows on photographs: one setting changed at a time.

Heads trained on the shipped backbone's frozen features read the photographs' floors worse after the photoreal
renders than after the same rooms ray-cast (experiments/RESULTS.md, "What the photoreal renders teach"). This
script trains such a head (``experiments/frozen_backbone.py``, 8 epochs, ``--backbone shipped``) on the rooms of
``synth-photoreal-open:SEED:N`` rendered with one setting changed, and scores it on labelled photographs
(``benchmarks/real_panoramas.py``), printing one line per variant: the ceiling and floor rows (px of 512) and the raw
3D IoU over all images and over the open-plan ones, and the floor rows' mean signed error. Every variant but
``raycast`` and ``photoreal`` traces at a quarter of the paths (``quarter``: the light at a quarter of the image's
size, 4 paths a pixel; 3 s a room on 2 cores instead of 15 s):

- ``raycast``, ``photoreal``: ``synth-decor-open`` and ``synth-photoreal-open`` as they are;
- ``quarter``; ``matte``: no glossy lobe on the floor; ``no-sun``; ``flat-windows``: the windows show each view's
  mean colour (so no sun); ``direct``: 1 bounce, no interreflection; ``six-bounces``;
- ``local-tone``: the camera fuses an HDR capture and tone-maps it locally (``PhotographConfig.local_compression``
  0.4-0.8: the windows show their view, shadowed corners lift);
- ``raycast-developed``: the ray caster's image taken back to radiance and developed by the photoreal camera
  (metering, tone curve, white balance), no path tracing;
- ``both``: the rooms ray-cast and at a quarter of the paths, twice the images.

Renders and features are cached by ``frozen_backbone.py`` (``experiments/out/frozen_shipped_<kind>_...npz``), the
heads written to ``experiments/out/factor_<variant>[_<rooms>][_imagenet][_epochs<E>][_seed<S>].safetensors``.

``--backbone imagenet`` trains the heads on ImageNet's frozen features instead of the shipped model's, which its
training adapted to ray-cast renders (and so may favour them).

    uv run python experiments/photoreal_factors.py --data DIR [--variants NAME ...] [--seed S] [--rooms 701:120]
        [--backbone imagenet] [--epochs 8]
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import importlib
import pathlib
import subprocess
import sys
from unittest import mock

import frozen_backbone
import numpy as np

from ncjax.synth.photograph import photograph
from ncjax.synth.photoreal import HDR_DEVELOPMENT, window_views
from ncjax.training.data import SYNTH_SOURCES

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "out"
PHOTOREAL = SYNTH_SOURCES["synth-photoreal-open"]
DEFAULT_ROOMS = "701:120"
# The module itself (``ncjax.synth.render`` as an attribute is the package's ``render`` function).
render_module = importlib.import_module("ncjax.synth.render")


def _photoreal(trace: dict | None = None, **settings):
    """``synth-photoreal-open`` at a quarter of the paths (the light traced at a quarter of the image's size, 4 paths
    a pixel), with ``settings`` on its :class:`PhotorealConfig` and ``trace`` on its tracer's."""
    photoreal = PHOTOREAL.photoreal
    trace = {"samples_per_pixel": 4, **(trace or {})}
    photoreal = dataclasses.replace(
        photoreal, trace=dataclasses.replace(photoreal.trace, **trace), **{"trace_scale": 4, **settings}
    )
    return dataclasses.replace(PHOTOREAL, photoreal=photoreal)


def flat_window_views() -> np.ndarray:
    """The shipped window views, each replaced by its mean colour."""
    views = window_views()
    return np.broadcast_to(views.mean((1, 2), keepdims=True), views.shape).copy()


def developed_raycast(key, scene, cam, views, config):
    """In place of :func:`ncjax.synth.photoreal.photoreal_image`: the ray caster's image of ``synth-photoreal-open``'s
    rooms, its radiance developed by the photoreal camera (``config.camera``), no path tracing."""
    del views
    rgb = render_module.render(scene, cam, PHOTOREAL.render).rgb
    return photograph(key, render_module.radiance_from_colours(rgb), config.camera)


# The variants' sources, registered beside ncjax train's (SYNTH_SOURCES) when the module loads.
SOURCES = {
    "photoreal-quarter": _photoreal(),
    "photoreal-matte": _photoreal(trace={"floor_specular": 0.0}),
    "photoreal-no-sun": _photoreal(sun=False),
    "photoreal-flat-windows": _photoreal(sun=False),
    "photoreal-direct": _photoreal(trace={"bounces": 1}),
    "photoreal-six-bounces": _photoreal(trace={"bounces": 6}),
    "photoreal-local-tone": _photoreal(camera=HDR_DEVELOPMENT),
    "raycast-developed": _photoreal(),
}
SYNTH_SOURCES.update(SOURCES)

# name: (the source kinds its head trains on, the renderer's functions replaced while they render)
VARIANTS = {
    "raycast": (("synth-decor-open",), {}),
    "photoreal": (("synth-photoreal-open",), {}),
    "quarter": (("photoreal-quarter",), {}),
    "matte": (("photoreal-matte",), {}),
    "no-sun": (("photoreal-no-sun",), {}),
    "flat-windows": (("photoreal-flat-windows",), {"window_views": flat_window_views}),
    "direct": (("photoreal-direct",), {}),
    "six-bounces": (("photoreal-six-bounces",), {}),
    "local-tone": (("photoreal-local-tone",), {}),
    "raycast-developed": (("raycast-developed",), {"photoreal_image": developed_raycast}),
    "both": (("synth-decor-open", "photoreal-quarter"), {}),
}


def head(variant: str, rooms: str, seed: int, backbone: str = "shipped", epochs: int = 8) -> pathlib.Path:
    """Train (or find) the head of ``variant`` on ``rooms`` (SEED:N) with head seed ``seed`` on the frozen
    ``backbone`` (``frozen_backbone.py --backbone``) for ``epochs``; its model file."""
    kinds, replaced = VARIANTS[variant]
    suffix = f"_{rooms.replace(':', '_')}" if rooms != DEFAULT_ROOMS else ""
    suffix += (f"_{backbone}" if backbone != "shipped" else "") + (f"_epochs{epochs}" if epochs != 8 else "")
    suffix += f"_seed{seed}" if seed else ""
    export = OUT / f"factor_{variant}{suffix}.safetensors"
    if not export.exists():
        with contextlib.ExitStack() as stack:
            for name, function in replaced.items():
                stack.enter_context(mock.patch.object(render_module, name, function))
            data = ["--data", *(f"{kind}:{rooms}" for kind in kinds)]
            arguments = [*data, "--backbone", backbone, "--seed", str(seed), "--epochs", str(epochs)]
            arguments += ["--export", str(export)]
            if frozen_backbone.main(arguments):
                raise RuntimeError(f"the head of {variant} did not train")
    return export


def scores(model: pathlib.Path, data: pathlib.Path) -> dict[str, dict[str, str]]:
    """``benchmarks/real_panoramas.py``'s mean rows for ``model`` on ``data``, by name."""
    out = OUT / f"{model.stem}_real_panoramas"
    command = [sys.executable, str(ROOT / "benchmarks" / "real_panoramas.py"), "--data", str(data), "--model"]
    subprocess.run([*command, str(model), "--out", str(out)], check=True, capture_output=True)
    with open(out / "real_panoramas.csv") as table:
        return {row["name"]: row for row in csv.DictReader(table) if row["name"].startswith("mean")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="labelled photographs (real_panoramas.py)")
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--seed", type=int, default=0, help="the heads' seed (frozen_backbone.py --seed)")
    parser.add_argument("--rooms", default=DEFAULT_ROOMS, help="SEED:N of the open-plan rooms")
    parser.add_argument(
        "--backbone",
        choices=("shipped", "imagenet"),
        default="shipped",
        help="the frozen backbone: the shipped model's (adapted to ray-cast renders) or ImageNet's (neither's)",
    )
    parser.add_argument("--epochs", type=int, default=8, help="the heads' epochs (frozen_backbone.py --epochs)")
    args = parser.parse_args(argv)
    if not args.data.is_dir():
        parser.error(f"--data {args.data} is not a folder")
    print("| variant | ceiling | floor | 3D IoU | open plan: floor / IoU | floor signed (below the label +) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for variant in args.variants:
        means = scores(head(variant, args.rooms, args.seed, args.backbone, args.epochs), args.data)
        every = next(iter(means.values()))  # the mean over all images comes first
        open_plan = next((row for name, row in means.items() if "open_plan" in name), None)
        line = f"| {variant} | {float(every['ceiling_error_px']):.1f} | {float(every['floor_error_px']):.1f} | "
        line += f"{float(every['iou_3d']):.3f} | "
        line += f"{float(open_plan['floor_error_px']):.1f} / {float(open_plan['iou_3d']):.3f} |" if open_plan else "- |"
        line += f" {float(every['floor_signed_error_px']):+.1f} |"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
