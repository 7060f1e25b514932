"""The real-panorama benchmark's contact sheet: each panorama downscaled with the label's and the prediction's
boundaries and corners, and the corner probability below it with the peak threshold."""

from __future__ import annotations

import math

import cv2
import numpy as np

from .panorama_labels import LabelledPanorama

TILE_WIDTH = 512
STRIP_HEIGHT = 40
CAPTION_HEIGHT = 18
CAPTION_NAME_LENGTH = 30  # the end of a longer name is shown
LABEL_COLOUR = (0, 220, 0)  # RGB
PREDICTION_COLOUR = (255, 40, 40)
THRESHOLD_COLOUR = (130, 130, 130)
OCCLUDED_COLOUR = (200, 200, 200)


def tile_coordinate(pixels: np.ndarray, scale: float) -> np.ndarray:
    """Image pixel coordinates (centres at integers) in an image downscaled by ``scale``."""
    return (np.asarray(pixels, np.float64) + 0.5) * scale - 0.5


def draw_curve(canvas: np.ndarray, u: np.ndarray, v: np.ndarray, colour, max_jump: float = math.inf) -> None:
    """Draw a curve through canvas points, broken at NaNs and where ``v`` jumps by more than ``max_jump``."""
    finite = np.isfinite(v)
    breaks = ~finite[1:] | ~finite[:-1] | (np.abs(np.diff(v)) > max_jump)
    for run in np.split(np.arange(len(v)), np.flatnonzero(breaks) + 1):
        if len(run) > 1 and finite[run[0]]:
            points = np.round(np.stack([u[run], v[run]], axis=-1) * 16).astype(np.int32)
            cv2.polylines(canvas, [points], False, colour, 1, cv2.LINE_AA, shift=4)


def draw_rows(canvas: np.ndarray, rows: np.ndarray, scale: float, colour) -> None:
    """Draw per-column image rows on a downscaled image, broken at occlusions (jumps of over 5% of the height)."""
    columns = tile_coordinate(np.arange(len(rows)), scale)
    draw_curve(canvas, columns, tile_coordinate(rows, scale), colour, max_jump=0.05 * canvas.shape[0])


def draw_ticks(canvas: np.ndarray, columns: np.ndarray, scale: float, top: int, bottom: int, colour) -> None:
    """Short vertical marks at image columns."""
    for x in np.round(tile_coordinate(columns, scale)).astype(int):
        cv2.line(canvas, (x, top), (x, bottom), colour, 2)


def probability_strip(
    corner_prob: np.ndarray, panorama: LabelledPanorama, peaks: np.ndarray, scale: float, corner_threshold: float
):
    """The corner probability under a tile: the curve, the peak threshold, label and predicted corner ticks."""
    strip = np.full((STRIP_HEIGHT, TILE_WIDTH, 3), 25, np.uint8)
    y_of = lambda p: (STRIP_HEIGHT - 3) - (STRIP_HEIGHT - 10) * np.clip(p, 0.0, 1.0)  # noqa: E731
    threshold_y = int(round(y_of(corner_threshold)))
    cv2.line(strip, (0, threshold_y), (TILE_WIDTH, threshold_y), THRESHOLD_COLOUR, 1)
    columns = tile_coordinate(np.arange(len(corner_prob)), scale)
    draw_curve(strip, columns, y_of(np.where(np.isfinite(corner_prob), corner_prob, 0.0)), PREDICTION_COLOUR)
    draw_ticks(strip, panorama.corner_columns, scale, 0, 5, LABEL_COLOUR)
    draw_ticks(strip, peaks, scale, STRIP_HEIGHT - 5, STRIP_HEIGHT, PREDICTION_COLOUR)
    return strip


def contact_tile(
    panorama: LabelledPanorama,
    image: np.ndarray,
    prediction: tuple[np.ndarray, ...],
    peaks: np.ndarray,
    scores: dict,
    corner_threshold: float,
) -> np.ndarray:
    """One panorama of the contact sheet (RGB): caption, downscaled image with both boundaries, probability strip
    (``corner_threshold``: the peak threshold drawn on it)."""
    ceiling_v, floor_v, corner_prob = prediction
    scale = TILE_WIDTH / panorama.width
    tile = cv2.resize(image, (TILE_WIDTH, TILE_WIDTH // 2), interpolation=cv2.INTER_AREA)
    for rows in (panorama.ceiling_v, panorama.floor_v):
        draw_rows(tile, rows, scale, LABEL_COLOUR)
    for rows in (ceiling_v, floor_v):
        draw_rows(tile, rows, scale, PREDICTION_COLOUR)
    draw_ticks(tile, panorama.corner_columns, scale, 0, 8, LABEL_COLOUR)
    draw_ticks(tile, panorama.occluded_columns, scale, 0, 8, OCCLUDED_COLOUR)
    draw_ticks(tile, peaks, scale, TILE_WIDTH // 2 - 9, TILE_WIDTH // 2 - 1, PREDICTION_COLOUR)
    caption = np.zeros((CAPTION_HEIGHT, TILE_WIDTH, 3), np.uint8)
    text = (
        f"{panorama.name[-CAPTION_NAME_LENGTH:]}  ceil {scores['ceiling_error_px']:.1f} floor "
        f"{scores['floor_error_px']:.1f} px  corners {scores['predicted_corners']}/{scores['label_corners']}  "
        f"IoU3D {scores['iou_3d']:.2f}"
    )
    cv2.putText(caption, text, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.37, (255, 255, 255), 1, cv2.LINE_AA)
    strip = probability_strip(corner_prob, panorama, peaks, scale, corner_threshold)
    return np.vstack([caption, tile, strip, np.zeros((4, TILE_WIDTH, 3), np.uint8)])


def contact_sheet_png(tiles: list[np.ndarray], columns: int = 2) -> bytes:
    """The tiles in a grid of ``columns``, PNG-encoded."""
    tiles = tiles + [np.zeros_like(tiles[0])] * (-len(tiles) % columns)
    grid = np.vstack([np.hstack(tiles[i : i + columns]) for i in range(0, len(tiles), columns)])
    ok, encoded = cv2.imencode(".png", grid[..., ::-1])
    if not ok:
        raise OSError("could not encode the contact sheet")
    return encoded.tobytes()
