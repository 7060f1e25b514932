"""How bright the rooms seen through open doors are against the room's own walls, photoreal and ray-cast.

In a photograph the room behind an open door is lit about as the room is: a little brighter where its window
faces the door, darker where it has none. A render whose rooms behind glow, or lie dark, teaches the network a
shortcut (the room behind is what is brighter) that photographs do not follow. Per room of ``--kind`` (seed
``--seed``, central camera), this prints the median luminance of the pixels whose centre ray meets a room behind an
open door (:attr:`~ncjax.synth.pathtrace_scene.SurfaceKind.NEXT_ROOM`, the doors' linings too) over the median
luminance of those meeting the room's walls: in the path tracer's radiance (``PhotorealConfig``'s paths and bounces,
its window views and sun, ``--next-room-light`` times the window view's irradiance lighting the rooms behind) and in
the ray caster's image (its tone curve undone), both at 128 x 256; then the median over the rooms. Rooms with fewer
than 20 such pixels are left out. About 10 s a room on 2 CPU cores.

    uv run python experiments/next_room_light.py [--next-room-light 0.015] [--rooms 16]
"""

from __future__ import annotations

import argparse
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ncjax.geometry.camera import NonCentralPanorama
from ncjax.io.tone_mapping import luminance
from ncjax.synth.dataset import rendered_samples
from ncjax.synth.pathtrace import path_trace
from ncjax.synth.pathtrace_denoise import guide_buffers
from ncjax.synth.pathtrace_scene import SurfaceKind
from ncjax.synth.photoreal import PhotorealConfig, next_room_irradiance, window_light, window_views
from ncjax.synth.render import radiance_from_colours
from ncjax.training.data import SYNTH_SOURCES

HEIGHT, WIDTH = 128, 256
MIN_PIXELS = 20


def at_traced_pixels(image: np.ndarray) -> np.ndarray:
    """``image`` sampled at the centres of the traced image's pixels (a whole multiple of its size)."""
    rows, columns = image.shape[0] // HEIGHT, image.shape[1] // WIDTH
    return image[rows // 2 :: rows, columns // 2 :: columns]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", default="synth-decor-open", choices=sorted(SYNTH_SOURCES))
    parser.add_argument("--seed", type=int, default=701)
    parser.add_argument("--rooms", type=int, default=16)
    parser.add_argument("--next-room-light", type=float, default=PhotorealConfig().next_room_light)
    args = parser.parse_args(argv)
    config = dataclasses.replace(PhotorealConfig(), next_room_light=args.next_room_light)
    ray_cast = dataclasses.replace(SYNTH_SOURCES[args.kind], photoreal=None)
    views = jnp.asarray(window_views())
    cam = NonCentralPanorama(WIDTH, HEIGHT, 0.0)

    @jax.jit
    def traced(key, scene):
        view, sun = window_light(key, views, config)
        radiance = path_trace(
            scene, cam, key, config.trace, view, sun if config.sun else None, next_room_irradiance(view, config)
        )
        return radiance, guide_buffers(scene, cam).surface % len(SurfaceKind)

    ratios = []
    for index, scene, rendering, _ in rendered_samples(args.rooms, args.seed, ray_cast, batch_size=8):
        radiance, kind = (np.asarray(a) for a in traced(jax.random.key(index), jax.tree.map(jnp.asarray, scene)))
        behind, walls = kind == SurfaceKind.NEXT_ROOM, kind == SurfaceKind.WALL
        if behind.sum() < MIN_PIXELS:
            continue
        cast = np.asarray(radiance_from_colours(at_traced_pixels(np.asarray(rendering.rgb))))
        photoreal, cast = np.asarray(luminance(radiance)), np.asarray(luminance(cast))
        ratios.append([np.median(image[behind]) / np.median(image[walls]) for image in (photoreal, cast)])
        print(
            f"room {index}: {behind.mean():.1%} of the pixels behind doors; behind / walls: photoreal "
            f"{ratios[-1][0]:.2f}, ray caster {ratios[-1][1]:.2f}",
            flush=True,
        )
    photoreal, cast = np.median(ratios, axis=0)
    print(
        f"median over {len(ratios)} rooms (next_room_light {args.next_room_light}): photoreal {photoreal:.2f}, "
        f"ray caster {cast:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
