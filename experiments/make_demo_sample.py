"""Render the sample that ``ncjax demo`` ships (ncjax/data/demo), reproducibly.

The sample is the first room of seed 2026 (never used for training: the
shipped models were trained on seeds 11-14, 21-22 and 31-33) that is Manhattan with at least 6 walls,
rendered at 512 x 1024 with 3 x 3 supersampling. Its ground truth is the exact
visible layout (camera frame, image order), stored with the image name, whose
``_R<rc>`` suffix carries the radius as in the authors' real captures.

    uv run python experiments/make_demo_sample.py
"""

import json
import pathlib

import cv2
import jax
import numpy as np

import ncjax

OUT = pathlib.Path(__file__).parents[1] / "ncjax" / "data" / "demo"
SEED = 2026


def main():
    config = ncjax.SynthConfig(
        room=ncjax.RoomConfig(world="mix", rc_range=(0.3, 1.0)), render=ncjax.synth.RenderConfig(supersampling=3)
    )
    keys = jax.random.split(jax.random.key(SEED), 16)
    scenes, renderings, labels = jax.device_get(ncjax.synthesize_batch(keys, config))
    for index in range(len(keys)):
        room = jax.tree.map(lambda x: x[index], scenes.room)
        walls = int(np.sum(room.mask))
        if bool(room.is_atlanta) or walls < 6 or not bool(labels.ok[index]):
            continue
        rc = float(room.rc)
        name = f"demo_manhattan_R{int(round(rc * 1e4)):05d}.png"
        image = np.round(np.clip(renderings.rgb[index], 0, 1) * 255).astype(np.uint8)
        OUT.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(OUT / name), image[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
        mask = labels.corner_mask[index]
        truth = {
            "image": name,
            "world": "manhattan",
            "rc": round(float(np.float32(int(round(rc * 1e4)) / 1e4)), 4),
            "seed": SEED,
            "index": index,
            "walls": walls,
            "ceiling_corners": np.round(labels.ceiling_corners[index][mask], 6).tolist(),
            "floor_corners": np.round(labels.floor_corners[index][mask], 6).tolist(),
        }
        (OUT / "ground_truth.json").write_text(json.dumps(truth, indent=1) + "\n")
        print(f"wrote {OUT / name} (sample {index}, {walls} walls, rc {rc:.4f} m)")
        return
    raise SystemExit("no Manhattan room with >= 6 walls among the 16 samples; change SEED")


if __name__ == "__main__":
    main()
