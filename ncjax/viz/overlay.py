"""The layout reprojected onto the panorama, with the network's boundaries and corner probability."""

from __future__ import annotations

import cv2
import jax
import numpy as np
from jaxtyping import ArrayLike, Float, UInt8

from ..geometry.camera import NonCentralPanorama, project
from ..io.export import failure_label, has_geometry, valid_corners
from ..io.images import check_rgb
from ..pipeline.types import Layout

# Overlay colours (RGB).
NETWORK_COLOUR = (255, 190, 0)  # the network's per-column boundaries
LAYOUT_COLOUR = (0, 230, 255)  # the reprojected layout
INSERTED_COLOUR = (255, 40, 200)  # walls inserted for an occlusion (not seen in the image)
CORNER_COLOUR = (255, 255, 255)  # the corner probability strip
LEGEND_TEXT_COLOUR = (235, 235, 235)
LEGEND_LABELS = {
    "network": "network boundaries",
    "layout": "layout",
    "inserted": "inserted wall (unseen)",
    "corner": "corner probability (bottom)",
}
_FONT = cv2.FONT_HERSHEY_SIMPLEX
# one compiled program (kept in the CLI's compilation cache) instead of a compilation per operation
_project = jax.jit(project)


# --- overlay on the panorama --------------------------------------------------------------------------


def _legend_metrics(height: int) -> tuple[float, int, int, int, int]:
    """Font scale, text height, line pitch, margin and colour swatch length of a legend, in proportion to the image."""
    scale = max(0.3, 0.4 * height / 512)
    (_, text_height), baseline = cv2.getTextSize("Mg", _FONT, scale, 1)
    pitch = text_height + baseline + max(2, round(0.006 * height))
    return scale, text_height, pitch, max(2, round(0.01 * height)), 2 * text_height


def legend_box(labels: list[str], height: int, width: int) -> tuple[int, int, int, int]:
    """Where :func:`draw_overlay` puts the legend of ``labels``: ``(top, bottom, left, right)`` pixels.

    The box sits in the top right corner (the ceiling, away from most boundaries; the
    label of a failed layout is in the top left), its size in proportion to the image.
    """
    scale, _, pitch, margin, swatch = _legend_metrics(height)
    text_width = max(cv2.getTextSize(label, _FONT, scale, 1)[0][0] for label in labels)
    box_width = min(width, 3 * margin + swatch + text_width)
    return 0, min(height, 2 * margin + pitch * len(labels)), width - box_width, width


def _draw_legend(canvas: np.ndarray, entries: list[tuple[str, tuple[int, int, int]]]) -> None:
    """Name each colour drawn, in a darkened box in the top right corner (:func:`legend_box`)."""
    if not entries:
        return
    height, width = canvas.shape[:2]
    top, bottom, left, right = legend_box([label for label, _ in entries], height, width)
    canvas[top:bottom, left:right] //= 3  # darkened, so the text reads on any image
    scale, text_height, pitch, margin, swatch = _legend_metrics(height)
    thickness = max(1, round(height / 256))
    for index, (label, colour) in enumerate(entries):
        base = top + margin + index * pitch + text_height
        middle = base - text_height // 2
        cv2.line(canvas, (left + margin, middle), (left + margin + swatch, middle), colour, thickness, cv2.LINE_AA)
        cv2.putText(canvas, label, (left + 2 * margin + swatch, base), _FONT, scale, LEGEND_TEXT_COLOUR, 1, cv2.LINE_AA)


def legend_entries(layout: Layout, boundaries: bool, corner_prob: bool) -> list[tuple[str, tuple[int, int, int]]]:
    """The legend of an overlay: (label, colour) of each kind of line drawn."""
    entries = [(LEGEND_LABELS["network"], NETWORK_COLOUR)] if boundaries else []
    if has_geometry(layout):
        entries.append((LEGEND_LABELS["layout"], LAYOUT_COLOUR))
        if np.any(np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]):
            entries.append((LEGEND_LABELS["inserted"], INSERTED_COLOUR))
    if corner_prob:
        entries.append((LEGEND_LABELS["corner"], CORNER_COLOUR))
    return entries


