"""One synthetic panorama through each camera effect of the training augmentation (``ncjax.synth.augment``).

Tiles, top to bottom and left to right: the render; vignetting of a 3-lens camera;
JPEG at quality 10 and a 4x enlarged crop of it (the 8 x 8 blocks); black bands at the
poles; stitching seams (exaggerated: 20% exposure steps and 2 px shifts); then
``random_augment`` with the training defaults for three keys. A check by eye that the
effects look like real camera output at the training resolution.

    uv run python experiments/camera_effects.py [--out experiments/out/camera_effects.png] [--seed 3]
"""

import argparse
import os

import cv2
import jax
import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.synth import augment


def effect_tiles(image: jax.Array, seed: int) -> list[tuple[str, jax.Array]]:
    """``(caption, image)`` per effect, for one RGB image in [0, 1]."""
    height, width = image.shape[:2]
    jpeg = augment.jpeg_compress(image, 10)
    crop = jpeg[3 * height // 8 : 5 * height // 8, 3 * width // 8 : 5 * width // 8]
    seams = augment.stitching_seams(
        image,
        jnp.array([0.2, 0.55, 0.8]) * width,
        jnp.array([[1.2, 1.15, 1.1], [0.8, 0.82, 0.85], [1.15, 1.2, 1.2]]),
        jnp.array([2.0, -2.0, 1.0]),
        0.01 * width,
        0.2 * width,
    )
    tiles = [
        ("render", image),
        ("vignetting, 3 lenses", augment.vignette(image, 0.5, 3, 0.0, 0.3)),
        ("JPEG quality 10", jpeg),
        ("JPEG quality 10, 4x crop", jnp.repeat(jnp.repeat(crop, 4, axis=0), 4, axis=1)),
        ("black bands 8% / 12%", augment.black_bands(image, 0.08 * height, 0.12 * height)),
        ("stitching seams (exaggerated)", seams),
    ]
    keys = jax.random.split(jax.random.key(seed), 3)
    for i, key in enumerate(keys):
        tiles.append((f"random_augment, key {i}", jax.jit(augment.random_augment)(key, image)))
    return tiles


def caption(tile: np.ndarray, text: str) -> np.ndarray:
    """An RGB uint8 tile as BGR with ``text`` written on it."""
    canvas = np.ascontiguousarray(tile[..., ::-1])
    cv2.putText(canvas, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(canvas, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="experiments/out/camera_effects.png")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--size", default="256x512", help="HxW of the panorama")
    args = parser.parse_args()
    height, width = (int(x) for x in args.size.split("x"))
    config = ncjax.SynthConfig(room=ncjax.RoomConfig(world="mix"), width=width, height=height)
    _, renderings, _ = ncjax.synthesize_batch(jax.random.split(jax.random.key(args.seed), 1), config)
    tiles = [
        caption(np.round(np.asarray(tile) * 255).astype(np.uint8), text)
        for text, tile in effect_tiles(renderings.rgb[0], args.seed)
    ]
    rows = [np.concatenate([tiles[i], np.full((height, 4, 3), 255, np.uint8), tiles[i + 1]], 1) for i in (0, 2, 4, 6)]
    rows.append(np.concatenate([tiles[8], np.full((height, width + 4, 3), 255, np.uint8)], 1))
    gap = np.full((4, rows[0].shape[1], 3), 255, np.uint8)
    sheet = np.concatenate(sum(([row, gap] for row in rows), [])[:-1])
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    cv2.imwrite(args.out, sheet, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out}: {sheet.shape[1]}x{sheet.shape[0]}")


if __name__ == "__main__":
    main()
