"""How much a layout depends on its RANSAC key: each input laid out with many keys.

The network's rows of each input are computed once; the geometry then runs once per key, as
``ncjax reconstruct`` runs it (``NETWORK_PIPELINE_CONFIG``, world auto, a camera height of 1.6 m
where the non-central geometry cannot fix the scale, or for the central real panoramas). Per set:

- the share of inputs whose status changes with the key;
- over the inputs with a layout for at least two keys, the ratio of the key-induced standard deviation
  to the reported sigma (the median of the keys'), for the room height and for each corner's plan
  position (the corners of the keys that found the most common corner count and columns): median,
  worst, and the share of inputs whose room height ratio is at most 0.25;
- on the renders, the coverage over keys and renders of the true corners by their 95% ellipses and of
  the true room heights by 1.96 sigma (ok layouts with the true corner count, as
  ``calibrate_uncertainty.py`` scores them), with its 95% interval when the renders are drawn again
  (bootstrap over renders), per world and for both worlds' renders together.

Sets: the rig's real capture L101 (``../shared/data/noncentral-real``), 64 Manhattan and 64 Atlanta test
renders (non-central, the shipped model's rows) and the 26 labelled real panoramas of
``../shared/data/real-dev`` (central: rc = 0, the camera height's scale); a set whose data is missing is
left out with a line saying so.

    uv run python experiments/key_stability.py                    # 32 keys, 64 renders per world
    uv run python experiments/key_stability.py --keys 8 --renders 8
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.io.export import status_has_geometry
from ncjax.network.predict import DEFAULT_VIEWS, default_model
from ncjax.pipeline.prior import DEFAULT_CAMERA_HEIGHT, HeightPrior, flag_scale_conflicts
from ncjax.pipeline.uncertainty import room_height_sigma
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG, SCALE_FAILURES

from common import OUT, corner_calibration, labelled_rows, model_suffix, rendered_boundaries, test_renders

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
RIG_CAPTURE = SHARED / "noncentral-real" / "L101_R06101.png"
REAL_DEV = SHARED / "real-dev"
HEIGHT_RATIO_GOAL = 0.25  # key-induced standard deviation of the room height, in reported sigmas
BOOTSTRAP_DRAWS = 2000


@dataclasses.dataclass
class InputSet:
    """The rows of a set of inputs (N leading), their radii and, for renders, the truths."""

    name: str
    ceiling_v: np.ndarray
    floor_v: np.ndarray
    corner_prob: np.ndarray
    rc: np.ndarray
    truth: list | None = None


def layouts_over_keys(inputs: InputSet, keys: int, config: ncjax.PipelineConfig) -> ncjax.Layout:
    """The layouts of every input with each of ``keys`` keys (N, keys leading), as ``ncjax reconstruct`` gets them."""
    count, width = inputs.ceiling_v.shape
    tiled = [np.repeat(x[:, None], keys, 1) for x in (inputs.ceiling_v, inputs.floor_v, inputs.corner_prob)]
    rc = np.repeat(inputs.rc[:, None], keys, 1)
    cams = jax.vmap(jax.vmap(lambda r: ncjax.NonCentralPanorama(width, width // 2, rc=r)))(jnp.asarray(rc))
    # key k of every input is the same key: a key's effect is then not mixed with the input's
    key = jnp.broadcast_to(jax.random.split(jax.random.key(0), keys)[None], (count, keys))
    prior = HeightPrior("camera_height", DEFAULT_CAMERA_HEIGHT)
    if np.all(rc == 0):
        return jax.device_get(ncjax.layout_from_boundaries(*tiled, cams, "auto", config, key=key, prior=prior))
    geometry = ncjax.layout_from_boundaries(*tiled, cams, "auto", config, key=key)
    needs = np.isin(np.asarray(geometry.status), np.asarray(SCALE_FAILURES))
    if not needs.any():
        return jax.device_get(geometry)
    from_prior = ncjax.layout_from_boundaries(*tiled, cams, "auto", config, key=key, prior=prior)
    chosen = jax.tree.map(
        lambda a, b: jnp.where(jnp.reshape(needs, needs.shape + (1,) * (a.ndim - 2)), a, b), from_prior, geometry
    )
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), (chosen, geometry))
    flagged = flag_scale_conflicts(*flat, prior, config.prior.max_scale_conflict)
    return jax.device_get(jax.tree.map(lambda x: x.reshape((count, keys) + x.shape[1:]), flagged))


def has_geometry(layout: ncjax.Layout) -> np.ndarray:
    return np.vectorize(status_has_geometry)(np.asarray(layout.ok), np.asarray(layout.status))


def input_spread(layouts: ncjax.Layout) -> dict:
    """One input's layouts over keys (keys leading): status change, height and corner ratios."""
    status = np.asarray(layouts.status)
    result = {
        "status_changes": len(set(status.tolist())) > 1,
        "height_ratio": math.nan,
        "corner_ratios": [],
        "statuses": sorted({ncjax.LayoutStatus(int(s)).name for s in status}),
        "corner_counts": sorted(set(np.sum(np.asarray(layouts.mask), -1).tolist())),
    }
    written = has_geometry(layouts)
    if written.sum() < 2:
        return result
    height = np.asarray(layouts.ceiling_height - layouts.floor_height, np.float64)[written]
    sigma = np.asarray(room_height_sigma(np.asarray(layouts.height_covariance, np.float64)))[written]
    result["height_ratio"] = float(np.std(height) / np.median(sigma))
    result["height_spread"] = (float(np.median(height)), float(np.std(height)), float(np.median(sigma)))
    # corners: the keys whose corner columns are the most common ones, slot by slot
    columns = np.where(np.asarray(layouts.mask), np.round(np.asarray(layouts.corner_columns), 1), np.nan)[written]
    signatures = [tuple(np.nan_to_num(c, nan=-1.0)) for c in columns]
    common = max(set(signatures), key=signatures.count)
    same = np.array([s == common for s in signatures])
    if same.sum() >= 2:
        mask = np.asarray(layouts.mask)[written][same][0]
        corners = np.asarray(layouts.floor_corners, np.float64)[written][same][:, mask, :2]
        spread = np.sqrt(np.sum(np.var(corners, axis=0), axis=-1))
        covariance = np.asarray(layouts.corner_covariance, np.float64)[written][same][:, mask]
        reported = np.median(np.sqrt(np.trace(covariance, axis1=-2, axis2=-1)), axis=0)
        result["corner_ratios"] = list(spread / reported)
    return result


