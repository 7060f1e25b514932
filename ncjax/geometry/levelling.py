"""Gravity alignment of tilted panoramas: estimate the roll and pitch, level the image, map results back.

Frames: see :mod:`ncjax.geometry.gravity`. ``rotation`` takes the input
camera's frame to the levelled frame (z along the true vertical), ``p_level = rotation @ p_input``;
roll and pitch are the camera's rotations about its x axis (the centre column) and its y axis
(azimuth +90 degrees), ``rotation = Ry(pitch) @ Rx(roll)``.

Estimation (:func:`estimate_tilt`): the panorama is cut into perspective views (several
yaws at a few elevations), straight segments are found in each with OpenCV's line segment
detector, and each segment is lifted to the normal of its great circle on the sphere.
Segments of vertical lines have normals orthogonal to the vertical, so the vertical is the
direction most orthogonal to the normals of the near-vertical segments: RANSAC over pairs
of normals (seeded, so the result is deterministic), then least squares (the smallest
eigenvector of the weighted sum of ``n n^T`` over the inliers). Where too few segments
agree, or they do not constrain the vertical in two directions, or chance explains their
agreement, the estimate is flagged unreliable and the identity rotation is returned.

Use (a layout found on the levelled image expressed in the input image; ``to_input_frame`` and
``direction_to_pixel`` are :mod:`ncjax.geometry.gravity`'s):

    estimate = estimate_tilt(image)
    levelled = level_panorama(image, estimate.rotation)
    layout = ncjax.reconstruct(levelled, ncjax.NonCentralPanorama(W, H, rc=0.0))
    corners = to_input_frame(np.asarray(layout.ceiling_corners), estimate.rotation)
    u, v = direction_to_pixel(corners, W, H)   # the corners in the input image's pixels

Only central panoramas are levelled exactly: a tilted non-central camera's circle of optical
centres leaves the horizontal plane, which no resampling of the image undoes. It leaves it by at
most ``rc`` times the tilt, so the resampled image of a tilted rig is that of a level one to about
``rc / range`` of the tilt, where the tilt itself moves its rows by the whole angle
(experiments/rig_tilt.py: at 1 degree, the room height's median error 3.1% tilted, 0.2% levelled).
The estimate reads a rig's panorama as a central one: a vertical line falls in one column of both.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import cv2
import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Shaped

from .gravity import (
    _check_size,
    direction_to_pixel,
    level_to_input_pixels,
    panorama_size_error,
    rotation_from_tilt,
    tilt_from_up,
)


@dataclasses.dataclass(frozen=True)
class TiltConfig:
    """Settings of :func:`estimate_tilt` (frozen, hashable).

    Attributes:
        working_width: the panorama is shrunk (pixel-area averaging) to at most this many
            columns before the views are cut; the views' focal length matches its resolution.
        yaws: number of perspective views per elevation, evenly spread in azimuth.
        elevations: elevations of the views' optical axes, degrees.
        field_of_view: horizontal and vertical field of view of each square view, degrees.
        min_segment: shortest segment kept, degrees of arc on the sphere.
        max_tilt: largest tilt (angle between the image's and the true vertical) searched, degrees.
        inlier_angle: a segment supports a vertical when its great circle passes within this
            angle of it, degrees.
        iterations: RANSAC pairs tried (fewer when there are fewer pairs).
        min_segments: fewest supporting segments of a reliable estimate.
        min_spread: smallest ratio of the middle to the largest eigenvalue of the supporting
            normals' scatter of a reliable estimate (the vertical lines must be seen in more
            than one direction).
        significance: a reliable vertical must be supported by more segments than chance
            explains: the expected number of equally supported verticals among RANSAC's
            candidates, were the segments' directions random (a-contrario), must be at most
            ``10 ** -significance``.
        seed: seed of RANSAC's random generator.
    """

    working_width: int = 1024
    yaws: int = 8
    elevations: tuple[float, ...] = (-30.0, 0.0, 30.0)
    field_of_view: float = 90.0
    min_segment: float = 2.0
    max_tilt: float = 20.0
    inlier_angle: float = 0.5
    iterations: int = 1000
    min_segments: int = 6
    min_spread: float = 0.05
    significance: float = 3.0
    seed: int = 0

    def __post_init__(self):
        if int(self.working_width) != self.working_width or self.working_width < 64 or self.working_width % 2:
            raise ValueError(f"working_width must be an even integer >= 64, got {self.working_width!r}")
        if int(self.yaws) != self.yaws or self.yaws < 1:
            raise ValueError(f"yaws must be a positive integer, got {self.yaws!r}")
        if not self.elevations or any(not -80.0 <= e <= 80.0 for e in self.elevations):
            raise ValueError(f"elevations must be angles in [-80, 80] degrees, at least one, got {self.elevations!r}")
        if not 10.0 <= self.field_of_view <= 150.0:
            raise ValueError(f"field_of_view must be in [10, 150] degrees, got {self.field_of_view!r}")
        if not 0.0 < self.max_tilt < 60.0:
            raise ValueError(f"max_tilt must be in (0, 60) degrees, got {self.max_tilt!r}")
        if not 0.0 < self.inlier_angle < self.max_tilt:
            raise ValueError(f"inlier_angle must be in (0, max_tilt) degrees, got {self.inlier_angle!r}")
        if self.min_segment < 0.0:
            raise ValueError(f"min_segment must be >= 0 degrees, got {self.min_segment!r}")
        if int(self.iterations) != self.iterations or self.iterations < 1:
            raise ValueError(f"iterations must be a positive integer, got {self.iterations!r}")
        if int(self.min_segments) != self.min_segments or self.min_segments < 2:
            raise ValueError(f"min_segments must be an integer >= 2, got {self.min_segments!r}")
        if self.significance < 0.0:
            raise ValueError(f"significance must be >= 0, got {self.significance!r}")
        if not 0.0 <= self.min_spread < 1.0:
            raise ValueError(f"min_spread must be in [0, 1), got {self.min_spread!r}")


@dataclasses.dataclass(frozen=True)
class GravityEstimate:
    """The tilt of a panorama (:func:`estimate_tilt`).

    Attributes:
        roll: rotation of the camera about its x axis (the centre column's direction), degrees.
        pitch: rotation of the camera about its y axis (azimuth +90 degrees), degrees.
        rotation: (3, 3) rotation taking input-frame coordinates to the levelled frame,
            ``Ry(pitch) @ Rx(roll)``; the identity when the estimate is not reliable.
        up: (3,) the true vertical in the input frame (``rotation[2]``).
        segments: number of line segments supporting the vertical.
        reliable: whether enough segments, in more than one direction and more than chance
            explains, support it; when False, ``roll`` and ``pitch`` are 0 and ``rotation`` is
            the identity.
    """

    roll: float
    pitch: float
    rotation: Float[np.ndarray, "3 3"]
    up: Float[np.ndarray, 3]
    segments: int
    reliable: bool


# ----------------------------------------------------------------- resampling

_REMAP_DTYPES = (np.uint8, np.uint16, np.int16, np.float32, np.float64)
_INTERPOLATIONS = {"bilinear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST}


def _pad_sphere(image: np.ndarray) -> np.ndarray:
    """The panorama with one more column on each side (wrapped) and one more row at each pole (continued
    over the pole: the row above row 0 at column u is row 0 at column u + W/2)."""
    half = image.shape[1] // 2
    padded = np.concatenate([np.roll(image[:1], half, axis=1), image, np.roll(image[-1:], half, axis=1)], axis=0)
    return np.concatenate([padded[:, -1:], padded, padded[:, :1]], axis=1)


def level_panorama(
    image: Shaped[np.ndarray, "H W *channels"],
    rotation: Float[ArrayLike, "3 3"],
    interpolation: str = "bilinear",
) -> Shaped[np.ndarray, "H W *channels"]:
    """Resample an equirectangular panorama so that its vertical is the levelled frame's z axis.

    Pixel (u, v) of the result shows what the input shows at :func:`level_to_input_pixels`
    ``(u, v)``; interpolation wraps around in azimuth and continues over the poles.
    ``level_panorama(levelled, rotation.T)`` tilts a levelled image back.

    Args:
        image: (H, W) or (H, W, C) panorama, W = 2 H, C <= 4; uint8, uint16, int16,
            float32 or float64.
        rotation: the input -> levelled rotation (:attr:`GravityEstimate.rotation`).
        interpolation: "bilinear" (images) or "nearest" (label maps).

    Returns:
        The levelled panorama, same shape and dtype.

    Raises:
        ValueError: the image is not a 2:1 panorama of a supported type, or ``rotation`` is
            not a rotation matrix.
    """
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and not 1 <= image.shape[2] <= 4):
        raise ValueError(f"image must be (H, W) or (H, W, C) with C <= 4, got shape {image.shape}")
    if image.dtype.type not in _REMAP_DTYPES:
        raise ValueError(f"unsupported image type {image.dtype} (uint8, uint16, int16, float32 or float64)")
    height, width = image.shape[:2]
    _check_size(width, height)
    if interpolation not in _INTERPOLATIONS:
        raise ValueError(f"interpolation must be 'bilinear' or 'nearest', got {interpolation!r}")
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float64)
    source_u, source_v = level_to_input_pixels(columns, rows, rotation, width, height)
    padded = _pad_sphere(image)
    levelled = cv2.remap(
        padded,
        (source_u + 1.0).astype(np.float32),
        (source_v + 1.0).astype(np.float32),
        _INTERPOLATIONS[interpolation],
        borderMode=cv2.BORDER_REPLICATE,
    )
    return levelled.reshape(image.shape)


# ----------------------------------------------------------------- segments on the sphere


@functools.lru_cache(maxsize=8)
def _views(width: int, config: TiltConfig) -> tuple[int, float, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """The perspective views cut from a ``width`` x ``width / 2`` panorama: (size, focal, [(basis, map_u, map_v)]).

    ``basis`` (3 x 3) has the view's right, down and forward axes as columns (panorama frame),
    so a view pixel (x, y) looks along ``basis @ (x - c, y - c, focal)``, c the view's centre.
    """
    focal = width / (2.0 * math.pi)  # the panorama's pixels per radian
    size = max(16, int(round(2.0 * focal * math.tan(math.radians(config.field_of_view) / 2.0))))
    centre = (size - 1) / 2.0
    ys, xs = np.mgrid[0:size, 0:size].astype(np.float64)
    local = np.stack([xs - centre, ys - centre, np.full_like(xs, focal)], axis=-1)
    views = []
    for elevation in config.elevations:
        for k in range(config.yaws):
            basis = _view_basis(2.0 * math.pi * k / config.yaws, math.radians(elevation))
            u, v = direction_to_pixel(local @ basis.T, width, width // 2)
            views.append((basis, (u + 1.0).astype(np.float32), (v + 1.0).astype(np.float32)))
    return size, focal, views


def _view_basis(yaw: float, elevation: float) -> np.ndarray:
    forward = np.array([math.cos(elevation) * math.cos(yaw), math.cos(elevation) * math.sin(yaw), math.sin(elevation)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])  # azimuth decreases to the right
    return np.stack([right, np.cross(forward, right), forward], axis=1)


def segment_normals(
    image: Shaped[np.ndarray, "H W 3"], config: TiltConfig = TiltConfig()
) -> tuple[Float[np.ndarray, "N 3"], Float[np.ndarray, " N"]]:
    """Straight segments of a panorama as unit normals of their great circles, with their lengths.

    The panorama (RGB uint8, W = 2 H) is shrunk to ``config.working_width`` columns at most,
    cut into perspective views, and OpenCV's line segment detector runs on each view.

    Returns:
        ``(normals, lengths)``: (N, 3) unit normals in the panorama's frame and (N,) arc
        lengths in radians, segments shorter than ``config.min_segment`` left out.

    Raises:
        ValueError: the image is not an RGB uint8 2:1 panorama.
    """
    image = _check_panorama(image)
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    if grey.shape[1] > config.working_width:
        grey = cv2.resize(grey, (config.working_width, config.working_width // 2), interpolation=cv2.INTER_AREA)
    size, focal, views = _views(grey.shape[1], config)
    padded = _pad_sphere(grey)
    detector = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD)
    centre = (size - 1) / 2.0
    normals, lengths = [np.zeros((0, 3))], [np.zeros(0)]
    for basis, map_u, map_v in views:
        view = cv2.remap(padded, map_u, map_v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        lines = detector.detect(view)[0]
        if lines is None:
            continue
        lines = lines.reshape(-1, 4).astype(np.float64)
        # LSD gives coordinates with the origin at the centre of pixel (0, 0), as the views do.
        ends = np.stack([lines[:, 0:2], lines[:, 2:4]], axis=1) - centre  # (n, 2 ends, 2)
        rays = np.concatenate([ends, np.full(ends.shape[:2] + (1,), focal)], axis=-1) @ basis.T
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        normal = np.cross(rays[:, 0], rays[:, 1])
        sine = np.linalg.norm(normal, axis=-1)
        length = np.arctan2(sine, np.sum(rays[:, 0] * rays[:, 1], axis=-1))
        keep = (length >= math.radians(config.min_segment)) & (sine > 0)
        normals.append(normal[keep] / sine[keep, None])
        lengths.append(length[keep])
    return np.concatenate(normals), np.concatenate(lengths)


# ----------------------------------------------------------------- the vertical vanishing direction


def _oriented(direction: np.ndarray) -> np.ndarray:
    direction = direction / np.linalg.norm(direction, axis=-1, keepdims=True)
    return np.where(direction[..., 2:3] < 0, -direction, direction)


def _log10_binomial_tail(n: int, k: int, p: float) -> float:
    """log10 of the probability of at least k successes in n trials of probability p."""
    if k <= 0:
        return 0.0
    if k > n:
        return -math.inf
    j = np.arange(k, n + 1, dtype=np.float64)
    log_terms = (
        math.lgamma(n + 1)
        - np.array([math.lgamma(x + 1) for x in j])
        - np.array([math.lgamma(n - x + 1) for x in j])
        + j * math.log(p)
        + (n - j) * math.log1p(-p)
    )
    top = log_terms.max()
    return float((top + math.log(np.exp(log_terms - top).sum())) / math.log(10.0))


def _refine(normals: np.ndarray, weights: np.ndarray, up: np.ndarray, inlier_sine: float, rounds: int = 3):
    """Least-squares vertical from the normals near-orthogonal to ``up``: (up, inlier mask, scatter eigenvalues)."""
    eigenvalues = np.zeros(3)
    inliers = np.abs(normals @ up) < inlier_sine
    for _ in range(rounds):
        if inliers.sum() < 2:
            break
        chosen = normals[inliers]
        scatter = (chosen * weights[inliers, None]).T @ chosen
        eigenvalues, eigenvectors = np.linalg.eigh(scatter)  # ascending
        up = _oriented(eigenvectors[:, 0])
        inliers = np.abs(normals @ up) < inlier_sine
    return up, inliers, eigenvalues


def vertical_from_normals(
    normals: Float[ArrayLike, "N 3"], lengths: Float[ArrayLike, " N"], config: TiltConfig = TiltConfig()
) -> tuple[Float[np.ndarray, 3], Bool[np.ndarray, " N"], bool]:
    """The direction most orthogonal to the great-circle normals of near-vertical segments.

    RANSAC over pairs of normals (each pair's cross product is a candidate vertical within
    ``config.max_tilt`` of z; its score is the arc length of the segments passing within
    ``config.inlier_angle`` of it), then least squares over the inliers.

    Args:
        normals: (N, 3) unit normals of the segments' great circles (:func:`segment_normals`).
        lengths: (N,) the segments' arc lengths, radians (their weights).
        config: thresholds and the RANSAC seed.

    Returns:
        ``(up, inliers, reliable)``: the vertical (unit, z > 0; e_z when not reliable), the
        supporting segments and whether they are enough (``config.min_segments``), spread
        over more than one direction (``config.min_spread``) and more than chance explains
        (``config.significance``).

    Raises:
        ValueError: ``normals`` and ``lengths`` differ in length.
    """
    normals = np.asarray(normals, np.float64).reshape(-1, 3)
    lengths = np.asarray(lengths, np.float64).reshape(-1)
    if len(normals) != len(lengths):
        raise ValueError(f"normals and lengths must have the same length, got {len(normals)} and {len(lengths)}")
    identity = np.array([0.0, 0.0, 1.0])
    none = np.zeros(len(normals), bool)
    cos_tilt = math.cos(math.radians(config.max_tilt))
    # Near-vertical segments: their great circles pass within max_tilt (plus the inlier band) of the zenith.
    candidate = np.abs(normals[:, 2]) < math.sin(math.radians(config.max_tilt + config.inlier_angle))
    index = np.flatnonzero(candidate)
    if len(index) < 2:
        return identity, none, False
    n, w = normals[index], lengths[index]
    inlier_sine = math.sin(math.radians(config.inlier_angle))
    rng = np.random.default_rng(config.seed)
    pairs = len(index) * (len(index) - 1) // 2
    if pairs <= config.iterations:
        first, second = np.triu_indices(len(index), k=1)
    else:
        first = rng.integers(0, len(index), config.iterations)
        second = (first + rng.integers(1, len(index), config.iterations)) % len(index)
    cross = np.cross(n[first], n[second])
    sine = np.linalg.norm(cross, axis=-1)
    usable = sine > math.sin(math.radians(2.0 * config.inlier_angle))  # near-parallel pairs fix no vertical
    candidates = _oriented(cross[usable])
    candidates = candidates[candidates[:, 2] >= cos_tilt]
    if len(candidates) == 0:
        return identity, none, False
    scores = ((np.abs(n @ candidates.T) < inlier_sine) * w[:, None]).sum(axis=0)
    up = candidates[int(np.argmax(scores))]
    up, inliers, eigenvalues = _refine(n, w, up, inlier_sine)
    mask = none.copy()
    mask[index[inliers]] = True
    spread = eigenvalues[1] / eigenvalues[2] if eigenvalues[2] > 0 else 0.0
    # Chance of a segment in the candidate band passing within inlier_angle of a given vertical.
    chance = inlier_sine / math.sin(math.radians(config.max_tilt + config.inlier_angle))
    log10_nfa = math.log10(len(candidates)) + _log10_binomial_tail(len(index), int(inliers.sum()), chance)
    reliable = bool(
        mask.sum() >= config.min_segments
        and spread >= config.min_spread
        and log10_nfa <= -config.significance
        and up[2] >= cos_tilt
    )
    return (up if reliable else identity), mask, reliable


def _check_panorama(image) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"expected an RGB uint8 panorama (H, W, 3), got {image.dtype} {image.shape}")
    error = panorama_size_error(image.shape[1], image.shape[0])
    if error:
        raise ValueError(error)
    return image


def estimate_tilt(image: Shaped[np.ndarray, "H W 3"], config: TiltConfig = TiltConfig()) -> GravityEstimate:
    """Roll and pitch of a central equirectangular panorama from its vertical lines.

    Args:
        image: RGB uint8 panorama (H, W, 3), W = 2 H, H >= 32.
        config: settings of the segment detection and of RANSAC (seeded: the same image
            gives the same estimate).

    Returns:
        The :class:`GravityEstimate`; when too few segments agree on a vertical (a
        featureless image, a tilt beyond ``config.max_tilt``), ``reliable`` is False and the
        rotation is the identity.

    Raises:
        ValueError: the image is not an RGB uint8 2:1 panorama.
    """
    normals, lengths = segment_normals(image, config)
    up, inliers, reliable = vertical_from_normals(normals, lengths, config)
    if not reliable:
        return GravityEstimate(0.0, 0.0, np.eye(3), np.array([0.0, 0.0, 1.0]), int(inliers.sum()), False)
    roll, pitch = tilt_from_up(up)
    rotation = rotation_from_tilt(roll, pitch)
    return GravityEstimate(roll, pitch, rotation, rotation[2].copy(), int(inliers.sum()), True)
