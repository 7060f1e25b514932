"""Calibrate the layouts' covariances on the network's rows: the size of the per-wall offset.

``Layout.corner_covariance`` and ``Layout.height_covariance`` describe the
boundary rows' noise as the fit's residuals show it. A network's rows also
share an error along whole walls (a skirting board or a furniture edge
followed for a whole wall), which the fit absorbs into the wall and its
residuals cannot show; ``UncertaintyConfig.wall_offset_ratio`` and
``wall_offset_noise`` give that offset a standard deviation, and
``corner_column_noise`` the detected corner columns' error, which the fit
also absorbs (:func:`ncjax.pipeline.uncertainty.layout_uncertainty`).

The three are chosen on the tuning renders of ``tune_network_pipeline.py``
(seeds 71 and 72; 256 per world here, twice the rooms that script uses, so that
the choice rests on about 2,000 corners) with ``NETWORK_PIPELINE_CONFIG``'s
scale test on, as ``ncjax reconstruct`` runs it (``max_height_uncertainty``
fails layouts by this same sigma, and the coverage that matters is that of
the layouts a user gets), then the coverage is measured on the test renders
of ``network_table.py`` (seeds 99 and 98) and on check renders of the same
generator (seeds 97 and 96, used nowhere else), which choose nothing. The shipped
model's snapped rows (4 views) go through ``ncjax.layout_from_boundaries``
with ``world="auto"`` and ``NETWORK_PIPELINE_CONFIG`` as ``ncjax reconstruct``
runs them. Per setting, over the ok layouts with the true corner count (the
covariance describes the rows' noise, not a missed corner): the share of the
true corners inside their 95% ellipse and of the true room heights within
1.96 sigma of the layout's (95% when calibrated), and the median corner sigma.
The setting chosen is the one whose two coverages on the tuning renders
lie nearest the middle of the goal's 90-97% (the larger of their distances
from 93.5% the smallest; on a tie, the smaller median corner sigma): on
other rooms a coverage moves by a few points (a room's corners err
together), and the middle leaves the most room either way; the sharpest
setting within 92-95% sat at the band's lower edge in heights and covered
89.5% of the test renders' heights. The test and check renders are scored
without the offsets (scale test off), with the chosen setting and with
``NETWORK_PIPELINE_CONFIG`` as it is (both with the scale test on).

    uv run python experiments/calibrate_uncertainty.py               # 256 tuning, 128 test, 128 check renders per world
    uv run python experiments/calibrate_uncertainty.py --tune-rooms 16 --test-rooms 16
    uv run python experiments/calibrate_uncertainty.py --skip-grid    # the test and check renders only
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from pathlib import Path

import jax
import numpy as np

import ncjax
from ncjax.evaluation import layout_metrics as metrics
from ncjax.io.export import layout_height_sigma
from ncjax.network.predict import DEFAULT_VIEWS
from ncjax.reconstruction import NETWORK_PIPELINE_CONFIG

from common import (
    OUT,
    TEST_SEEDS,
    corner_calibration,
    model_suffix,
    rendered_boundaries,
    test_renders,
    tuning_boundaries,
)

WORLDS = ("manhattan", "atlanta")
RATIOS = (0.0, 1.0, 2.0)
NOISES = (0.0, 1.0, 2.0)  # pixels of a 512-row panorama
CORNER_NOISES = (0.0, 1.0, 2.0, 3.0, 4.0, 8.0)  # columns of a 1024-column panorama
TARGET = 93.5  # the middle of the goal's 90-97% coverage: what the chosen setting aims at on the tuning renders
CHECK_SEEDS = {"manhattan": 97, "atlanta": 96}  # renders used by nothing but this script's last check


def coverage(data: dict, config: ncjax.PipelineConfig) -> dict:
    """Shares of true corners in their 95% ellipse and of true room heights within 1.96 sigma (%)."""
    width = data["ceiling_v"].shape[1]
    cams = jax.vmap(lambda rc: ncjax.NonCentralPanorama(width, width // 2, rc=rc))(data["rc"])
    layouts = jax.device_get(
        ncjax.layout_from_boundaries(data["ceiling_v"], data["floor_v"], data["corner_prob"], cams, "auto", config)
    )
    inside, sigmas, heights = [], [], []
    for index, truth in enumerate(data["truth"]):
        layout = jax.tree.map(lambda x: np.asarray(x[index]), layouts)
        if not bool(layout.ok):  # the scale test (max_height_uncertainty) fails more layouts as sigma grows
            continue
        _, shift = metrics.corner_error(layout, truth)
        if shift is None:  # another corner count
            continue
        within, sigma, _ = corner_calibration(layout, truth, shift)
        inside.extend(within)
        sigmas.extend(sigma)
        true_height = truth["ceiling_corners"][0][2] - truth["floor_corners"][0][2]
        height = float(layout.ceiling_height) - float(layout.floor_height)
        heights.append(abs(height - true_height) <= 1.96 * layout_height_sigma(layout))
    return {
        "ok": int(np.sum(layouts.ok)),
        "rooms": len(heights),
        "corners": len(inside),
        "corner_coverage": 100 * float(np.mean(inside)),
        "height_coverage": 100 * float(np.mean(heights)),
        "sigma_median": float(np.median(sigmas)),
        "sigmas": np.asarray(sigmas),
    }


def pooled(data: dict[str, dict], config: ncjax.PipelineConfig) -> dict:
    """:func:`coverage` of both worlds' renders together, and per world."""
    per_world = {world: coverage(data[world], config) for world in WORLDS}
    rooms = sum(r["rooms"] for r in per_world.values())
    ok = sum(r["ok"] for r in per_world.values())
    corners = sum(r["corners"] for r in per_world.values())
    return {
        "per_world": per_world,
        "corner_coverage": sum(r["corner_coverage"] * r["corners"] for r in per_world.values()) / corners,
        "height_coverage": sum(r["height_coverage"] * r["rooms"] for r in per_world.values()) / rooms,
        "ok": ok,
        "rooms": rooms,
        "corners": corners,
        "sigma_median": float(np.median(np.concatenate([r["sigmas"] for r in per_world.values()]))),
    }


