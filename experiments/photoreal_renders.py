"""The same rooms rendered two ways, for the realism probe: today's ray caster, and the path tracer developed by a
consumer 360-degree camera's model (``ncjax.synth.photograph``).

The rooms are those of ``ncjax synth --decor --shadows --rc 0:0`` (central, so the probe compares like with like
against the central real panoramas), made through the dataset's own path (``rendered_samples``). Both are rendered
at ``--size`` (256 x 512 by default, what 2 cores path-trace in seconds) and upsampled bilinearly to 512 x 1024,
the probe's size:

- ``raycast/``: the ray caster's 8-bit image, as the dataset stores it;
- ``raycast_camera/``: the same image made linear again (gamma 2.2) and developed by the camera model, which tells
  the camera's share of a difference from the light's;
- ``pathtrace/``: the path tracer's radiance (area lights sampled at every bounce, windows showing an outdoor CC0
  HDR photograph, turned and scaled at random, and lighting the room through their glass), upsampled, then
  developed by the camera model;
- ``pathtrace_denoised/``: the same radiance denoised (``ncjax.synth.pathtrace_denoise``: the irradiance smoothed
  within each surface, guided by the primary hits' albedo, normal and depth) before it is upsampled and developed.

Resumable: images already written are skipped, and ``--count`` bounds the path traces of one call (about 30 s each
on 2 cores at 16 spp), so that a long run goes in chunks. ``--sheet`` writes a contact sheet of what exists.

    uv run python experiments/photoreal_renders.py --count 8      # repeat until all are written
    uv run python experiments/photoreal_renders.py --sheet
"""

import os

# OpenCV reads the HDR photographs (OpenEXR) only when asked to before it is imported.
os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

import argparse
import functools
import time
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.cli.compilation import enable_compilation_cache
from ncjax.synth.dataset import rendered_samples, rendering_rgb8, sample_name
from ncjax.synth.pathtrace import PathTraceConfig, path_trace
from ncjax.synth.pathtrace_denoise import denoise, guide_buffers
from ncjax.synth.photograph import PhotographConfig, luminance, photograph

OUT = Path(__file__).parent / "out" / "photoreal"
PROBE_HEIGHT, PROBE_WIDTH = 512, 1024
HDRI = Path(__file__).parents[2] / "shared" / "data" / "cc0-hdri"
# What a window shows: the outdoor photographs (night left out: its windows would be black)
OUTDOOR = ("bridge", "city", "dawn", "esplanade", "forest", "park", "sky", "sunrise", "sunset", "venice")
SETS = ("raycast", "raycast_camera", "pathtrace", "pathtrace_denoised")
SEED = 0  # ncjax synth's default


def synth_config(height: int, width: int) -> ncjax.SynthConfig:
    """The settings of ``ncjax synth --decor --shadows --rc 0:0 --size HxW``."""
    return ncjax.SynthConfig(
        room=ncjax.RoomConfig(world="mix", rc_range=(0.0, 0.0)),
        scene=ncjax.synth.SceneConfig(decor=True),
        render=ncjax.synth.RenderConfig(supersampling=1, shadows=True),
        width=width,
        height=height,
    )


def environment(index: int, brightness: float, sun_clip: float) -> np.ndarray:
    """The outdoor HDR photograph of room ``index`` (one of :data:`OUTDOOR` in turn), turned by a random
    azimuth, scaled to a median luminance of ``brightness`` and clipped at ``sun_clip`` times it: the sun, a
    thousand times the sky, would be found through a window only by chance (fireflies)."""
    rng = np.random.default_rng(index)
    name = OUTDOOR[index % len(OUTDOOR)]
    image = cv2.imread(str(HDRI / f"{name}.exr"), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise FileNotFoundError(f"cannot read {HDRI / name}.exr")
    image = np.maximum(image[..., ::-1].astype(np.float32), 0.0)  # resampling left texels below 0 around the sun
    level = np.asarray(luminance(jnp.asarray(image)))
    factor = brightness * rng.uniform(0.7, 1.4) / np.median(level)
    clipped = np.minimum(1.0, sun_clip * brightness / np.maximum(level * factor, 1e-12))
    return np.roll(image * (factor * clipped)[..., None], rng.integers(image.shape[1]), axis=1)


def upsampled(image: np.ndarray) -> np.ndarray:
    """Bilinear resize to the probe's 512 x 1024 (either image type)."""
    return cv2.resize(image, (PROBE_WIDTH, PROBE_HEIGHT), interpolation=cv2.INTER_LINEAR)


@functools.partial(jax.jit, static_argnames=("config", "camera"))
def traced_photographs(scene, cam, key, sky, config: PathTraceConfig, camera: PhotographConfig):
    """The path-traced radiance of one scene, as traced and denoised, each upsampled to the probe's size and
    developed by the same camera."""
    key_trace, key_camera = jax.random.split(key)
    radiance = path_trace(scene, cam, key_trace, config, sky)
    denoised = denoise(radiance, guide_buffers(scene, cam))
    return tuple(
        photograph(key_camera, jax.image.resize(image, (PROBE_HEIGHT, PROBE_WIDTH, 3), "linear"), camera)
        for image in (radiance, denoised)
    )


develop = jax.jit(photograph, static_argnames="config")


def write_png(path: Path, rgb: np.ndarray) -> None:
    """An RGB image in [0, 1] or uint8 as an 8-bit PNG."""
    if rgb.dtype != np.uint8:
        rgb = np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"could not write {path}")


