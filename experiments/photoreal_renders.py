"""The same rooms rendered as today's training data and as photoreal training data, for the realism probe.

The rooms are those of the ``synth-decor-home`` training source (``ncjax.training.data.SYNTH_SOURCES``: central,
decor, pale walls in most of them), 512 x 1024, made through the dataset's own path (``rendered_samples``):

- ``raycast/``: the ray caster's 8-bit images, as ``synth-decor-home`` trains on them;
- ``photoreal/``: the same rooms as ``synth-photoreal-home`` renders them (``ncjax.synth.photoreal``, its default
  settings: path-traced at 256 x 512, 8 samples a pixel, 3 bounces, windows showing the shipped outdoor HDR
  panoramas and letting in their sun, denoised, the light brought to 512 x 1024 over the surfaces' albedo there,
  developed by the camera's metering, tone curve and white balance);
- ``photoreal_camera/``: the same radiance developed by the whole camera model (vignetting, stitching seams,
  the tripod at the nadir, sensor noise: ``ncjax.synth.photograph.PhotographConfig()``), which training leaves
  to its own augmentation;
- ``photoreal_local_tone/``: the same radiance fused and tone-mapped locally as an HDR capture
  (``PhotographConfig.local_compression`` 0.4-0.8: the windows show their view, shadowed corners lift);
- ``pathtrace/``: the same traces not denoised;
- ``photoreal_full_size/``: traced at the image's size (four times the paths).

Images already written are skipped. ``--sheet`` writes a contact sheet of the first rooms, one row per room and
one column per set.

    uv run python experiments/photoreal_renders.py            # about 6 minutes a set of 26 on 2 cores
    uv run python experiments/photoreal_renders.py --sheet
    uv run --with scikit-learn --with scipy python ../shared/tools/realism_probe/probe.py \\
        --real ../shared/data/real-dev "raycast=experiments/out/photoreal/raycast/*.png" ...
"""

import argparse
import dataclasses
import time
from pathlib import Path

import cv2
import numpy as np

from ncjax.cli.compilation import enable_compilation_cache
from ncjax.synth.dataset import rendered_samples, rendering_rgb8
from ncjax.synth.photograph import PhotographConfig
from ncjax.synth.photoreal import HDR_DEVELOPMENT
from ncjax.training.data import SYNTH_SOURCES

OUT = Path(__file__).parent / "out" / "photoreal"
SEED = 0
RAYCAST = SYNTH_SOURCES["synth-decor-home"]
PHOTOREAL = SYNTH_SOURCES["synth-photoreal-home"]
SETS = {
    "raycast": RAYCAST,
    "photoreal": PHOTOREAL,
    "photoreal_camera": dataclasses.replace(
        PHOTOREAL, photoreal=dataclasses.replace(PHOTOREAL.photoreal, camera=PhotographConfig())
    ),
    "photoreal_local_tone": dataclasses.replace(
        PHOTOREAL, photoreal=dataclasses.replace(PHOTOREAL.photoreal, camera=HDR_DEVELOPMENT)
    ),
    "pathtrace": dataclasses.replace(PHOTOREAL, photoreal=dataclasses.replace(PHOTOREAL.photoreal, denoise=None)),
    "photoreal_full_size": dataclasses.replace(
        PHOTOREAL, photoreal=dataclasses.replace(PHOTOREAL.photoreal, trace_scale=1)
    ),
}


def render(out: Path, rooms: int, sets: list[str]) -> None:
    for name in sets:
        folder = out / name
        folder.mkdir(parents=True, exist_ok=True)
        if len(list(folder.glob("*.png"))) >= rooms:
            continue
        start = time.perf_counter()
        for index, _, rendering, _ in rendered_samples(rooms, SEED, SETS[name], batch_size=2):
            path = folder / f"{index:03d}.png"
            if not cv2.imwrite(str(path), np.ascontiguousarray(rendering_rgb8(rendering)[..., ::-1])):
                raise OSError(f"could not write {path}")
        print(f"{name}: {rooms} rooms in {time.perf_counter() - start:.0f} s", flush=True)
    globs = " ".join(f'"{name}={out / name}/*.png"' for name in sets)
    print(
        "probe: uv run --with scikit-learn --with scipy python ../shared/tools/realism_probe/probe.py "
        f"--real ../shared/data/real-dev {globs}"
    )


def contact_sheet(out: Path, rows: int, sets: list[str]) -> Path:
    """``rows`` rooms at half size, one column per set."""
    names = sorted(p.name for p in (out / sets[0]).glob("*.png"))[:rows]
    if not names:
        raise FileNotFoundError(f"no images in {out / sets[0]}")
    tiles = [
        np.concatenate([cv2.resize(cv2.imread(str(out / folder / name)), (512, 256)) for folder in sets], 1)
        for name in names
    ]
    path = out / "contact_sheet.jpg"
    cv2.imwrite(str(path), np.concatenate(tiles, 0), [cv2.IMWRITE_JPEG_QUALITY, 85])
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=26, help="rooms (real-dev has 26 panoramas)")
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS), help="what to render")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--sheet", action="store_true", help="only write the contact sheet (6 rooms)")
    args = parser.parse_args()
    if args.sheet:
        print(f"wrote {contact_sheet(args.out, 6, args.sets)}")
        return
    enable_compilation_cache()
    render(args.out, args.n, args.sets)


if __name__ == "__main__":
    main()