SETTING = ("wall_offset_ratio", "wall_offset_noise", "corner_column_noise")


def shipped_setting() -> tuple[float, float, float]:
    """The three error sources as ``NETWORK_PIPELINE_CONFIG`` sets them."""
    return tuple(getattr(NETWORK_PIPELINE_CONFIG.uncertainty, name) for name in SETTING)


def with_setting(setting: tuple[float, float, float], scale_test: bool) -> ncjax.PipelineConfig:
    """``NETWORK_PIPELINE_CONFIG`` with the three error sources of ``setting``, its scale test on or off."""
    config = NETWORK_PIPELINE_CONFIG.replace(uncertainty=dict(zip(SETTING, setting, strict=True)))
    return config if scale_test else config.replace(checks={"max_height_uncertainty": math.inf})


def setting_name(setting: tuple[float, float, float], scale_test: bool) -> str:
    ratio, noise, corner = setting
    test = f"scale test {NETWORK_PIPELINE_CONFIG.checks.max_height_uncertainty:g}" if scale_test else "no scale test"
    return f"ratio {ratio:g}, offset {noise:g} px, corner {corner:g} px, {test}"


def line(name: str, result: dict) -> str:
    worlds = "; ".join(
        f"{w} {r['corner_coverage']:.1f} / {r['height_coverage']:.1f} "
        f"({r['rooms']} rooms, sigma {r['sigma_median']:.3f} m)"
        for w, r in result["per_world"].items()
    )
    return (
        f"| {name} | {result['corner_coverage']:.1f} | {result['height_coverage']:.1f} | "
        f"{result['sigma_median']:.3f} | "
        f"{result['ok']} | {result['rooms']} / {result['corners']} | {worlds} |"
    )


HEADER = [
    "| setting | corners in their 95% ellipse (%) | room heights within 1.96 sigma (%) | corner sigma median (m) | "
    "ok layouts | "
    "with the true count: rooms / corners | per world: corners / heights (%) |",
    "| --- | --- | --- | --- | --- | --- | --- |",
]


def held_out_boundaries(name: str, seeds: dict[str, int], rooms: int, out: Path) -> dict:
    """Per world, the shipped model's outputs on ``rooms`` renders of ``seeds`` (``network_table``'s test renders,
    or another set of that generator named ``name``), cached per model."""
    return {
        w: rendered_boundaries(
            test_renders(w, rooms, out, seeds, name),
            w,
            out / f"{name}_{w}_{rooms}_views{DEFAULT_VIEWS}{model_suffix(None)}.npz",
            DEFAULT_VIEWS,
        )
        for w in WORLDS
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tune-rooms", type=int, default=256, help="tuning renders per world")
    parser.add_argument("--test-rooms", type=int, default=128, help="test renders per world")
    parser.add_argument("--check-rooms", type=int, default=128, help="check renders per world")
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument(
        "--skip-grid", action="store_true", help="score NETWORK_PIPELINE_CONFIG on the test renders only"
    )
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    tuning = {w: tuning_boundaries(w, args.tune_rooms, DEFAULT_VIEWS, args.out) for w in WORLDS}
    test = held_out_boundaries("test", TEST_SEEDS, args.test_rooms, args.out)
    check = held_out_boundaries("check", CHECK_SEEDS, args.check_rooms, args.out)
    lines = [
        f"Tuning renders ({args.tune_rooms} per world), world auto, the shipped model's snapped rows:",
        "",
        *HEADER,
    ]
    best, best_rank = None, (np.inf, np.inf)
    for setting in [] if args.skip_grid else itertools.product(RATIOS, NOISES, CORNER_NOISES):
        result = pooled(tuning, with_setting(setting, scale_test=True))
        lines.append(line(setting_name(setting, scale_test=True), result))
        print(lines[-1], flush=True)
        off_target = max(abs(result[name] - TARGET) for name in ("corner_coverage", "height_coverage"))
        if (off_target, result["sigma_median"]) < best_rank:
            best, best_rank = setting, (off_target, result["sigma_median"])
    current = shipped_setting()
    lines += [
        "",
        f"Chosen on the tuning renders: {setting_name(best, True) if best else 'none'}; "
        f"NETWORK_PIPELINE_CONFIG: {setting_name(current, True)}.",
    ]
    scored = [(current, True), ((0.0, 0.0, 0.0), False), (best, True)]
    for name, data, rooms in (("Test", test, args.test_rooms), ("Check", check, args.check_rooms)):
        lines += ["", f"{name} renders ({rooms} per world), the same pipeline:", "", *HEADER]
        for setting, scale_test in dict.fromkeys(scored if best else scored[:2]):
            lines.append(line(setting_name(setting, scale_test), pooled(data, with_setting(setting, scale_test))))
    table = "\n".join(lines)
    print(table)
    print(f"total time {time.time() - start:.0f} s")
    (args.out / f"calibrate_uncertainty{model_suffix(None)}.md").write_text(table + "\n")


if __name__ == "__main__":
    main()
