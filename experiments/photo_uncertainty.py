"""How far to trust the corners' uncertainty ellipses on real photographs: their coverage against the labels.

``Layout.corner_covariance`` is the first-order covariance of the final adjustment under the rows' noise plus a
per-wall offset, calibrated on renders (``experiments/calibrate_uncertainty.py``: 95% ellipses holding 90-97% of the
true corners there). A central panorama's covariance is conditional on its camera height (the prior's, 1.6 m: its
``floor_height_sigma`` is 0), so each label is back-projected at that same height: what is left between a corner and
its label is what the ellipse describes, the rows' error. Per labelled panorama of ``--data`` (unlevelled, the
shipped model's rows, 4 views, ``world="auto"``, ``NETWORK_PIPELINE_CONFIG``, as ``experiments/common.py``'s central
experiments run them), for the layouts with a covariance (the plan fallback has none): each layout corner is paired
with a distinct label corner whose column lies within ``--tolerance`` of the width of its own, the nearest pairs
first (the corner benchmark's matching; a corner without a label corner near is a wrong structure, not noise). The
table gives, over the paired corners and per status, the share inside their 95% ellipse, the median corner sigma (the
RMS radius, ``sqrt trace``) and plan error, and the factor the ellipses would need for 95%: the 95th percentile of
``sqrt(mahalanobis^2 / chi2_95)`` (a description, not a calibration: the photographs choose nothing).

    uv run python experiments/photo_uncertainty.py --data ../shared/data/real-dev [--tolerance 0.025]
"""

from __future__ import annotations

import argparse
import pathlib

import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.evaluation.panorama_scores import one_to_one_pairs
from ncjax.geometry.camera import pixel_to_angles, project
from ncjax.network.predict import default_model
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT
from ncjax.viz.plan import CHI2_2D_95

from common import central_layout, labelled_rows


def label_floor_plan(label, cam: ncjax.NonCentralPanorama, camera_height: float) -> np.ndarray:
    """The label's floor corners (n, 2) in the camera's plan, back-projected onto a floor ``camera_height`` below."""
    azimuth, elevation = (
        np.asarray(a) for a in pixel_to_angles(cam, jnp.asarray(label.floor[:, 0]), label.floor[:, 1])
    )
    distance = camera_height / np.tan(-elevation)
    return np.stack([distance * np.cos(azimuth), distance * np.sin(azimuth)], axis=-1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=pathlib.Path, required=True, help="folder of panoramas with label_cor .txt")
    parser.add_argument("--tolerance", type=float, default=0.025, help="pairing distance, a fraction of the width")
    args = parser.parse_args(argv)
    model = default_model()
    corners = {"inside": [], "sigma": [], "error": [], "ratio": [], "status": []}
    counted = {"panoramas": 0, "no covariance": 0, "label corners": 0, "paired": 0}
    for path, cam, label, rows in labelled_rows(args.data, model):
        counted["panoramas"] += 1
        counted["label corners"] += len(label.floor)
        layout = central_layout(*rows, cam)
        mask = np.asarray(layout.mask, bool)
        covariance = np.asarray(layout.corner_covariance, np.float64)[mask]
        if not mask.any() or not np.all(np.isfinite(covariance)):
            counted["no covariance"] += 1
            continue
        floor_corners = np.asarray(layout.floor_corners, np.float64)[mask]
        columns = np.asarray(project(cam, jnp.asarray(floor_corners))[0], np.float64)
        pairs = np.array(one_to_one_pairs(columns, label.floor[:, 0], args.tolerance * cam.width, cam.width))
        if len(pairs) == 0:
            continue
        error = floor_corners[pairs[:, 0], :2] - label_floor_plan(label, cam, DEFAULT_CAMERA_HEIGHT)[pairs[:, 1]]
        covariance = covariance[pairs[:, 0]]
        mahalanobis = np.einsum("ki,kij,kj->k", error, np.linalg.inv(covariance), error)
        status = ncjax.LayoutStatus(int(layout.status)).name
        counted["paired"] += len(pairs)
        corners["inside"] += list(mahalanobis <= CHI2_2D_95)
        corners["sigma"] += list(np.sqrt(np.trace(covariance, axis1=1, axis2=2)))
        corners["error"] += list(np.linalg.norm(error, axis=1))
        corners["ratio"] += list(np.sqrt(mahalanobis / CHI2_2D_95))
        corners["status"] += [status] * len(pairs)
        inside, errors = np.mean(mahalanobis <= CHI2_2D_95), np.linalg.norm(error, axis=1)
        print(
            f"{path.stem}: {status}, {len(pairs)} of {len(label.floor)} label corners paired, {inside:.0%} inside, "
            f"median error {np.median(errors):.3f} m",
            flush=True,
        )
    print()
    print(", ".join(f"{name}: {count}" for name, count in counted.items()))
    inside, status = np.asarray(corners["inside"]), np.asarray(corners["status"])
    print("| layouts | corners | inside their 95% ellipse | median sigma (m) | median error (m) | factor for 95% |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, chosen in [("all", np.ones(len(inside), bool))] + [(s, status == s) for s in sorted(set(status))]:
        if not chosen.any():
            continue
        sigma, error, ratio = (np.asarray(corners[key])[chosen] for key in ("sigma", "error", "ratio"))
        print(
            f"| {name} | {chosen.sum()} | {inside[chosen].mean():.0%} | {np.median(sigma):.3f} | "
            f"{np.median(error):.3f} | {np.quantile(ratio, 0.95):.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