def render_coverage(layouts: ncjax.Layout, truths: list) -> list[dict]:
    """Per render: for each true corner of its ok layouts (over keys) with the true corner count, inside its 95%
    ellipse? its plan error (m); per such layout, the true room height within 1.96 sigma? its error (m)."""
    records = []
    for index, truth in enumerate(truths):
        record = {"inside": [], "heights": [], "corner_errors": [], "height_errors": []}
        for key in range(layouts.ok.shape[1]):
            layout = jax.tree.map(lambda x: np.asarray(x[index, key]), layouts)
            if not bool(layout.ok):
                continue
            _, shift = metrics.corner_error(layout, truth)
            if shift is None:
                continue
            within, _, errors = corner_calibration(layout, truth, shift)
            record["inside"].extend(within)
            record["corner_errors"].extend(errors)
            true_height = truth["ceiling_corners"][0][2] - truth["floor_corners"][0][2]
            height = float(layout.ceiling_height) - float(layout.floor_height)
            sigma = float(room_height_sigma(np.asarray(layout.height_covariance, np.float64)))
            record["heights"].append(abs(height - true_height) <= 1.96 * sigma)
            record["height_errors"].append(abs(height - true_height))
        records.append(record)
    return records


def coverage(records: list[dict], name: str, draws: int = BOOTSTRAP_DRAWS) -> tuple[float, float, float]:
    """The share (%) of ``name`` ("inside" or "heights") over ``records`` (:func:`render_coverage`), and its 95%
    interval when whole renders are drawn again (a room's corners err together: the corners are not independent
    samples, and a few dozen rooms leave the share uncertain by several points)."""
    hits = np.array([np.sum(r[name]) for r in records], float)
    counts = np.array([len(r[name]) for r in records], float)
    draw = np.random.default_rng(0).integers(0, len(records), (draws, len(records)))
    shares = 100 * hits[draw].sum(1) / np.maximum(counts[draw].sum(1), 1)
    low, high = np.percentile(shares, [2.5, 97.5])
    return 100 * hits.sum() / max(counts.sum(), 1), float(low), float(high)


