"""The top-down floor plan in metres, with the corners' uncertainty ellipses.

Drawn with Pillow, twice the size and then averaged down (smooth lines): importing a plotting
library would cost a one-panorama run about 0.6 s, a sixth of it.
"""

from __future__ import annotations

import math

import numpy as np
from jaxtyping import ArrayLike, Float, UInt8
from PIL import Image, ImageDraw, ImageFont

from ..io.export import failure_label, has_geometry, layout_height_sigma, signed_area, valid_corners, wall_lengths
from ..pipeline.types import Layout

# --- floor plan ------------------------------------------------------------------------------------------


CHI2_2D_95 = 5.991464547107979  # 95% quantile of the chi-square distribution with 2 degrees of freedom


def corner_ellipses(covariance: Float[ArrayLike, "n 2 2"]) -> Float[np.ndarray, "n 3"]:
    """Full width, full height and angle (degrees, of the width's axis from x) of each corner's 95% ellipse.

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


SIZE = 600  # pixels, square
SUPERSAMPLE = 2
PLOT_BOX = (64, 52, 564, 552)  # left, top, right, bottom of the square plot area, pixels
MAX_GRID_LINES = 12
GRID_STEPS = (1, 2, 5, 10, 20, 50, 100, 200, 500)  # metres
WALL, INSERTED, ORANGE = (31, 119, 180), (214, 39, 40), (255, 127, 14)
FLOOR, GRID, FRAME = (235, 235, 235), (204, 204, 204), (120, 120, 120)


class _Canvas:
    """A white square image at :data:`SUPERSAMPLE` times :data:`SIZE`, metres mapped onto :data:`PLOT_BOX`."""

    def __init__(self, centre: np.ndarray, half: float):
        self.image = Image.new("RGB", (SIZE * SUPERSAMPLE, SIZE * SUPERSAMPLE), "white")
        self.draw = ImageDraw.Draw(self.image)
        self.centre, self.half = centre, half
        left, top, right, _ = PLOT_BOX
        self.scale = SUPERSAMPLE * (right - left) / (2 * half)  # pixels per metre, both axes

    def pixels(self, points: Float[ArrayLike, "n 2"]) -> list[tuple[float, float]]:
        """Metres to pixels (y up), clamped far outside the image (a huge ellipse's points)."""
        points = np.asarray(points, np.float64).reshape(-1, 2)
        left, top = PLOT_BOX[0] * SUPERSAMPLE, PLOT_BOX[1] * SUPERSAMPLE
        x = left + (points[:, 0] - self.centre[0] + self.half) * self.scale
        y = top + (self.centre[1] + self.half - points[:, 1]) * self.scale
        far = 50.0 * SIZE * SUPERSAMPLE
        return [(float(a), float(b)) for a, b in zip(np.clip(x, -far, far), np.clip(y, -far, far), strict=True)]

    def font(self, size: int) -> ImageFont.FreeTypeFont:
        return ImageFont.load_default(size=size * SUPERSAMPLE)

    def text(self, at: tuple[float, float], text: str, size: int, anchor: str = "mm", box: bool = False) -> None:
        """``text`` at ``at`` (pixels of the final image), on a white box if ``box``."""
        xy = (at[0] * SUPERSAMPLE, at[1] * SUPERSAMPLE)
        font = self.font(size)
        if box:
            left, top, right, bottom = self.draw.textbbox(xy, text, font=font, anchor=anchor)
            pad = 2 * SUPERSAMPLE
            self.draw.rectangle((left - pad, top - pad, right + pad, bottom + pad), fill="white")
        self.draw.text(xy, text, font=font, fill="black", anchor=anchor)

    def line(self, points, colour, width: float, dashed: bool = False) -> None:
        """A line between two points in metres (:meth:`segment`)."""
        self.segment(*self.pixels(points), colour, width, dashed)

    def segment(self, start, end, colour, width: float, dashed: bool = False) -> None:
        """A line between two pixels of the supersampled image, ``width`` pixels of the final one wide."""
        start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
        if not dashed:
            self.draw.line([tuple(start), tuple(end)], fill=colour, width=round(width * SUPERSAMPLE))
            return
        length = float(np.linalg.norm(end - start))
        dash, gap = 8.0 * SUPERSAMPLE, 5.0 * SUPERSAMPLE
        for offset in np.arange(0.0, length, dash + gap):
            a = start + (end - start) * offset / max(length, 1e-9)
            b = start + (end - start) * min(offset + dash, length) / max(length, 1e-9)
            self.draw.line([tuple(a), tuple(b)], fill=colour, width=round(width * SUPERSAMPLE))

    def plus(self, at, arm: float) -> None:
        """A black ``+`` at a pixel of the supersampled image, arms ``arm`` pixels of the final one long."""
        x, y = at
        arm *= SUPERSAMPLE
        self.draw.line([(x - arm, y), (x + arm, y)], fill="black", width=SUPERSAMPLE)
        self.draw.line([(x, y - arm), (x, y + arm)], fill="black", width=SUPERSAMPLE)

    def finished(self) -> UInt8[np.ndarray, "H W 3"]:
        return np.asarray(self.image.reduce(SUPERSAMPLE))


def _ellipse_outline(centre, width: float, height: float, angle: float, points: int = 72) -> np.ndarray:
    turn = np.radians(angle)
    t = np.linspace(0.0, 2 * np.pi, points, endpoint=False)
    along, across = width / 2 * np.cos(t), height / 2 * np.sin(t)
    return np.stack(
        [
            centre[0] + along * np.cos(turn) - across * np.sin(turn),
            centre[1] + along * np.sin(turn) + across * np.cos(turn),
        ],
        -1,
    )


def _grid_step(span: float) -> int:
    """The smallest of :data:`GRID_STEPS` that draws at most :data:`MAX_GRID_LINES` lines over ``span`` metres."""
    return next((step for step in GRID_STEPS if span / step <= MAX_GRID_LINES), GRID_STEPS[-1])


def draw_plan(layout: Layout, *, title: str = "", rc: float | None = None) -> UInt8[np.ndarray, "H W 3"]:
    """The top-down floor plan: x right, y up, metres, camera at the origin.

    Walls are lines with their length written at their middle (inserted walls
    red and dashed), each corner carries the ellipse that holds its true position with
    95% probability under :attr:`ncjax.Layout.corner_covariance` (cut at the frame, which
    is set by the room and the camera), the origin is marked, and the circle of optical
    centres is drawn if ``rc`` is given; a grid of whole metres (1, 2, 5, ... m apart) and a
    legend. The title gives the ceiling and floor heights, the room height (with its
    standard deviation) and the floor area. A failed layout gives a figure saying
    "no layout: <status>".

    Args:
        layout: one unbatched layout.
        title: first line of the title (e.g. the panorama's name).
        rc: radius of the circle of optical centres, metres.

    Returns:
        An RGB uint8 image (600 x 600 pixels).
    """
    rc = max(float(rc), 0.0) if rc is not None and math.isfinite(rc) else None
    if not has_geometry(layout):
        return _failure_figure(layout, title)

    _, floor = valid_corners(layout)
    inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
    plan = floor[:, :2]
    covariance = np.asarray(layout.corner_covariance, np.float64)[np.asarray(layout.mask, bool)]
    ellipses = [(c, e) for c, e in zip(plan, corner_ellipses(covariance), strict=True) if np.isfinite(e[0])]
    entries = _legend_entries(any(~inserted), any(inserted), bool(ellipses), rc)
    canvas, place = _framed_canvas(plan, rc, entries)
    ticks = _draw_grid(canvas)
    canvas.draw.polygon(canvas.pixels(plan), fill=FLOOR)
    if ellipses:
        _draw_ellipses(canvas, ellipses)
    _draw_walls(canvas, plan, inserted)
    _draw_camera(canvas, rc)
    _draw_frame(canvas, ticks)
    _draw_legend(canvas, entries, place)
    _draw_title(canvas, layout, plan, title)
    return canvas.finished()


def _failure_figure(layout: Layout, title: str) -> UInt8[np.ndarray, "H W 3"]:
    """The figure of a layout without geometry: "no layout: <status>" and the title."""
    canvas = _Canvas(np.zeros(2), 1.0)
    canvas.text((SIZE / 2, SIZE / 2), failure_label(layout), 22)
    if title:
        canvas.text((SIZE / 2, 16), title, 13)
    return canvas.finished()


def _framed_canvas(
    plan: np.ndarray, rc: float | None, entries: list[tuple[str, str]]
) -> tuple[_Canvas, tuple[float, float]]:
    """The canvas framed on the room and the camera, and the legend's place, widened until the legend covers no wall.

    An ellipse far larger than the room is cut, not shrinking the room.
    """
    along = np.linspace(0.0, 1.0, 25)[:, None, None]
    wall_points = (1 - along) * plan + along * np.roll(plan, -1, axis=0)  # where the room is drawn
    shown = np.concatenate([plan, np.full((1, 2), -(rc or 0.0)), np.full((1, 2), rc or 0.0)])
    low, high = shown.min(0), shown.max(0)
    for widening in (1.0, 1.15, 1.3, 1.5):
        canvas = _Canvas((low + high) / 2, widening * (0.6 * float(np.max(high - low)) + 0.3))
        place, covered = _legend_place(canvas, entries, np.asarray(canvas.pixels(wall_points)))
        if not covered:
            break
    return canvas, place


def _draw_grid(canvas: _Canvas) -> list[np.ndarray]:
    """The grid of whole metres over the plot (:func:`_grid_step`); returns its x and y ticks."""
    step = _grid_step(2 * canvas.half)
    lower, upper = canvas.centre - canvas.half, canvas.centre + canvas.half
    ticks = [np.arange(math.ceil(lower[axis] / step) * step, upper[axis] + 1e-9, step) for axis in (0, 1)]
    for x in ticks[0]:
        canvas.line([(x, lower[1]), (x, upper[1])], GRID, 1)
    for y in ticks[1]:
        canvas.line([(lower[0], y), (upper[0], y)], GRID, 1)
    return ticks


def _draw_ellipses(canvas: _Canvas, ellipses: list) -> None:
    """The corners' 95% regions, ``(centre, (width, height, angle))`` each, shaded over the floor."""
    shade = Image.new("RGBA", canvas.image.size, (0, 0, 0, 0))
    shade_draw = ImageDraw.Draw(shade)
    for centre, (width, height, angle) in ellipses:
        outline = canvas.pixels(_ellipse_outline(centre, width, height, angle))
        shade_draw.polygon(outline, fill=(*ORANGE, 90), outline=(*ORANGE, 200))
    canvas.image.paste(Image.alpha_composite(canvas.image.convert("RGBA"), shade).convert("RGB"))


def _draw_walls(canvas: _Canvas, plan: np.ndarray, inserted: np.ndarray) -> None:
    """The walls (inserted ones red and dashed), then each one's length at its middle."""
    n = len(plan)
    lengths = wall_lengths(plan)
    for k in range(n):
        start, end = plan[k], plan[(k + 1) % n]
        canvas.line([start, end], INSERTED if inserted[k] else WALL, 2, dashed=bool(inserted[k]))
    for k in range(n):
        middle = np.asarray(canvas.pixels((plan[k] + plan[(k + 1) % n]) / 2))[0] / SUPERSAMPLE
        canvas.text(tuple(middle), f"{lengths[k]:.2f} m", 10, box=True)


def _draw_camera(canvas: _Canvas, rc: float | None) -> None:
    """The origin's ``+``, and the circle of optical centres when ``rc`` is given and positive."""
    (origin,) = canvas.pixels(np.zeros(2))
    canvas.plus(origin, 7)
    if rc:
        radius = rc * canvas.scale
        canvas.draw.ellipse(
            (origin[0] - radius, origin[1] - radius, origin[0] + radius, origin[1] + radius),
            outline="black",
            width=SUPERSAMPLE,
        )


def _draw_frame(canvas: _Canvas, ticks: list[np.ndarray]) -> None:
    """White margins over what reaches past the plot (ellipses), then the frame, the tick labels and the axis names."""
    left, top, right, bottom = (SUPERSAMPLE * x for x in PLOT_BOX)
    lower = canvas.centre - canvas.half
    full = SIZE * SUPERSAMPLE
    for box in ((0, 0, full, top), (0, bottom, full, full), (0, 0, left, full), (right, 0, full, full)):
        canvas.draw.rectangle(box, fill="white")
    canvas.draw.rectangle((left, top, right, bottom), outline=FRAME, width=SUPERSAMPLE)
    for x in ticks[0]:
        (at,) = canvas.pixels([(x, lower[1])])
        canvas.text((at[0] / SUPERSAMPLE, PLOT_BOX[3] + 10), f"{x:g}", 11)
    for y in ticks[1]:
        (at,) = canvas.pixels([(lower[0], y)])
        canvas.text((PLOT_BOX[0] - 6, at[1] / SUPERSAMPLE), f"{y:g}", 11, anchor="rm")
    canvas.text(((PLOT_BOX[0] + PLOT_BOX[2]) / 2, PLOT_BOX[3] + 28), "x (m)", 12)
    label = Image.new("RGB", canvas.draw.textbbox((0, 0), "y (m)", font=canvas.font(12))[2:], "white")
    ImageDraw.Draw(label).text((0, 0), "y (m)", font=canvas.font(12), fill="black")
    label = label.rotate(90, expand=True)
    canvas.image.paste(label, (6 * SUPERSAMPLE, (top + bottom - label.height) // 2))


def _draw_title(canvas: _Canvas, layout: Layout, plan: np.ndarray, title: str) -> None:
    """The title and the heights, room height, its standard deviation and the floor area (a long line is cut)."""
    ceiling_height = float(np.asarray(layout.ceiling_height))
    floor_height = float(np.asarray(layout.floor_height))
    height_sigma = layout_height_sigma(layout)
    spread = f" ± {height_sigma:.2f}" if math.isfinite(height_sigma) else ""
    summary = (
        f"ceiling {ceiling_height:.2f} m, floor {floor_height:.2f} m, "
        f"height {ceiling_height - floor_height:.2f}{spread} m, "
        f"area {abs(signed_area(plan)):.2f} m^2"
    )
    if not bool(np.asarray(layout.ok)):
        summary = f"{failure_label(layout)}: {summary}"
    lines = [title, summary] if title else [summary]
    for row, line in enumerate(lines):
        size = 12 if row or not title else 13
        while len(line) > 1 and canvas.draw.textlength(line, font=canvas.font(size)) > (SIZE - 20) * SUPERSAMPLE:
            line = line[:-2] + "…"  # a long name is cut, not run off the image
        canvas.text((SIZE / 2, 14 + 18 * row - 9 * (len(lines) - 1) + 9), line, size)


def _legend_entries(walls: bool, inserted: bool, ellipses: bool, rc: float | None) -> list[tuple[str, str]]:
    """``(text, mark)`` of each kind of mark drawn."""
    entries = [("wall", "line")] * walls + [("inserted wall", "dashed")] * inserted
    entries += [("95% corner region", "patch")] * ellipses + [("origin", "plus")]
    if rc is not None:
        entries.append((f"camera (rc = {rc:.2f} m)", "circle"))
    return entries


def _legend_size(canvas: _Canvas, entries: list[tuple[str, str]]) -> tuple[float, float]:
    font = canvas.font(10)
    return max(font.getlength(text) for text, _ in entries) / SUPERSAMPLE + 40, 16 * len(entries) + 6


def _legend_place(canvas: _Canvas, entries, avoid: np.ndarray) -> tuple[tuple[float, float], int]:
    """The legend's top left corner in the plot's corner that covers fewest of the pixels ``avoid`` (top right
    first), and how many it covers."""
    width, height = _legend_size(canvas, entries)
    places = [
        (PLOT_BOX[2] - 8 - width, PLOT_BOX[1] + 8),
        (PLOT_BOX[0] + 8, PLOT_BOX[1] + 8),
        (PLOT_BOX[2] - 8 - width, PLOT_BOX[3] - 8 - height),
        (PLOT_BOX[0] + 8, PLOT_BOX[3] - 8 - height),
    ]

    def covered(place):
        x, y = avoid[:, 0] / SUPERSAMPLE - place[0], avoid[:, 1] / SUPERSAMPLE - place[1]
        return int(np.sum((x >= 0) & (x <= width) & (y >= 0) & (y <= height)))

    place = min(places, key=covered)
    return place, covered(place)


def _draw_legend(canvas: _Canvas, entries, place: tuple[float, float]) -> None:
    s = SUPERSAMPLE
    width, height = _legend_size(canvas, entries)
    left, top = place
    canvas.draw.rectangle(
        (left * s, top * s, (left + width) * s, (top + height) * s), fill="white", outline=FRAME, width=1
    )
    for row, (text, mark) in enumerate(entries):
        y = (top + 11 + 16 * row) * s
        x0, x1 = (left + 6) * s, (left + 28) * s
        if mark in ("line", "dashed"):
            canvas.segment((x0, y), (x1, y), WALL if mark == "line" else INSERTED, 2, dashed=mark == "dashed")
        elif mark == "patch":
            canvas.draw.rectangle((x0, y - 5 * s, x1, y + 5 * s), fill=(255, 210, 170), outline=ORANGE)
        elif mark == "plus":
            canvas.plus(((x0 + x1) / 2, y), 6)
        else:
            canvas.segment((x0, y), (x1, y), "black", 1)
        canvas.draw.text((x1 + 6 * s, y), text, font=canvas.font(10), fill="black", anchor="lm")