def render(args) -> None:
    height, width = (int(x) for x in args.size.split("x"))
    config = synth_config(height, width)
    trace_config = PathTraceConfig(
        samples_per_pixel=args.spp, bounces=args.bounces, pixels_per_chunk=2048, emissive_boxes_light=False
    )
    camera = PhotographConfig()
    cam = ncjax.NonCentralPanorama(width, height, rc=0.0)
    traced = 0
    for index, scene, rendering, _ in rendered_samples(args.n, SEED, config, batch_size=8):
        world = "atlanta" if bool(scene.room.is_atlanta) else "manhattan"
        name = f"{index:03d}_{sample_name(world, index, 0.0)}.png"
        paths = {folder: args.out / folder / name for folder in SETS}
        key = jax.random.fold_in(jax.random.key(args.seed), index)
        if not paths["raycast"].exists():
            write_png(paths["raycast"], upsampled(rendering_rgb8(rendering)))
        if not paths["raycast_camera"].exists():
            linear = (upsampled(rendering_rgb8(rendering)) / 255.0) ** 2.2
            write_png(paths["raycast_camera"], np.asarray(develop(key, jnp.asarray(linear, jnp.float32), camera)))
        if paths["pathtrace_denoised"].exists() or traced >= args.count:
            continue
        start = time.perf_counter()
        sky = jnp.asarray(environment(index, args.window_brightness, args.sun_clip))
        images = traced_photographs(jax.tree.map(jnp.asarray, scene), cam, key, sky, trace_config, camera)
        for folder, image in zip(("pathtrace", "pathtrace_denoised"), images, strict=True):
            write_png(paths[folder], np.asarray(image))
        traced += 1
        print(
            f"{name}: path-traced {width}x{height} at {args.spp} spp in {time.perf_counter() - start:.1f} s", flush=True
        )
    done = {folder: len(list((args.out / folder).glob("*.png"))) for folder in SETS}
    print("written: " + ", ".join(f"{folder} {count}/{args.n}" for folder, count in done.items()))
    if done["pathtrace_denoised"] == args.n:
        sets = " ".join(f'"{folder}={args.out}/{folder}/*.png"' for folder in SETS)
        print(
            "probe: uv run --with scikit-learn --with scipy python ../shared/tools/realism_probe/probe.py "
            f"--real ../shared/data/real-dev {sets}"
        )


def contact_sheet(out: Path, rows: int) -> Path:
    """``rows`` rooms at half size: the ray caster's image, the path-traced photograph and the denoised one."""
    names = sorted(p.name for p in (out / "pathtrace_denoised").glob("*.png"))[:rows]
    if not names:
        raise FileNotFoundError(f"no path-traced images in {out / 'pathtrace_denoised'}")
    tiles = []
    for name in names:
        views = [cv2.imread(str(out / folder / name)) for folder in ("raycast", "pathtrace", "pathtrace_denoised")]
        tiles.append(np.concatenate([cv2.resize(p, (PROBE_WIDTH // 2, PROBE_HEIGHT // 2)) for p in views], 1))
    path = out / "contact_sheet.png"
    cv2.imwrite(str(path), np.concatenate(tiles, 0))
    return path


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=26, help="rooms (real-dev has 26 panoramas)")
    parser.add_argument("--count", type=int, default=26, help="at most this many path traces in this call")
    parser.add_argument("--size", default="256x512", help="HxW the rooms are rendered at (then upsampled)")
    parser.add_argument("--spp", type=int, default=16, help="path-traced samples per pixel")
    parser.add_argument("--bounces", type=int, default=4, help="path-traced reflections per path")
    parser.add_argument("--window-brightness", type=float, default=2.0, help="median radiance through windows")
    parser.add_argument("--sun-clip", type=float, default=4.0, help="windows' radiance clipped at this times it")
    parser.add_argument("--seed", type=int, default=1, help="seed of the path tracer's and the camera's keys")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--sheet", action="store_true", help="only write the contact sheet (6 rooms)")
    args = parser.parse_args()
    if args.sheet:
        print(f"wrote {contact_sheet(args.out, 6)}")
        return
    enable_compilation_cache()
    render(args)


if __name__ == "__main__":
    main()
