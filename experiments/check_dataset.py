"""Check a dataset folder written by ``ncjax synth`` with numpy only (no ncjax code).

For every sample: 3D_gt minus cam_pose, projected with the non-central model
(docs/design.md section 2: varphi = atan2(y, x), phi = atan2(z, sqrt(x^2 + y^2) - rc))
using the rc of the json and of the file name, must land on label_cor within
1 px; ceiling corners at the room height and floor corners at z = 0 (world);
the split must not share a layout. Prints the worst errors.

    uv run python experiments/check_dataset.py DIR
"""

import argparse
import json
import os
import re

import numpy as np


def project(points: np.ndarray, rc: float, width: int, height: int) -> np.ndarray:
    x, y, z = points.T
    azimuth = np.arctan2(y, x)
    elevation = np.arctan2(z, np.hypot(x, y) - rc)
    u = (np.pi - azimuth) / (2 * np.pi) * width - 0.5
    v = (np.pi / 2 - elevation) / np.pi * height - 0.5
    return np.stack([u, v], -1)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("directory")
    args = parser.parse_args()
    folder = args.directory
    names = sorted(os.path.splitext(f)[0] for f in os.listdir(os.path.join(folder, "json")))
    worst_u = worst_v = worst_rc = worst_z = 0.0
    for name in names:
        with open(os.path.join(folder, "json", f"{name}.json")) as file:
            meta = json.load(file)
        rc_name = int(re.search(r"_R(\d{5})", name).group(1)) / 1e4
        worst_rc = max(worst_rc, abs(rc_name - meta["rc"]))
        points = np.load(os.path.join(folder, "3D_gt", f"{name}.npy"))
        pose = np.load(os.path.join(folder, "cam_pose", f"{name}.npy")).reshape(3)
        label = np.loadtxt(os.path.join(folder, "label_cor", f"{name}.txt"), dtype=int, ndmin=2)
        n = len(points) // 2
        ordered = np.stack([points[:n], points[n:]], 1).reshape(-1, 3)
        uv = project(ordered - pose, meta["rc"], meta["width"], meta["height"])
        du = np.abs(uv[:, 0] - label[:, 0])
        worst_u = max(worst_u, np.max(np.minimum(du, meta["width"] - du)))
        worst_v = max(worst_v, np.max(np.abs(uv[:, 1] - label[:, 1])))
        worst_z = max(worst_z, np.max(np.abs(points[:n, 2] - meta["room_height"])), np.max(np.abs(points[n:, 2])))
    with open(os.path.join(folder, "split.json")) as file:
        split = json.load(file)
    seen = {}
    for part, members in split.items():
        for name in members:
            layout = tuple(np.round(np.load(os.path.join(folder, "3D_gt", f"{name}.npy")), 3).ravel())
            assert seen.setdefault(layout, part) == part, f"layout of {name} in two splits"
    ok = worst_u <= 1 and worst_v <= 1 and worst_rc <= 1e-6 and worst_z <= 1e-5
    print(
        f"{len(names)} samples, splits {', '.join(f'{k} {len(v)}' for k, v in split.items())}: max |u - label| "
        f"{worst_u:.3f} px, max |v - label| {worst_v:.3f} px, max |rc(name) - rc(json)| {worst_rc:.1e} m, "
        f"max corner height error {worst_z:.1e} m -> {'OK' if ok else 'FAILED'}"
    )


if __name__ == "__main__":
    main()