def _draw_curve(canvas: np.ndarray, u: np.ndarray, v: np.ndarray, colour: tuple[int, int, int], thickness: int) -> None:
    """Draw sampled image points as antialiased polylines, broken at NaNs and where u wraps at the seam."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    finite = np.isfinite(u) & np.isfinite(v)
    breaks = ~finite[1:] | ~finite[:-1] | (np.abs(np.diff(u)) > canvas.shape[1] / 2)
    shift = 4  # cv2 draws at 1/16-pixel precision from fixed-point coordinates
    for run in np.split(np.arange(len(u)), np.flatnonzero(breaks) + 1):
        if len(run) < 2 or not finite[run[0]]:
            continue
        points = np.round(np.stack([u[run], v[run]], axis=-1) * 2**shift).astype(np.int32)
        cv2.polylines(canvas, [points], False, colour, thickness, cv2.LINE_AA, shift)


def draw_overlay(
    image: UInt8[np.ndarray, "H W 3"],
    layout: Layout,
    cam: NonCentralPanorama,
    ceiling_v: Float[ArrayLike, " W"] | None = None,
    floor_v: Float[ArrayLike, " W"] | None = None,
    corner_prob: Float[ArrayLike, " W"] | None = None,
) -> UInt8[np.ndarray, "H W 3"]:
    """The panorama with the network's boundaries and the recovered layout drawn on it.

    - the network's ceiling and floor rows per column, if given, in
      ``NETWORK_COLOUR``;
    - the layout's ceiling and floor edges, sampled densely in 3D and
      projected with :func:`ncjax.geometry.project` (the curves of a non-central
      camera), and the vertical edges at the corners, in ``LAYOUT_COLOUR``;
      inserted walls (occluded, not seen) in ``INSERTED_COLOUR``. Curves break
      at the image seam and where points are not visible;
    - the corner probability, if given, as a plot strip along the bottom;
    - a legend in the top right corner (:func:`legend_box`) naming the colours drawn.

    A failed layout draws only the network's outputs and a "no layout" label;
    a flagged one (``UNCERTAIN_SCALE``, ``LOW_CONFIDENCE``, ``SCALE_CONFLICT``) is drawn with its flag as a label.

    Args:
        image: the panorama, RGB uint8 (H, W, 3).
        layout: one unbatched layout.
        cam: the camera; its size must be the image's.
        ceiling_v, floor_v, corner_prob: optional network outputs, (W,) each.

    Returns:
        A new RGB uint8 image; ``image`` is not modified.

    Raises:
        ValueError: for an image that is not RGB uint8, a camera of another
            size than the image, or network outputs not of shape (W,).
    """
    canvas = check_rgb(image).copy()
    height, width = canvas.shape[:2]
    if (cam.width, cam.height) != (width, height):
        raise ValueError(f"camera size {cam.width} x {cam.height} differs from the image's {width} x {height}")
    outputs = {"ceiling_v": ceiling_v, "floor_v": floor_v, "corner_prob": corner_prob}
    for key, value in outputs.items():
        if value is not None and np.shape(value) != (width,):
            raise ValueError(f"{key} must have shape ({width},), got {np.shape(value)}")
    thickness = max(1, round(width / 512))
    columns = np.arange(width, dtype=np.float64)

    for rows in (ceiling_v, floor_v):
        if rows is not None:
            _draw_curve(canvas, columns, np.asarray(rows, np.float64), NETWORK_COLOUR, thickness)

    if has_geometry(layout):
        ceiling, floor = valid_corners(layout)
        inserted = np.asarray(layout.inserted, bool)[np.asarray(layout.mask, bool)]
        n = len(ceiling)
        # Edges are sampled densely because a non-central camera images them as curves. A vertical
        # edge has one azimuth (a straight column) but is sampled too, so invisible parts break it.
        along = np.linspace(0.0, 1.0, max(64, width // 2))[None, :, None]
        up = np.linspace(0.0, 1.0, 16)[None, :, None]
        following = np.roll(np.arange(n), -1)
        ceiling_edges = ceiling[:, None] + along * (ceiling[following] - ceiling)[:, None]
        floor_edges = floor[:, None] + along * (floor[following] - floor)[:, None]
        vertical_edges = floor[:, None] + up * (ceiling - floor)[:, None]
        samples = np.concatenate(
            [ceiling_edges.reshape(-1, 3), floor_edges.reshape(-1, 3), vertical_edges.reshape(-1, 3)]
        )
        u, v = _project(cam, samples.astype(np.float32))  # one call for everything: one dispatch
        u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
        horizontal = 2 * n * along.shape[1]
        u_edges, v_edges = u[:horizontal].reshape(2, n, -1), v[:horizontal].reshape(2, n, -1)
        u_vertical, v_vertical = u[horizontal:].reshape(n, -1), v[horizontal:].reshape(n, -1)
        for k in range(n):
            colour = INSERTED_COLOUR if inserted[k] else LAYOUT_COLOUR
            for edge in range(2):  # ceiling, floor
                _draw_curve(canvas, u_edges[edge, k], v_edges[edge, k], colour, thickness)
            _draw_curve(canvas, u_vertical[k], v_vertical[k], LAYOUT_COLOUR, thickness)
    if not bool(np.asarray(layout.ok)):
        scale = height / 512
        cv2.putText(
            canvas,
            failure_label(layout),
            (round(8 * scale), round(32 * scale)),
            cv2.FONT_HERSHEY_SIMPLEX,
            scale,
            INSERTED_COLOUR,
            thickness,
            cv2.LINE_AA,
        )

    if corner_prob is not None:
        strip = max(16, height // 8)
        canvas[height - strip :] //= 2  # darken the strip so the plot reads on any image
        probability = np.clip(np.asarray(corner_prob, np.float64), 0.0, 1.0)
        _draw_curve(canvas, columns, height - 1 - probability * (strip - 1), CORNER_COLOUR, thickness)

    _draw_legend(canvas, legend_entries(layout, ceiling_v is not None or floor_v is not None, corner_prob is not None))
    return canvas
