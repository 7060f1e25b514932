"""Contact sheet of synthetic panoramas with their exact labels drawn over them.

Eight random realistic rooms (Manhattan and Atlanta; ``SceneConfig(decor=True)``:
open doors, decals, ceiling lights and panels, sunlight) rendered by ``ncjax``'s
JAX ray caster (3x3 supersampling, shadows), each with its ceiling-wall (red) and
floor-wall (blue) boundaries and its layout corners (yellow; occlusion corners
magenta) from ``ncjax.synth.room_labels``, i.e. the labels a network is trained on.

    uv run python experiments/contact_sheet.py [--out docs/contact_sheet.png] [--seed 3]
"""

import argparse
import os

import cv2
import jax
import numpy as np

import ncjax


def draw_labels(image: np.ndarray, labels, cam: ncjax.NonCentralPanorama) -> np.ndarray:
    """Boundaries and corners over an RGB uint8 image (returns a BGR copy for OpenCV)."""
    canvas = np.ascontiguousarray(image[..., ::-1])
    height, width = canvas.shape[:2]
    columns = np.arange(width) + 0.5
    for rows, colour in ((labels.ceiling_v, (40, 40, 230)), (labels.floor_v, (230, 120, 30))):
        points = np.stack([columns, np.asarray(rows) + 0.5], -1)
        # Split the polyline where it jumps (occlusions) so no false segments are drawn.
        breaks = np.nonzero(np.abs(np.diff(points[:, 1])) > 0.05 * height)[0] + 1
        for piece in np.split(points, breaks):
            cv2.polylines(canvas, [np.round(piece * 4).astype(np.int32)], False, colour, 1, cv2.LINE_AA, shift=2)
    for ceiling, floor, valid, occlusion in zip(
        np.asarray(labels.ceiling_corners),
        np.asarray(labels.floor_corners),
        np.asarray(labels.corner_mask),
        np.asarray(labels.corner_is_occlusion),
        strict=False,
    ):
        if not valid:
            continue
        colour = (200, 0, 200) if occlusion else (0, 220, 255)
        (u_top, u_bottom), (v_top, v_bottom) = ncjax.geometry.project(cam, np.stack([ceiling, floor]))
        top = (int(round(float(u_top) + 0.5)), int(round(float(v_top) + 0.5)))
        bottom = (int(round(float(u_bottom) + 0.5)), int(round(float(v_bottom) + 0.5)))
        cv2.line(canvas, top, bottom, colour, 1)
        for point in (top, bottom):
            cv2.circle(canvas, point, 3, colour, -1, cv2.LINE_AA)
    return canvas


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="docs/contact_sheet.png")
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--size", default="256x512", help="HxW of each panorama")
    args = parser.parse_args()
    height, width = (int(x) for x in args.size.split("x"))
    config = ncjax.SynthConfig(
        room=ncjax.RoomConfig(world="mix"),
        scene=ncjax.synth.SceneConfig(decor=True),
        render=ncjax.synth.RenderConfig(supersampling=3, shadows=True),
        width=width,
        height=height,
    )
    keys = jax.random.split(jax.random.key(args.seed), 8)
    scenes, renderings, labels = ncjax.synthesize_batch(keys, config)
    tiles = []
    for i in range(8):
        image = np.round(np.asarray(renderings.rgb[i]) * 255).astype(np.uint8)
        cam = ncjax.NonCentralPanorama(width, height, rc=scenes.room.rc[i])
        tile = draw_labels(image, jax.tree.map(lambda x: x[i], labels), cam)
        world = "Atlanta" if bool(scenes.room.is_atlanta[i]) else "Manhattan"
        text = f"{world}, {int(scenes.room.num_walls[i])} walls, rc = {float(scenes.room.rc[i]):.2f} m"
        cv2.putText(tile, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(tile, text, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    gap = np.full((4, width, 3), 255, np.uint8)
    column_a = np.concatenate(sum(([t, gap] for t in tiles[:4]), [])[:-1])
    column_b = np.concatenate(sum(([t, gap] for t in tiles[4:]), [])[:-1])
    sheet = np.concatenate([column_a, np.full((column_a.shape[0], 4, 3), 255, np.uint8), column_b], 1)
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    cv2.imwrite(args.out, sheet, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out}: {sheet.shape[1]}x{sheet.shape[0]}, {os.path.getsize(args.out) / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
