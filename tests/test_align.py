"""Gravity alignment: frames and pixel maps, levelling, and the tilt estimated from a room's vertical lines."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import ncjax
from ncjax.geometry import gravity, levelling

# A box room around the camera: x, y, z extents in metres (floor 1.4 m below, ceiling 1.2 m above).
ROOM = np.array([[-2.3, 3.1], [-1.7, 2.6], [-1.4, 1.2]])
FACE_GREY = np.array([0.55, 0.62, 0.48, 0.70, 0.85, 0.35])  # -x, +x, -y, +y walls, floor, ceiling
FACE_TINT = np.array(
    [[1.0, 0.95, 0.9], [0.9, 1.0, 0.95], [0.95, 0.9, 1.0], [1.0, 1.0, 0.9], [0.9, 0.9, 1.0], [1, 1, 1]]
)


def _albedo(points: np.ndarray, face: np.ndarray) -> np.ndarray:
    """Grey level of the surfaces: walls of their own shades, a door, a window, panels, a picture, floor tiles."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    grey = FACE_GREY[face]
    grey = np.where((face == 1) & (y > 0.2) & (y < 1.1) & (z < 0.6), 0.25, grey)  # door
    window = (face == 3) & (x > -1.0) & (x < 0.5) & (z > -0.2) & (z < 0.8)
    grey = np.where(window, np.where(np.abs(x + 0.25) < 0.02, 0.6, 0.95), grey)  # window and its bar
    grey = np.where((face == 2) & (np.floor(x / 0.6) % 2 == 0), grey - 0.12, grey)  # wall panels
    grey = np.where((face == 0) & (y > -1.0) & (y < 0.0) & (z > 0.0) & (z < 0.7), 0.2, grey)  # picture
    tile = (np.abs(x / 0.5 - np.round(x / 0.5)) < 0.03) | (np.abs(y / 0.5 - np.round(y / 0.5)) < 0.03)
    return np.where((face == 4) & tile, 0.6, grey)  # floor tiles


@functools.cache
def room_panorama(roll: float = 0.0, pitch: float = 0.0, height: int = 256, noise: float = 2.0) -> np.ndarray:
    """RGB uint8 panorama of ROOM cast directly by a camera tilted by roll and pitch (2 x 2 rays per pixel, plus
    white noise of ``noise`` grey levels)."""
    width = 2 * height
    rotation = gravity.rotation_from_tilt(roll, pitch)
    rows, columns = np.mgrid[0:height, 0:width].astype(np.float64)
    colour = np.zeros((height, width, 3))
    for dv in (-0.25, 0.25):
        for du in (-0.25, 0.25):
            direction = gravity.pixel_to_direction(columns + du, rows + dv, width, height) @ rotation.T
            with np.errstate(divide="ignore"):
                distance = np.where(direction > 0, ROOM[:, 1] / direction, ROOM[:, 0] / direction)
            axis = np.argmin(distance, axis=-1)
            points = direction * np.take_along_axis(distance, axis[..., None], -1)
            positive = np.take_along_axis(direction, axis[..., None], -1)[..., 0] > 0
            face = np.where(axis == 2, np.where(positive, 5, 4), 2 * axis + positive)
            colour += _albedo(points, face)[..., None] * FACE_TINT[face]
    noise = np.random.default_rng(height).normal(0.0, noise, colour.shape)
    return np.clip(np.round(colour / 4 * 255 + noise), 0, 255).astype(np.uint8)


def circular_difference(a, b, period):
    return (np.asarray(a) - np.asarray(b) + period / 2) % period - period / 2


# ----------------------------------------------------------------- frames and pixel maps


def test_pixel_maps_follow_the_camera_conventions():
    cam = ncjax.NonCentralPanorama(64, 32, rc=0.0)
    u = np.array([0.0, 10.3, 31.5, 63.0, -0.5])
    v = np.array([0.0, 5.2, 15.5, 31.0, 20.0])
    np.testing.assert_allclose(
        gravity.pixel_to_direction(u, v, 64, 32), np.asarray(ncjax.geometry.pixel_to_ray(cam, u, v))[..., :3], atol=1e-6
    )
    points = np.array([[1.0, 0.0, 0.0], [0.3, -2.0, 0.7], [-1.0, 0.2, -0.4], [-1.0, -1e-9, 0.0]])
    expected = np.asarray(ncjax.geometry.project(cam, points))
    np.testing.assert_allclose(np.stack(gravity.direction_to_pixel(points, 64, 32)), expected, atol=1e-4)
    assert np.all(np.isnan(gravity.direction_to_pixel(np.zeros(3), 64, 32)))


