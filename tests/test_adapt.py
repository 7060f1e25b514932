"""Test-time adaptation to a panorama's flat floor and ceiling (ncjax.network.adapt): the loss against the geometry
of exact rows, and the adaptation lowering it on the demo panorama without touching the model it copies."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx
from test_app import demo_image

from ncjax import programs
from ncjax.geometry.camera import NonCentralPanorama, elevation_to_row, point_to_angles
from ncjax.network.adapt import ADAPTED, adapt_to_panorama
from ncjax.network.config import AdaptConfig
from ncjax.network.flatness import flatness_loss, huber_loss, row_flatness
from ncjax.network.predict import default_model, network_input, predict_boundaries
from ncjax.network.weights import DEFAULT_MODEL_PATH, read_weights
from ncjax.reconstruction import _check_batch_settings, adaptation_key, reconstruct_batch


def _box_room_elevations(ceiling_height: float, floor_height: float, width: int = 256):
    """The exact ceiling and floor elevations per column of a 4 x 3 m box room seen from (0.5, -0.3) (central)."""
    azimuth = np.linspace(-np.pi, np.pi, width, endpoint=False)
    direction = np.stack([np.cos(azimuth), np.sin(azimuth)], -1)
    camera, half = np.array([0.5, -0.3]), np.array([2.0, 1.5])
    # distance to the box's wall along each column's direction
    with np.errstate(divide="ignore"):
        steps = np.where(direction != 0, (np.sign(direction) * half - camera) / direction, np.inf)
    distance = steps.min(axis=-1)
    return jnp.arctan2(ceiling_height, distance), jnp.arctan2(-floor_height, distance)


def test_flat_rows_cost_nothing_and_a_doorway_costs_in_proportion():
    ceiling, floor = _box_room_elevations(1.1, 1.5)
    assert float(flatness_loss(ceiling, floor, 0.05)) == pytest.approx(0.0, abs=1e-10)
    # rows of another room of the same shape and heights' ratio: still flat
    assert float(flatness_loss(*_box_room_elevations(2.2, 3.0), 0.05)) == pytest.approx(0.0, abs=1e-10)
    # the floor row of 32 columns through a doorway, 1.5 m further away: the loss grows with the stretch
    far = jnp.arctan2(-1.5, 1.5 / jnp.tan(-floor) + 1.5)
    losses = [float(flatness_loss(ceiling, floor.at[:n].set(far[:n]), 0.05)) for n in (16, 32)]
    assert 0 < losses[0] < losses[1]
    # its gradient moves those floor rows back towards the wall (lower: more negative elevation), the others not
    grad = jax.grad(lambda f: flatness_loss(ceiling, f, 0.05))(floor.at[:32].set(far[:32]))
    assert np.all(np.asarray(grad[:32]) > 0) and np.allclose(np.asarray(grad[64:]), 0.0, atol=1e-7)


@pytest.mark.parametrize("rc", [0.0, 0.3])
def test_the_walls_foot_and_top_cost_nothing_for_the_rig_too(rc):
    # a column's rays leave one optical centre at one azimuth (the paper's forward projection, point_to_angles), so
    # it sees its wall's foot and top at one distance whatever rc: points along an off-centre box room's walls
    corners = np.array([[3.0, -1.2], [3.0, 2.0], [-1.5, 2.0], [-1.5, -1.2]])
    along = np.linspace(0.0, 1.0, 64, endpoint=False)[:, None]
    plan = np.concatenate([a + along * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True)])
    cam = NonCentralPanorama(width=256, height=128, rc=rc)
    ceiling = point_to_angles(cam, jnp.asarray(np.c_[plan, np.full(len(plan), 1.1)]))[1]
    floor = point_to_angles(cam, jnp.asarray(np.c_[plan, np.full(len(plan), -1.5)]))[1]
    assert float(flatness_loss(ceiling, floor, 0.05)) == pytest.approx(0.0, abs=1e-9)
    # the floor of a quarter of them 0.02 rad lower (a floor row through a doorway, say) is not flat
    assert float(flatness_loss(ceiling, floor.at[: len(plan) // 4].add(-0.02), 0.05)) > 1e-4


def test_huber_loss_is_optaxs():
    x = jnp.linspace(-0.2, 0.2, 81)
    np.testing.assert_allclose(huber_loss(x, 0.05), optax.huber_loss(x, delta=0.05), rtol=1e-6, atol=1e-9)


def test_row_flatness_is_the_loss_of_the_rows_elevations():
    ceiling, floor = _box_room_elevations(1.1, 1.5)
    height = 128
    rows = [elevation_to_row(e, height) for e in (ceiling, floor)]
    assert float(row_flatness(*rows, height, 0.05)) == pytest.approx(0.0, abs=1e-8)
    # a doorway's 32 floor rows 6 px lower: the rows' loss is their elevations' (the rows' own map, docs/design.md)
    lowered = rows[1].at[:32].add(6.0)
    elevation = -np.pi / 2 + np.pi * (height - np.asarray(lowered) - 0.5) / height  # rows grow downwards
    want = float(flatness_loss(ceiling, jnp.asarray(elevation), 0.05))
    assert float(row_flatness(rows[0], lowered, height, 0.05)) == pytest.approx(want, rel=1e-4) and want > 1e-4


def test_the_backbones_batch_norm_scales_and_offsets_are_what_adapts():
    model = default_model()
    adapted = {
        jax.tree_util.keystr(path) for path, _ in jax.tree_util.tree_flatten_with_path(nnx.state(model, ADAPTED))[0]
    }
    norms = [module for path, module in nnx.iter_graph(model.backbone) if isinstance(module, nnx.BatchNorm)]
    assert len(adapted) == 2 * len(norms) > 0  # a scale and an offset each, nothing else
    assert all("['backbone']" in path and "['norm']" in path for path in adapted)


def test_the_adaptation_program_is_keyed_by_its_traced_settings_alone():
    weights = read_weights(DEFAULT_MODEL_PATH)
    same = (AdaptConfig(), AdaptConfig(min_loss=0.0, max_rc=np.inf), AdaptConfig(learning_rate=np.float64(1e-3)))
    keys = {adaptation_key(weights, config) for config in same}
    assert len(keys) == 1 and adaptation_key(weights, AdaptConfig(steps=2)) not in keys
    # the package ships it for 1024 x 512, whichever panoramas a run adapts
    image_like = jax.ShapeDtypeStruct((1, 512, 1024, 3), jnp.uint8)
    assert programs.program_path(programs.SHIPPED_DIRECTORY, keys.pop(), (weights.tensors, image_like)).exists()


def test_configuration_rejects_bad_values():
    bad_values = ({"steps": 0}, {"learning_rate": 0.0}, {"huber": -1.0}, {"min_loss": -1e-3}, {"min_loss": np.nan})
    for bad in (*bad_values, {"max_rc": -0.1}):
        with pytest.raises(ValueError):
            AdaptConfig(**bad)
    images = np.zeros((1, 64, 128, 3), np.uint8)
    with pytest.raises(TypeError):  # the tests' type checker says so first, the function's own check without it
        reconstruct_batch(images, np.zeros(1, np.float32), adapt=True)
    with pytest.raises(TypeError, match="AdaptConfig or None"):
        _check_batch_settings(images, "auto", 4, 1, adapt=True)


@pytest.mark.slow
def test_adaptation_lowers_the_loss_on_the_demo_and_leaves_the_model_it_copies():
    image = np.ascontiguousarray(demo_image())
    model = default_model()
    before = jax.tree.map(np.asarray, nnx.state(model, ADAPTED))
    adapted, losses = adapt_to_panorama(model, image, AdaptConfig(steps=2))

    # the loss before each step; the first is the model's own, in eval mode (running statistics, no dropout), on
    # the network's input, and the adapted copy's own is lower than the loss before the last step
    def own_loss(network):
        network.eval()
        prediction = network(network_input(network, jnp.asarray(image)[None])[1])
        return float(flatness_loss(prediction.ceiling_elevation[0], prediction.floor_elevation[0], AdaptConfig().huber))

    assert len(losses) == 2 and losses[0] == pytest.approx(own_loss(model), rel=1e-4)
    assert own_loss(adapted) < losses[1] < losses[0]
    after = jax.tree.map(np.asarray, nnx.state(model, ADAPTED))
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after), strict=True))
    changed = jax.tree.leaves(jax.tree.map(np.asarray, nnx.state(adapted, ADAPTED)))
    assert any(not np.array_equal(a, b) for a, b in zip(jax.tree.leaves(before), changed, strict=True))
    frozen = [nnx.state(m, nnx.Not(ADAPTED)) for m in (model, adapted)]
    assert all(np.array_equal(a, b) for a, b in zip(*(jax.tree.leaves(f) for f in frozen), strict=True))


@pytest.mark.slow
@pytest.mark.parametrize("program_cache", [True, False])
def test_reconstruct_reads_each_panorama_with_the_network_adapted_to_it(program_cache):
    """``reconstruct_batch(adapt=...)``: the rows the geometry gets are the adapted network's (through the saved
    network program, with the adapted parameters as its arguments, or jitted in the process), not the shipped
    one's, where the shipped network's rows are less flat than ``min_loss`` asks; else the shipped network's."""
    image = np.ascontiguousarray(demo_image())
    config = AdaptConfig(steps=2, min_loss=0.0, max_rc=np.inf)
    adapted, _ = adapt_to_panorama(default_model(), image, config)
    expected = predict_boundaries(image, adapted)
    result = reconstruct_batch(image[None], np.array([0.68], np.float32), program_cache=program_cache, adapt=config)
    assert result.adapted.tolist() == [True]
    for got, want in zip((result.ceiling_v, result.floor_v, result.corner_prob), expected, strict=True):
        np.testing.assert_allclose(np.asarray(got[0]), want, atol=2e-3)
    shipped = predict_boundaries(image)
    moved = [
        np.abs(np.asarray(got[0]) - own).max()
        for got, own in zip((result.ceiling_v, result.floor_v), shipped[:2], strict=True)
    ]
    assert max(moved) > 0.05, moved
    # rows as flat as the demo's (a render's) are read as they are, unless min_loss is at most their flatness loss
    flatness = float(row_flatness(jnp.asarray(shipped[0]), jnp.asarray(shipped[1]), image.shape[0], config.huber))
    # and a panorama of the rig (rc 0.68) only where max_rc allows it
    cases = ((1.01 * flatness, np.inf, False), (0.99 * flatness, np.inf, True), (0.0, 0.5, False), (0.0, 0.68, True))
    for min_loss, max_rc, adapts in cases:
        gated = dataclasses.replace(config, min_loss=min_loss, max_rc=max_rc)
        result = reconstruct_batch(image[None], np.array([0.68], np.float32), program_cache=program_cache, adapt=gated)
        assert result.adapted.tolist() == [adapts]
        want = expected if adapts else shipped
        np.testing.assert_allclose(np.asarray(result.floor_v[0]), want[1], atol=2e-3)