def coverage_summary(records: list[dict]) -> dict:
    """:func:`coverage` of the corners and the heights, and the median errors (cm), of ``records``."""
    return {
        "corner_coverage": coverage(records, "inside"),
        "height_coverage": coverage(records, "heights"),
        "corner_error": 100 * float(np.median(np.concatenate([r["corner_errors"] for r in records]))),
        "height_error": 100 * float(np.median(np.concatenate([r["height_errors"] for r in records]))),
        "rooms": sum(bool(r["heights"]) for r in records),
    }


def set_summary(inputs: InputSet, layouts: ncjax.Layout) -> dict:
    spreads = [input_spread(jax.tree.map(lambda x: x[i], layouts)) for i in range(len(inputs.rc))]
    heights = np.array([s["height_ratio"] for s in spreads])
    corners = np.concatenate([s["corner_ratios"] for s in spreads] + [np.zeros(0)])
    measured = heights[np.isfinite(heights)]
    for index, spread in enumerate(spreads):
        if spread["status_changes"] or spread["height_ratio"] > HEIGHT_RATIO_GOAL:
            print(
                f"  {inputs.name}, input {index}: height ratio {spread['height_ratio']:.2f} "
                f"(median, key sd, sigma {np.round(spread.get('height_spread', ()), 3).tolist()} m), statuses "
                f"{spread['statuses']}, corner counts {spread['corner_counts']}"
            )
    summary = {
        "set": inputs.name,
        "inputs": len(spreads),
        "status_changes": float(np.mean([s["status_changes"] for s in spreads])),
        "with_layouts": int(measured.size),
        "height_median": float(np.median(measured)) if measured.size else math.nan,
        "height_worst": float(np.max(measured)) if measured.size else math.nan,
        "height_within_goal": float(np.mean(measured <= HEIGHT_RATIO_GOAL)) if measured.size else math.nan,
        "corner_median": float(np.median(corners)) if corners.size else math.nan,
        "corner_worst": float(np.max(corners)) if corners.size else math.nan,
        "ok": float(np.mean(np.asarray(layouts.ok))),
        "records": None,
    }
    if inputs.truth is not None:
        summary["records"] = render_coverage(layouts, inputs.truth)
        summary |= coverage_summary(summary["records"])
    return summary


def rig_capture() -> InputSet | None:
    if not RIG_CAPTURE.is_file():
        print(f"{RIG_CAPTURE} missing: L101 left out")
        return None
    image = ncjax.read_panorama(RIG_CAPTURE)
    rows = ncjax.predict_boundaries(image[None], default_model())
    return InputSet("L101 (rig, rc 0.61 m)", *(np.asarray(r) for r in rows), np.array([0.6101], np.float32))


def renders(world: str, count: int) -> InputSet:
    folder = test_renders(world, count, OUT)
    cache = OUT / f"test_{world}_{count}_views{DEFAULT_VIEWS}{model_suffix(None)}.npz"
    data = rendered_boundaries(folder, world, cache, DEFAULT_VIEWS)
    rows = (np.asarray(data[k]) for k in ("ceiling_v", "floor_v", "corner_prob"))
    return InputSet(f"{count} {world} test renders", *rows, data["rc"], data["truth"])


def real_dev() -> InputSet | None:
    if not REAL_DEV.is_dir():
        print(f"{REAL_DEV} missing: the real panoramas left out")
        return None
    cache = OUT / f"real_dev_rows{model_suffix(None)}.npz"
    if not cache.is_file():
        rows = [r for *_, r in labelled_rows(REAL_DEV, default_model())]
        widths = {r[0].shape[-1] for r in rows}
        if widths != {1024}:
            raise SystemExit(f"expected 1024-column rows of the real panoramas, got widths {widths}")
        np.savez(cache, **{k: np.stack([r[i] for r in rows]) for i, k in enumerate(("ceiling_v", "floor_v", "p"))})
    with np.load(cache) as stored:
        rows = stored["ceiling_v"], stored["floor_v"], stored["p"]
    return InputSet(f"{len(rows[0])} real panoramas (central)", *rows, np.zeros(len(rows[0]), np.float32))