def test_rotation_from_tilt_conventions():
    r, p = math.radians(7.0), math.radians(-4.0)
    roll_only = gravity.rotation_from_tilt(7.0, 0.0)
    np.testing.assert_allclose(roll_only @ [1.0, 0, 0], [1, 0, 0], atol=1e-15)  # about x
    np.testing.assert_allclose(roll_only @ [0, 1.0, 0], [0, math.cos(r), math.sin(r)], atol=1e-15)
    pitch_only = gravity.rotation_from_tilt(0.0, -4.0)
    np.testing.assert_allclose(pitch_only @ [0, 1.0, 0], [0, 1, 0], atol=1e-15)  # about y
    np.testing.assert_allclose(pitch_only @ [1.0, 0, 0], [math.cos(p), 0, -math.sin(p)], atol=1e-15)
    rotation = gravity.rotation_from_tilt(7.0, -4.0)
    up = [-math.sin(p), math.cos(p) * math.sin(r), math.cos(p) * math.cos(r)]
    np.testing.assert_allclose(rotation[2], up, atol=1e-15)
    np.testing.assert_allclose(rotation @ up, [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(gravity.tilt_from_up(up), (7.0, -4.0), atol=1e-12)


angles = st.floats(-80.0, 80.0, allow_nan=False)


@given(angles, angles)
def test_tilt_from_up_inverts_rotation_from_tilt(roll, pitch):
    np.testing.assert_allclose(
        gravity.tilt_from_up(gravity.rotation_from_tilt(roll, pitch)[2]), (roll, pitch), atol=1e-9
    )


def general_rotation(roll, pitch, yaw):
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ gravity.rotation_from_tilt(roll, pitch)


@given(angles, angles, st.floats(-180.0, 180.0), st.floats(-0.5, 127.49), st.floats(-0.45, 63.45))
def test_frame_and_pixel_maps_are_inverse(roll, pitch, yaw, u, v):
    rotation = general_rotation(roll, pitch, yaw)
    point = np.array([u - 60.0, v - 30.0, 0.37 * u])
    np.testing.assert_allclose(
        gravity.to_input_frame(gravity.to_level_frame(point, rotation), rotation), point, atol=1e-9
    )
    np.testing.assert_allclose(
        gravity.to_level_frame(gravity.to_input_frame(point, rotation), rotation), point, atol=1e-9
    )
    for forward, backward in (
        (gravity.input_to_level_pixels, gravity.level_to_input_pixels),
        (gravity.level_to_input_pixels, gravity.input_to_level_pixels),
    ):
        there = forward(u, v, rotation, 128, 64)
        assert -0.5 <= there[0] < 127.5 and -0.5 <= there[1] <= 63.5
        back_u, back_v = backward(*there, rotation, 128, 64)
        assert abs(circular_difference(back_u, u, 128)) < 1e-6 and abs(back_v - v) < 1e-6


def test_layout_corners_map_to_the_input_image():
    """A point of the levelled frame is seen in the input image where the levelled image's pixel of it maps to."""
    rotation = general_rotation(6.0, -8.0, 30.0)
    corners = np.array([[3.1, 2.6, 1.2], [-2.3, 2.6, -1.4], [-2.3, -1.7, 1.2], [3.1, -1.7, -1.4]])
    level_u, level_v = gravity.direction_to_pixel(corners, 512, 256)
    input_u, input_v = gravity.direction_to_pixel(gravity.to_input_frame(corners, rotation), 512, 256)
    mapped_u, mapped_v = gravity.level_to_input_pixels(level_u, level_v, rotation, 512, 256)
    np.testing.assert_allclose(circular_difference(mapped_u, input_u, 512), 0.0, atol=1e-9)
    np.testing.assert_allclose(mapped_v, input_v, atol=1e-9)


# ----------------------------------------------------------------- levelling


def test_identity_and_yaw_resampling_are_exact():
    image = np.random.default_rng(0).integers(0, 256, (32, 64, 3)).astype(np.uint8)
    np.testing.assert_array_equal(levelling.level_panorama(image, np.eye(3)), image)
    # A rotation about z by one column's azimuth shifts the columns by one, wrapping around.
    step = 360.0 / 64
    yaw = general_rotation(0.0, 0.0, step)
    np.testing.assert_array_equal(levelling.level_panorama(image, yaw), np.roll(image, -1, axis=1))
    labels = np.random.default_rng(1).integers(0, 5, (32, 64)).astype(np.uint8)
    np.testing.assert_array_equal(levelling.level_panorama(labels, yaw, "nearest"), np.roll(labels, -1, axis=1))
    values = image[..., 0].astype(np.float32)
    np.testing.assert_array_equal(levelling.level_panorama(values, yaw.T), np.roll(values, 1, axis=1))


def test_half_turn_about_x_swaps_the_poles():
    image = np.random.default_rng(2).integers(0, 256, (16, 32)).astype(np.float32)
    # (x, y, z) -> (x, -y, -z): azimuth a -> -a (column u -> W - 1 - u), elevation e -> -e (row v -> H - 1 - v)
    np.testing.assert_allclose(
        levelling.level_panorama(image, gravity.rotation_from_tilt(180.0, 0.0)), image[::-1, ::-1]
    )


@pytest.mark.parametrize("roll, pitch", [(10.0, -10.0), (3.0, 4.0), (25.0, 0.0)])
def test_interpolation_wraps_in_azimuth_and_continues_over_the_poles(roll, pitch):
    """A function linear in the direction is resampled to within bilinear interpolation's error everywhere,
    the rows next to the poles and the columns next to the seam included (padding by repeating the edge
    pixels instead errs by 0.03-0.05 there)."""
    rows, columns = np.mgrid[0:16, 0:32].astype(np.float64)
    directions = gravity.pixel_to_direction(columns, rows, 32, 16)
    weights = np.array([0.3, -0.5, 0.8])
    rotation = gravity.rotation_from_tilt(roll, pitch)
    levelled = levelling.level_panorama((directions @ weights).astype(np.float32), rotation)
    np.testing.assert_allclose(levelled, gravity.to_input_frame(directions, rotation) @ weights, atol=0.012)


def _band(image: np.ndarray) -> np.ndarray:
    """Rows within 60 degrees of the horizon, as float."""
    height = image.shape[0]
    return image[height // 6 : height - height // 6].astype(np.float64)


def test_level_panorama_undoes_the_tilt():
    roll, pitch = 6.0, -8.0
    level, tilted = room_panorama(0.0, 0.0, noise=0.0), room_panorama(roll, pitch, noise=0.0)
    rotation = gravity.rotation_from_tilt(roll, pitch)
    levelled = levelling.level_panorama(tilted, rotation)
    error = np.abs(_band(levelled) - _band(level)).mean()
    before = np.abs(_band(tilted) - _band(level)).mean()
    wrong_way = np.abs(_band(levelling.level_panorama(tilted, rotation.T)) - _band(level)).mean()
    assert error < 2.0 < before / 2 and wrong_way > before
    # level_panorama(level, rotation.T) tilts: it matches the tilted camera's own image
    assert np.abs(_band(levelling.level_panorama(level, rotation.T)) - _band(tilted)).mean() < 2.0
    # levelled with the estimated rotation: as good
    estimated = levelling.level_panorama(tilted, levelling.estimate_tilt(tilted).rotation)
    assert np.abs(_band(estimated) - _band(level)).mean() < 2.0


def test_a_panorama_tilted_less_than_the_minimum_is_kept_and_its_tilt_recorded():
    from ncjax.cli.outputs import MIN_RIG_TILT, align_to_gravity

    tilted = room_panorama(0.06, 0.0, noise=0.0)  # under a rig's minimum: within the estimate's own error
    kept, record = align_to_gravity(tilted, MIN_RIG_TILT)
    assert kept is tilted and record["reliable"] and record["rotation"] is None
    assert math.hypot(record["roll_deg"], record["pitch_deg"]) < MIN_RIG_TILT  # recorded all the same
    levelled, record = align_to_gravity(tilted)  # a central panorama's: always levelled
    assert record["rotation"] is not None and not np.array_equal(levelled, tilted)
    steep = room_panorama(2.0, -1.0, noise=0.0)
    levelled, record = align_to_gravity(steep, MIN_RIG_TILT)
    assert record["rotation"] is not None and abs(record["roll_deg"] - 2.0) < 0.3


# ----------------------------------------------------------------- estimation


@pytest.mark.parametrize(
    "roll, pitch, height", [(0.0, 0.0, 256), (3.0, -2.0, 256), (-7.5, 6.0, 256), (10.0, -10.0, 256), (-4.0, 9.0, 512)]
)
def test_estimate_tilt_recovers_roll_and_pitch(roll, pitch, height):
    estimate = levelling.estimate_tilt(room_panorama(roll, pitch, height))
    assert estimate.reliable and estimate.segments >= levelling.TiltConfig().min_segments
    assert abs(estimate.roll - roll) < 0.3 and abs(estimate.pitch - pitch) < 0.3
    np.testing.assert_allclose(estimate.rotation, gravity.rotation_from_tilt(estimate.roll, estimate.pitch))
    np.testing.assert_allclose(estimate.up, estimate.rotation[2])


def test_estimate_tilt_is_deterministic():
    image = room_panorama(-7.5, 6.0)
    first, second = levelling.estimate_tilt(image), levelling.estimate_tilt(image)
    assert (first.roll, first.pitch, first.segments) == (second.roll, second.pitch, second.segments)
    np.testing.assert_array_equal(first.rotation, second.rotation)


@pytest.mark.parametrize("kind", ["constant", "smooth", "noise"])
def test_featureless_panorama_is_unreliable(kind):
    rng = np.random.default_rng(3)
    if kind == "constant":
        image = np.full((128, 256, 3), 90, np.uint8)
    elif kind == "smooth":  # brightness varying with elevation only: no straight edge anywhere
        image = np.repeat(np.linspace(40, 220, 128)[:, None, None], 256, axis=1).repeat(3, axis=2).astype(np.uint8)
    else:
        image = rng.integers(0, 256, (256, 512, 3)).astype(np.uint8)
    estimate = levelling.estimate_tilt(image)
    assert not estimate.reliable
    assert (estimate.roll, estimate.pitch) == (0.0, 0.0)
    np.testing.assert_array_equal(estimate.rotation, np.eye(3))
    np.testing.assert_array_equal(estimate.up, [0.0, 0.0, 1.0])


def normals_of_lines_through(up: np.ndarray, azimuths: np.ndarray) -> np.ndarray:
    """Unit normals of the great circles through ``up`` and the horizontal directions of ``azimuths`` (degrees)."""
    a = np.radians(azimuths)
    horizontal = np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], -1)
    normals = np.cross(up, horizontal)
    return normals / np.linalg.norm(normals, axis=-1, keepdims=True)


def test_vertical_from_normals_ignores_outliers():
    up = gravity.rotation_from_tilt(4.0, -3.0)[2]
    rng = np.random.default_rng(4)
    inliers = normals_of_lines_through(up, rng.uniform(-180, 180, 40))
    outliers = rng.normal(size=(60, 3))
    outliers /= np.linalg.norm(outliers, axis=-1, keepdims=True)
    normals = np.concatenate([inliers, outliers])
    found, mask, reliable = levelling.vertical_from_normals(normals, np.full(100, 0.2))
    assert reliable and mask[:40].all() and mask[40:].sum() < 5
    assert math.degrees(math.acos(min(1.0, float(found @ up)))) < 0.2


def test_vertical_from_normals_needs_lines_in_more_than_one_direction():
    up = gravity.rotation_from_tilt(4.0, -3.0)[2]
    normals = normals_of_lines_through(up, np.full(30, 40.0) + np.linspace(0, 0.5, 30))  # one wall edge, many times
    found, mask, reliable = levelling.vertical_from_normals(normals, np.full(30, 0.5))
    assert not reliable
    np.testing.assert_array_equal(found, [0.0, 0.0, 1.0])


def test_bad_input_is_a_value_error():
    with pytest.raises(ValueError, match="not a full 360 x 180 degree panorama"):
        levelling.estimate_tilt(np.zeros((100, 300, 3), np.uint8))
    with pytest.raises(ValueError, match="RGB uint8"):
        levelling.estimate_tilt(np.zeros((64, 128, 3), np.float32))
    with pytest.raises(ValueError, match="2:1"):
        levelling.level_panorama(np.zeros((64, 100, 3), np.uint8), np.eye(3))
    with pytest.raises(ValueError, match="C <= 4"):
        levelling.level_panorama(np.zeros((64, 128, 5), np.uint8), np.eye(3))
    with pytest.raises(ValueError, match="unsupported image type"):
        levelling.level_panorama(np.zeros((64, 128), np.int64), np.eye(3))
    with pytest.raises(ValueError, match="rotation matrix"):
        levelling.level_panorama(np.zeros((64, 128), np.uint8), 2 * np.eye(3))
    with pytest.raises(ValueError, match="rotation matrix"):
        gravity.to_input_frame(np.ones(3), np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="interpolation"):
        levelling.level_panorama(np.zeros((64, 128), np.uint8), np.eye(3), "cubic")
    with pytest.raises(ValueError, match="finite non-zero"):
        gravity.tilt_from_up(np.zeros(3))
    with pytest.raises(ValueError, match="max_tilt"):
        levelling.TiltConfig(max_tilt=90.0)


@pytest.mark.extended
def test_estimate_tilt_on_a_render(tmp_path):
    """A furnished room of the project's renderer (central, 256 x 512), tilted by resampling."""
    from ncjax.synth.dataset import rendered_samples, rendering_rgb8

    config = ncjax.SynthConfig(room=ncjax.RoomConfig(rc_range=(0.0, 0.0)), width=512, height=256)
    _, _, rendering, _ = next(rendered_samples(1, 5, config, batch_size=1))
    level = rendering_rgb8(rendering)
    for roll, pitch in ((5.0, -9.0), (-8.0, 2.5)):
        rotation = gravity.rotation_from_tilt(roll, pitch)
        estimate = levelling.estimate_tilt(levelling.level_panorama(level, rotation.T))
        assert estimate.reliable
        assert abs(estimate.roll - roll) < 0.3 and abs(estimate.pitch - pitch) < 0.3
