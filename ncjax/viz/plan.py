"""The top-down floor plan in metres, with the corners' uncertainty ellipses."""

from __future__ import annotations

import math

import numpy as np
from jaxtyping import ArrayLike, Float, UInt8
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Ellipse
from matplotlib.ticker import MaxNLocator

from ..io.export import failure_label, has_geometry, layout_height_sigma, signed_area, valid_corners, wall_lengths
from ..pipeline.types import Layout

# --- floor plan ------------------------------------------------------------------------------------------


def _figure_to_rgb(figure: Figure) -> np.ndarray:
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


CHI2_2D_95 = 5.991464547107979  # 95% quantile of the chi-square distribution with 2 degrees of freedom


def corner_ellipses(covariance: Float[ArrayLike, "n 2 2"]) -> Float[np.ndarray, "n 3"]:
    """Full width, full height and angle (degrees) of each corner's 95% ellipse (matplotlib's ``Ellipse``).

    The ellipse ``e^T C^-1 e <= chi2_2(0.95)`` of a 2D Gaussian error with
    covariance ``C``: semi-axes ``sqrt(chi2 lambda)`` along ``C``'s
    eigenvectors. NaN for a covariance that is not finite.
    """
    covariance = np.asarray(covariance, np.float64).reshape(-1, 2, 2)
    finite = np.all(np.isfinite(covariance), axis=(1, 2))
    values, vectors = np.linalg.eigh(np.where(finite[:, None, None], covariance, np.eye(2)))
    axes = 2 * np.sqrt(CHI2_2D_95 * np.maximum(values, 0.0))
    angle = np.degrees(np.arctan2(vectors[:, 1, 1], vectors[:, 0, 1]))
    ellipses = np.stack([axes[:, 1], axes[:, 0], angle], -1)
    return np.where(finite[:, None], ellipses, np.nan)


def draw_plan(layout: Layout, *, title: str = "", rc: float | None = None) -> UInt8[np.ndarray, "H W 3"]:
    """The top-down floor plan: x right, y up, metres, camera at the origin.

    Walls are lines with their length written at their middle (inserted walls
    dashed), each corner carries the ellipse that holds its true position with
    95% probability under :attr:`ncjax.Layout.corner_covariance`, the origin
    is marked, and the circle of optical centres is drawn if ``rc`` is given.
    The title gives the ceiling and floor heights, the room height (with its
    standard deviation) and the floor area. A failed layout gives a figure saying
    "no layout: <status>". Matplotlib's Agg canvas is used directly: no
    pyplot state is left behind.

    Args:
        layout: one unbatched layout.
        title: first line of the title (e.g. the panorama's name).
        rc: radius of the circle of optical centres, metres.

    Returns:
        An RGB uint8 image (600 x 600 pixels).
    """
    figure = Figure(figsize=(6, 6), dpi=100)
    axes = figure.add_subplot()
    if not has_geometry(layout):
        axes.set_axis_off()
        axes.text(0.5, 0.5, failure_label(layout), ha="center", va="center", fontsize=16)
        if title:
            axes.set_title(title)
        return _figure_to_rgb(figure)

    _, floor = valid_corners(layout)
    inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
    plan = floor[:, :2]
    n = len(plan)
    lengths = wall_lengths(plan)
    axes.fill(plan[:, 0], plan[:, 1], color="0.92", zorder=0)
    for k in range(n):
        start, end = plan[k], plan[(k + 1) % n]
        axes.plot(
            [start[0], end[0]],
            [start[1], end[1]],
            color="tab:red" if inserted[k] else "tab:blue",
            linestyle="--" if inserted[k] else "-",
            linewidth=2,
            label=("inserted wall" if inserted[k] else "wall"),
        )
        middle = (start + end) / 2
        axes.annotate(
            f"{lengths[k]:.2f} m",
            middle,
            ha="center",
            va="center",
            fontsize=8,
            bbox={"fc": "white", "ec": "none", "alpha": 0.8},
        )
    covariance = np.asarray(layout.corner_covariance, np.float64)[np.asarray(layout.mask, bool)]
    for centre, (width, height, angle) in zip(plan, corner_ellipses(covariance), strict=True):
        if np.isfinite(width):
            axes.add_patch(
                Ellipse(
                    centre,
                    width,
                    height,
                    angle=angle,
                    facecolor="tab:orange",
                    alpha=0.35,
                    edgecolor="tab:orange",
                    label="95% corner region",
                )
            )
    axes.plot([0.0], [0.0], marker="+", color="black", markersize=10, linestyle="none", label="origin")
    if rc is not None:
        angle = np.linspace(0.0, 2 * np.pi, 90)
        axes.plot(rc * np.cos(angle), rc * np.sin(angle), color="black", linewidth=1, label=f"camera (rc = {rc:.2f} m)")
    handles, labels = axes.get_legend_handles_labels()
    unique = dict(zip(labels, handles, strict=True))  # one legend entry per kind of line
    axes.legend(unique.values(), unique.keys(), loc="best", fontsize=8)

    # framed on the room and the camera: an ellipse far larger than the room is cut, not shrinking the room
    shown = np.concatenate([plan, np.full((1, 2), -(rc or 0.0)), np.full((1, 2), rc or 0.0)])
    low, high = shown.min(0), shown.max(0)
    centre, half = (low + high) / 2, 0.6 * float(np.max(high - low)) + 0.3  # one span for both axes: equal scales
    axes.set_xlim(centre[0] - half, centre[0] + half)
    axes.set_ylim(centre[1] - half, centre[1] + half)
    axes.set_aspect("equal")
    for axis in (axes.xaxis, axes.yaxis):  # whole metres, about 12 grid lines at most
        axis.set_major_locator(MaxNLocator(nbins=12, steps=[1, 2, 5, 10], integer=True))
    axes.grid(True, color="0.8", linewidth=0.5)
    axes.set_xlabel("x (m)")
    axes.set_ylabel("y (m)")
    ceiling_height = float(np.asarray(layout.ceiling_height))
    floor_height = float(np.asarray(layout.floor_height))
    height_sigma = layout_height_sigma(layout)
    spread = f" ± {height_sigma:.2f}" if math.isfinite(height_sigma) else ""
    summary = (
        f"ceiling {ceiling_height:.2f} m, floor {floor_height:.2f} m, "
        f"height {ceiling_height - floor_height:.2f}{spread} m, "
        f"area {abs(signed_area(plan)):.2f} m²"
    )
    if not bool(np.asarray(layout.ok)):
        summary = f"{failure_label(layout)}: {summary}"
    axes.set_title(f"{title}\n{summary}" if title else summary, fontsize=10)
    figure.tight_layout()
    return _figure_to_rgb(figure)