def table(summaries: list[dict], keys: int) -> str:
    lines = [
        f"| set ({keys} keys) | status changes | ok | height: key sd / sigma, median / worst | "
        f"height ratio <= {HEIGHT_RATIO_GOAL} | corners: key sd / sigma, median / worst | "
        "coverage (%, 95% interval over renders): corners / heights | rooms scored | "
        "median error: corners / height (cm) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for s in summaries:
        lines.append(
            (
                f"| {s['set']} | {100 * s['status_changes']:.1f}% | {100 * s['ok']:.1f}% | "
                f"{s['height_median']:.3f} / {s['height_worst']:.3f} | "
                f"{100 * s['height_within_goal']:.1f}% of {s['with_layouts']} | "
                f"{s['corner_median']:.3f} / {s['corner_worst']:.3f} | "
                if "status_changes" in s
                else f"| {s['set']} | | | | | | "
            )
            + (
                "- | - | - |"
                if s["records"] is None
                else f"{interval(s['corner_coverage'])} / {interval(s['height_coverage'])} | {s['rooms']} | "
                f"{s['corner_error']:.1f} / {s['height_error']:.1f} |"
            )
        )
    return "\n".join(lines)


def interval(share: tuple[float, float, float]) -> str:
    return f"{share[0]:.1f} ({share[1]:.0f}-{share[2]:.0f})"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keys", type=int, default=32, help="RANSAC keys per input")
    parser.add_argument("--renders", type=int, default=64, help="test renders per world")
    parser.add_argument("--sets", default="rig,manhattan,atlanta,real", help="comma-separated sets to run")
    ransac = NETWORK_PIPELINE_CONFIG.ransac
    parser.add_argument(
        "--outlier-rate", type=float, default=ransac.outlier_rate, help="RANSAC's epsilon: sets the hypotheses"
    )
    parser.add_argument("--refits", type=int, default=ransac.refits, help="refits of RANSAC's chosen wall")
    parser.add_argument(
        "--strata", type=int, default=ransac.strata, help="RANSAC's fixed stratified samples (0: random ones)"
    )
    args = parser.parse_args(argv)
    changes = {"outlier_rate": args.outlier_rate, "refits": args.refits, "strata": args.strata}
    config = NETWORK_PIPELINE_CONFIG.replace(ransac=changes)
    sampling = f"the fixed samples of {args.strata} strata" if args.strata else "random"
    print(f"{config.ransac.hypotheses} {sampling} hypotheses per wall and 16 windows, {config.ransac.refits} refits")
    OUT.mkdir(parents=True, exist_ok=True)
    wanted = args.sets.split(",")
    loaders = {
        "rig": rig_capture,
        "manhattan": lambda: renders("manhattan", args.renders),
        "atlanta": lambda: renders("atlanta", args.renders),
        "real": real_dev,
    }
    summaries = []
    for name in wanted:
        inputs = loaders[name]()
        if inputs is None:
            continue
        start = time.perf_counter()
        layouts = layouts_over_keys(inputs, args.keys, config)
        summaries.append(set_summary(inputs, layouts))
        print(f"{inputs.name}: {len(inputs.rc)} x {args.keys} layouts in {time.perf_counter() - start:.0f} s")
        print(table(summaries[-1:], args.keys).splitlines()[-1])
        if name == "rig":
            height = np.asarray(layouts.ceiling_height - layouts.floor_height)[0]
            sigma = np.asarray(room_height_sigma(np.asarray(layouts.height_covariance[0], np.float64)))
            statuses = [ncjax.LayoutStatus(int(s)).name for s in np.asarray(layouts.status)[0]]
            print(f"  heights {np.round(height, 2).tolist()}")
            print(f"  sigmas {np.round(sigma, 2).tolist()}")
            print(f"  statuses {sorted(set(statuses))}, corners {sorted(set(np.sum(layouts.mask[0], -1).tolist()))}")
    rendered = [s for s in summaries if s["records"] is not None]
    if len(rendered) > 1:  # the goal's coverage is the renders': both worlds' together
        records = [record for s in rendered for record in s["records"]]
        summaries.append({"set": "the renders of both worlds", "records": records} | coverage_summary(records))
    print(table(summaries, args.keys))


if __name__ == "__main__":
    main()
