"""Layout metrics against hand-computed areas, volumes and distances."""

import math

import numpy as np
import pytest

import ncjax
from ncjax.evaluation import layout_metrics


def _layout(plan, ceiling=1.0, floor=-1.5):
    plan = np.asarray(plan, dtype=float)
    ones = np.ones((len(plan), 1))
    return {
        "ceiling_corners": np.concatenate([plan, ceiling * ones], 1),
        "floor_corners": np.concatenate([plan, floor * ones], 1),
    }


SQUARE = [[2, -2], [2, 2], [-2, 2], [-2, -2]]
L_SHAPE = [[2, -2], [2, 0], [0, 0], [0, 2], [-2, 2], [-2, -2]]


def test_identical_layouts_are_perfect():
    result = layout_metrics.evaluate_layout(_layout(L_SHAPE), _layout(L_SHAPE))
    assert result["iou3d"] == pytest.approx(1.0) and result["iou2d"] == pytest.approx(1.0)
    assert result["ce"] == pytest.approx(0.0) and result["height_error"] == pytest.approx(0.0)
    assert result["direction_error"] == pytest.approx(0.0, abs=1e-6) and result["depth_error"] == pytest.approx(0.0)


def test_shifted_square_by_hand():
    shifted = np.asarray(SQUARE) + [1.0, 0.0]
    # Overlap 3 x 4 = 12, union 16 + 16 - 12 = 20.
    assert layout_metrics.iou_2d(_layout(shifted), _layout(SQUARE)) == pytest.approx(0.6)
    assert layout_metrics.iou_3d(_layout(shifted), _layout(SQUARE)) == pytest.approx(0.6)
    ce, shift = layout_metrics.corner_error(_layout(shifted), _layout(SQUARE))
    assert ce == pytest.approx(1.0) and shift == 0


def test_heights_enter_the_3d_iou():
    taller = _layout(SQUARE, ceiling=1.5)
    assert layout_metrics.iou_3d(_layout(SQUARE), taller) == pytest.approx(2.5 / 3.0)
    result = layout_metrics.evaluate_layout(_layout(SQUARE), taller)
    assert result["height_error"] == pytest.approx(0.5) and result["ceiling_error"] == pytest.approx(0.5)
    assert result["floor_error"] == pytest.approx(0.0)


def test_non_convex_floor_plan():
    assert layout_metrics.iou_2d(_layout(L_SHAPE), _layout(SQUARE)) == pytest.approx(12 / 16)


def test_corner_matching_is_cyclic_and_counts_must_agree():
    rolled = _layout(np.roll(np.asarray(L_SHAPE), 2, axis=0))
    ce, shift = layout_metrics.corner_error(rolled, _layout(L_SHAPE))
    assert ce == pytest.approx(0.0) and shift == 2
    ce, shift = layout_metrics.corner_error(_layout(SQUARE), _layout(L_SHAPE))
    assert math.isnan(ce) and shift is None
    summary = layout_metrics.aggregate(
        [
            layout_metrics.evaluate_layout(_layout(SQUARE), _layout(L_SHAPE)),
            layout_metrics.evaluate_layout(_layout(SQUARE), _layout(SQUARE)),
        ]
    )
    assert summary["failure_rate"] == pytest.approx(0.5) and summary["ce"] == pytest.approx(0.0)


def test_up_to_scale_iou_removes_the_scale():
    gt = _layout(L_SHAPE)
    doubled = {key: 2.0 * value for key, value in gt.items()}
    assert layout_metrics.iou_3d(doubled, gt) == pytest.approx(1 / 8)
    assert layout_metrics.iou_3d(doubled, gt, up_to_scale=True) == pytest.approx(1.0)


def test_cen_and_line_errors():
    gt = _layout(SQUARE)
    moved = _layout(np.asarray(SQUARE) * 1.1)
    result = layout_metrics.evaluate_layout(moved, gt)
    diagonal = math.sqrt(4**2 + 4**2 + 2.5**2)
    assert result["cen"] == pytest.approx(result["ce"] / diagonal)
    assert result["direction_error"] == pytest.approx(0.0, abs=1e-6)
    # Ceiling lines at distance sqrt(2^2 + 1^2) vs sqrt(2.2^2 + 1^2); floor with 1.5.
    expected = np.mean([math.hypot(2.2, 1.0) - math.hypot(2, 1.0), math.hypot(2.2, 1.5) - math.hypot(2, 1.5)])
    assert result["depth_error"] == pytest.approx(expected)


@pytest.mark.slow
def test_room_and_labels_are_layouts():
    import jax

    config = ncjax.RoomConfig(occlusion="none", room_tries=1, camera_tries=16)
    room = jax.jit(ncjax.synth.random_room, static_argnums=1)(jax.random.key(0), config)
    labels = jax.jit(lambda r: ncjax.synth.room_labels(r, r.camera(128, 64)))(room)
    result = layout_metrics.evaluate_layout(labels, room)
    assert result["iou3d"] == pytest.approx(1.0, abs=1e-5) and result["ce"] == pytest.approx(0.0, abs=1e-5)


def test_bad_layouts_are_rejected():
    with pytest.raises(TypeError, match="not a layout"):
        layout_metrics.evaluate_layout(object(), _layout(SQUARE))
    with pytest.raises(ValueError, match="corners"):
        layout_metrics.evaluate_layout(
            {"ceiling_corners": np.zeros((4, 2)), "floor_corners": np.zeros((4, 2))}, _layout(SQUARE)
        )
