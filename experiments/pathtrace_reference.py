"""The path tracer (``ncjax.synth.pathtrace``) against Mitsuba 3 at full size: a closed room with two boxes and two
ceiling lights of different colours, flat Lambertian materials, both renderers given the same pixel-centre rays of
the rig (central or not), the same path lengths, several independent images each.

Prints, over the pixels whose ray does not meet the scene near a light (only Mitsuba's geometry holds the lights'
discs, which are seen there or shade the ceiling around them): the share of pixel channels within 3 combined
standard errors, the root mean square and mean of the normalised differences (about 1 and 0 for two unbiased
images), the mean relative difference against what the noise alone explains, the ratio of the image means with its
standard error, and both renderers' times. Writes ``out/pathtrace_reference_rc{rc}.png``: ncjax's image,
Mitsuba's, and the normalised difference of their luminances (blue: ncjax darker, red: brighter, saturated at 4
standard errors), side by side.

    uv run python experiments/pathtrace_reference.py                     # 256 x 512, rc = 0.3
    uv run python experiments/pathtrace_reference.py --rc 0 --size 128x256
"""

import argparse
import time
from pathlib import Path

import jax
import numpy as np
from PIL import Image

import ncjax
from ncjax.synth.pathtrace import PathTraceConfig, path_trace
from ncjax.synth.pathtrace_reference import agreement, comparison_scene, mean_and_error, render_reference

OUT = Path(__file__).parent / "out"


def scene():
    """The room: 5 x 3.6 m, 2.7 m high, a cabinet and a table, a warm and a cool light under the ceiling."""
    return comparison_scene(
        half=(2.5, 1.8),
        floor_height=-1.5,
        ceiling_height=1.2,
        boxes=[((1.6, 1.2, -1.0), (0.5, 0.3, 0.5), 0.0), ((-0.9, -0.7, -1.1), (0.6, 0.4, 0.4), 0.6)],
        lights=[((-1.0, 0.5, 1.15), (3.0, 2.4, 1.6)), ((1.2, -0.6, 1.15), (1.4, 1.8, 2.6))],
    )


def tone_map(radiance: np.ndarray, exposure: float) -> np.ndarray:
    """8-bit sRGB-like image of linear radiance: Reinhard's curve after ``exposure``, then gamma 2.2."""
    scaled = exposure * np.nan_to_num(radiance)
    return np.uint8(255 * (scaled / (1 + scaled)) ** (1 / 2.2) + 0.5)


def difference_panel(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """8-bit colours of normalised differences: white at 0, red towards +4, blue towards -4; grey where invalid."""
    t = np.clip(np.nan_to_num(z) / 4, -1, 1)[..., None]
    white = np.ones(3)
    colour = np.where(
        t > 0, white + t * (np.array([0.85, 0.1, 0.1]) - white), white - t * (np.array([0.1, 0.2, 0.85]) - white)
    )
    colour[~valid] = 0.5
    return np.uint8(255 * colour + 0.5)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", default="256x512", help="H x W of the panorama")
    parser.add_argument("--rc", type=float, default=0.3, help="radius of the circle of optical centres, metres")
    parser.add_argument("--bounces", type=int, default=4)
    parser.add_argument("--batches", type=int, default=16, help="independent images per renderer")
    parser.add_argument("--spp", type=int, default=32, help="paths per pixel in each image")
    parser.add_argument("--light-radius", type=float, default=PathTraceConfig.light_radius, help="metres")
    args = parser.parse_args()
    height, width = (int(n) for n in args.size.split("x"))
    cam = ncjax.NonCentralPanorama(width, height, rc=args.rc)
    config = PathTraceConfig(
        samples_per_pixel=args.spp,
        bounces=args.bounces,
        light_radius=args.light_radius,
        floor_specular=0.0,
        jitter=False,
    )
    room = scene()

    trace = jax.jit(path_trace, static_argnames="config")
    start = time.perf_counter()
    trace(room, cam, jax.random.key(-1), config).block_until_ready()
    compiled = time.perf_counter()
    ours = np.stack([np.asarray(trace(room, cam, jax.random.key(k), config)) for k in range(args.batches)])
    traced = time.perf_counter()
    references = [render_reference(room, cam, config, args.spp, seed) for seed in range(args.batches)]
    referenced = time.perf_counter()
    paths = args.batches * args.spp * height * width
    print(f"{height} x {width}, rc {args.rc}, {args.bounces} bounces, {args.batches} x {args.spp} spp")
    print(
        f"ncjax:   {traced - compiled:.1f} s ({1e6 * (traced - compiled) / paths:.2f} us a path), "
        f"compile and first image {compiled - start:.1f} s"
    )
    print(f"mitsuba: {referenced - traced:.1f} s ({1e6 * (referenced - traced) / paths:.2f} us a path, scalar_rgb)")

    mean, error = mean_and_error(ours)
    references_stack = np.stack([image for image, _ in references])
    reference, reference_error = mean_and_error(references_stack)
    valid = ~references[0][1]
    figures = agreement(mean, error, reference, reference_error, valid)
    z = (mean - reference) / np.sqrt(error**2 + reference_error**2)
    print(f"pixels left out (their ray meets the scene near a light): {np.sum(~valid)} of {valid.size}")
    print(f"within 3 combined standard errors: {figures['within_3_sigma']:.4f} of the pixel channels")
    print(f"normalised differences: rms {figures['z_rms']:.3f}, mean {z[valid].mean():+.4f}")
    print(
        f"mean relative difference {figures['mean_relative_difference']:.4f} "
        f"(the noise alone: about {figures['relative_noise']:.4f})"
    )
    # The spread of the batches' image means gives the ratio's standard error.
    means = [images[:, valid].mean((1, 2)) for images in (ours, references_stack)]
    relative_errors = [m.std(ddof=1) / (np.sqrt(len(m)) * m.mean()) for m in means]
    ratio_error = figures["mean_ratio"] * np.hypot(*relative_errors)
    print(f"image mean ratio ncjax / mitsuba: {figures['mean_ratio']:.5f} +- {ratio_error:.5f}")

    exposure = 1 / np.percentile(reference[valid].mean(-1), 90)
    # The luminances' own standard errors, from the same batches (a pixel's channels are far from independent).
    luminance, luminance_error = mean_and_error(ours.mean(-1))
    reference_luminance, reference_luminance_error = mean_and_error(references_stack.mean(-1))
    luminance_z = (luminance - reference_luminance) / np.sqrt(luminance_error**2 + reference_luminance_error**2)
    panels = [tone_map(mean, exposure), tone_map(reference, exposure), difference_panel(luminance_z, valid)]
    gap = np.full((height, 4, 3), 255, np.uint8)
    OUT.mkdir(exist_ok=True)
    radius = "" if args.light_radius == PathTraceConfig.light_radius else f"_light{args.light_radius:g}"
    path = OUT / f"pathtrace_reference_rc{args.rc:g}{radius}.png"
    Image.fromarray(np.concatenate([panels[0], gap, panels[1], gap, panels[2]], 1)).save(path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
