"""Non-central HorizonNet: shapes, wrap-awareness, parameter counts, loss, augmentations,
checkpoints, resume, Table netcorExp metrics, predict_boundaries.

One tiny configuration (ResNet-10, 64 x 128) is compiled once per jitted
function and shared by the tests (functools.cache); shape and parameter-count
tests only trace (nnx.eval_shape).
"""

import dataclasses
import functools
import itertools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

import ncjax
from ncjax import _network, _predict, _rooms, _train
from ncjax._checkpoint import load_checkpoint, load_weights, read_metadata, save_checkpoint
from ncjax._denoise import denoise_for_network
from ncjax._rooms import Room

TINY = ncjax.HorizonNetConfig(depth=10, width=8, input_height=64, input_width=128, lstm_hidden=16, lstm_layers=1, dropout=0.1)
TRAIN = ncjax.TrainConfig(peak_learning_rate=3e-3, warmup_steps=3, total_steps=40)
BATCH = 4


@functools.cache
def tiny_model():
    return ncjax.init_model(TINY, seed=0)


def convex_room(key, rc=0.5, n=6):
    """n corners around the camera at radii 2.5-3.5 m, evenly spaced counter-clockwise, randomly turned."""
    k_turn, k_radius = jax.random.split(key)
    angles = jax.random.uniform(k_turn, (), maxval=2 * jnp.pi) + jnp.arange(n) * (2 * jnp.pi / n)
    radii = jax.random.uniform(k_radius, (n,), minval=2.5, maxval=3.5)
    corners = radii[:, None] * jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)
    return Room(
        corners=corners,
        mask=jnp.ones(n, bool),
        ceiling_height=jnp.array(1.1),
        floor_height=jnp.array(-1.4),
        rc=jnp.array(rc),
        camera_position=jnp.array([0.0, 0.0, 1.4]),
        is_atlanta=jnp.array(True),
        status=jnp.array(0),
    )


@functools.cache
def painted_samples(count=8):
    """``count`` painted panoramas of convex rooms at TINY's size (cheap to compile)."""

    def one(key):
        k_room, k_colour = jax.random.split(key)
        room = convex_room(k_room)
        labels = ncjax.room_labels(room, room.camera(TINY.input_width, TINY.input_height))
        colours = jax.random.uniform(k_colour, (3, 3), minval=0.1, maxval=0.9)
        image = _train.paint_panorama(labels.ceiling_v, labels.floor_v, labels.wall_index, TINY.input_height, colours)
        return {"image": image, "ceiling_v": labels.ceiling_v, "floor_v": labels.floor_v, "corner_target": labels.corner_target}

    return jax.jit(jax.vmap(one))(jax.random.split(jax.random.PRNGKey(0), count))


def batches(start):
    """Deterministic batches: batch i is a fixed function of i (so resumes see the same data)."""
    samples = painted_samples()
    for i in itertools.count(start):
        index = (jnp.arange(BATCH) + BATCH * i) % samples["image"].shape[0]
        yield {k: v[index] for k, v in samples.items()}


def params_of(model):
    return {"/".join(map(str, p)): np.asarray(v.get_value()) for p, v in nnx.to_flat_state(nnx.state(model))}


# ----------------------------------------------------------------------------- architecture


@pytest.mark.parametrize("height, width", [(32, 64), (64, 128), (96, 160), (64, 256)])
def test_output_shapes_follow_input_shape(height, width):
    config = ncjax.HorizonNetConfig(depth=10, width=8, input_height=height, input_width=width, lstm_hidden=8)
    model = _network.abstract_model(config)
    model.eval()
    images = jax.ShapeDtypeStruct((2, height, width, 3), jnp.float32)
    features = nnx.eval_shape(lambda m, x: m.column_features(x), model, images)
    prediction = nnx.eval_shape(lambda m, x: m(x), model, images)
    assert features.shape == (2, width // 4, _network.column_feature_size(config))
    assert [p.shape for p in prediction] == [(2, width)] * 3


def test_config_validation():
    with pytest.raises(ValueError, match="multiples of 32"):
        ncjax.HorizonNetConfig(input_height=100)
    with pytest.raises(ValueError, match="depth"):
        ncjax.HorizonNetConfig(depth=101)
    with pytest.raises(ValueError, match="unknown preset"):
        ncjax.HorizonNetConfig.preset("huge")
    with pytest.raises(ValueError, match="corner_base"):
        ncjax.HorizonNetConfig(corner_base=1.0)
    config = ncjax.HorizonNetConfig.preset("compact")
    assert ncjax.HorizonNetConfig.from_json(config.to_json()) == config
    # Files written before corner_base existed hold HorizonNet's encoding.
    old_fields = {k: v for k, v in json.loads(config.to_json()).items() if k != "corner_base"}
    assert ncjax.HorizonNetConfig.from_json(json.dumps(old_fields)).corner_base == 0.96


def test_parameter_counts():
    # PyTorch HorizonNet (ResNet-50, 512 x 1024, LSTM 512) has 81,570,348 parameters:
    # ResNet-50 trunk 23,508,032 + height compression 45,450,720 + LSTM 12,599,296
    # + head 12,300. Flax's LSTM cell has one bias per gate where PyTorch has two
    # (b_ih and b_hh): 4 gates x 512 x 2 directions x 2 layers = 8,192 fewer.
    paper = ncjax.HorizonNetConfig.preset("paper")
    assert ncjax.count_parameters(paper) == 81_570_348 - 8_192 == 81_562_156
    abstract = _network.abstract_model(paper)
    count = lambda node: sum(math.prod(x.shape) for x in jax.tree.leaves(nnx.state(node, nnx.Param)))  # noqa: E731
    assert count(abstract.backbone) == 25_557_032 - 2_049_000  # torchvision resnet50 minus its fc layer
    assert count(abstract.compressions) == 45_450_720
    assert count(abstract.lstm) == 12_599_296 - 8_192
    assert _network.column_feature_size(paper) == 1024  # HorizonNet's c_last at 512 rows
    assert ncjax.count_parameters(ncjax.HorizonNetConfig.preset("compact")) <= 4_000_000


def test_resample_columns_wraps_around():
    width, out = 16, 64
    x = np.random.default_rng(0).normal(size=(width, 3)).astype(np.float32)
    result = np.asarray(_network.resample_columns(jnp.asarray(x), out))
    centres = (np.arange(out) + 0.5) * width / out - 0.5
    expected = np.stack([np.interp(centres, np.arange(width), x[:, c], period=width) for c in range(3)], -1)
    np.testing.assert_allclose(result, expected, atol=1e-6)
    # Rolling the input by one column rolls the output by the factor.
    rolled = np.asarray(_network.resample_columns(jnp.roll(jnp.asarray(x), 1, axis=0), out))
    np.testing.assert_allclose(rolled, np.roll(result, out // width, axis=0), atol=1e-6)


def test_convolutional_features_roll_with_the_panorama():
    model = tiny_model()
    model.eval()
    features = nnx.jit(lambda m, x: m.column_features(x))
    images = jax.random.uniform(jax.random.PRNGKey(1), (2, TINY.input_height, TINY.input_width, 3))
    reference = np.asarray(features(model, images))
    for shift in (32, 96):
        rolled = np.asarray(features(model, jnp.roll(images, shift, axis=2)))
        np.testing.assert_allclose(rolled, np.roll(reference, shift // TINY.step_cols, axis=1), atol=1e-5)
    # Eval mode uses running statistics: a sample's features do not depend on the rest of the batch.
    other = images.at[1].set(1.0 - images[1])
    np.testing.assert_allclose(np.asarray(features(model, other))[0], reference[0], atol=1e-6)


def test_elevation_row_round_trip():
    rows = jnp.array([-0.5, 0.0, 31.5, 63.5])
    elevation = _network.row_to_elevation(rows, 64)
    np.testing.assert_allclose(elevation[2], 0.0, atol=1e-7)  # the horizon is between rows 31 and 32
    np.testing.assert_allclose(_network.elevation_to_row(elevation, 64), rows, atol=1e-5)
    prediction = ncjax.BoundaryPrediction(jnp.full((1, 8), 0.0), jnp.full((1, 8), -math.pi / 4), jnp.zeros((1, 8)))
    ceiling_v, floor_v, corner_prob = _network.prediction_to_rows(prediction, height=64, width=32)
    assert ceiling_v.shape == (1, 32)
    np.testing.assert_allclose(ceiling_v, 31.5, atol=1e-5)
    np.testing.assert_allclose(floor_v, 47.5, atol=1e-5)
    np.testing.assert_allclose(corner_prob, 0.5, atol=1e-6)


# ----------------------------------------------------------------------------- loss and augmentations


def test_loss_matches_numpy():
    rng = np.random.default_rng(0)
    pred = [rng.normal(size=(2, 16)).astype(np.float32) for _ in range(3)]
    ceiling_v, floor_v = rng.uniform(0, 16, (2, 16)), rng.uniform(16, 32, (2, 16))
    target = rng.uniform(0, 1, (2, 16))
    terms = ncjax.horizonnet_loss(ncjax.BoundaryPrediction(*map(jnp.asarray, pred)), ceiling_v, floor_v, target, 32)
    elevation = lambda v: np.pi / 2 - np.pi * (v + 0.5) / 32  # noqa: E731
    boundary = 0.5 * (np.abs(pred[0] - elevation(ceiling_v)).mean() + np.abs(pred[1] - elevation(floor_v)).mean())
    p = 1 / (1 + np.exp(-pred[2]))
    corner = np.mean(-(target * np.log(p) + (1 - target) * np.log(1 - p)))
    np.testing.assert_allclose(terms["boundary"], boundary, rtol=1e-5)
    np.testing.assert_allclose(terms["corner"], corner, rtol=1e-5)
    np.testing.assert_allclose(terms["loss"], boundary + corner, rtol=1e-5)


def test_sharper_corner_encoding():
    """The loss re-encodes the 0.96**d labels as base**d; re-encoding back recovers them."""
    rng = np.random.default_rng(1)
    corners = np.array([3.2, 20.0, 22.0, 90.0])
    target = np.asarray(_rooms.corner_target(corners, np.ones(4, bool), 128))
    distance = np.abs(np.arange(128)[:, None] - corners[None, :])
    distance = np.minimum(distance, 128 - distance).min(axis=1)
    np.testing.assert_allclose(target, 0.96**distance, rtol=1e-5)
    sharp = _rooms.reencode_corner_prob(target, 0.96, 0.7)
    np.testing.assert_allclose(sharp, 0.7**distance, rtol=1e-4, atol=1e-30)
    np.testing.assert_allclose(_rooms.reencode_corner_prob(sharp, 0.7, 0.96), target, rtol=1e-4)
    # Peaks and dips stay where they were (a monotone map); the dip between corners 2 columns apart deepens.
    assert np.array_equal(np.argsort(sharp), np.argsort(target))
    assert sharp[21] < 0.75 * sharp[20] and target[21] > 0.95 * target[20]

    logits = rng.normal(size=(2, 128)).astype(np.float32)
    prediction = ncjax.BoundaryPrediction(jnp.zeros((2, 128)), jnp.zeros((2, 128)), jnp.asarray(logits))
    rows = np.full((2, 128), 10.0)
    terms = ncjax.horizonnet_loss(prediction, rows, rows, np.stack([target, target]), 64, corner_base=0.7)
    p = 1 / (1 + np.exp(-logits))
    expected = np.mean(-(0.7**distance * np.log(p) + (1 - 0.7**distance) * np.log(1 - p)))
    np.testing.assert_allclose(terms["corner"], expected, rtol=1e-5)


def test_augmented_images_match_augmented_labels():
    samples = painted_samples()
    colours = jnp.array([[0.9, 0.8, 0.7], [0.5, 0.6, 0.2], [0.2, 0.3, 0.4]])
    geometric_only = ncjax.TrainConfig(max_gamma=1.0, max_brightness=0.0, greyscale_probability=0.0)
    augment = jax.jit(_train.augment_sample, static_argnums=2)
    flips = []
    for i in range(6):
        sample = {k: v[i % 8] for k, v in samples.items()}
        sample["image"] = _train.paint_panorama(sample["ceiling_v"], sample["floor_v"], jnp.zeros(128, int), 64, colours)
        out = augment(jax.random.PRNGKey(i), sample, geometric_only)
        repainted = _train.paint_panorama(out["ceiling_v"], out["floor_v"], jnp.zeros(128, int), 64, colours)
        np.testing.assert_allclose(out["image"], repainted, atol=1e-6)
        # The labels are the original ones rolled, possibly after a flip: find which.
        ceiling = np.asarray(sample["ceiling_v"])
        candidates = [(f, s) for f in (False, True) for s in range(128)
                      if np.array_equal(np.roll(ceiling[::-1] if f else ceiling, s), out["ceiling_v"])]
        assert len(candidates) == 1
        flip, shift = candidates[0]
        for key in ("floor_v", "corner_target"):
            original = np.asarray(sample[key])
            np.testing.assert_array_equal(np.roll(original[::-1] if flip else original, shift), out[key])
        flips.append(flip)
    assert set(flips) == {False, True}


def test_flip_is_the_mirrored_room():
    """Column u -> W - 1 - u is the panorama of the room mirrored in y (same rc, same rows)."""
    room = convex_room(jax.random.PRNGKey(3), rc=0.7)
    mirrored = Room(**{**vars(room), "corners": (room.corners * jnp.array([1.0, -1.0]))[::-1]})
    cam = room.camera(128, 64)
    room_labels = jax.jit(ncjax.room_labels)
    labels, mirror_labels = room_labels(room, cam), room_labels(mirrored, cam)
    sample = {"image": jnp.zeros((64, 128, 3)), "ceiling_v": labels.ceiling_v, "floor_v": labels.floor_v,
              "corner_target": labels.corner_target}
    flipped = _train.flip_panorama(sample)
    np.testing.assert_allclose(flipped["ceiling_v"], mirror_labels.ceiling_v, atol=1e-3)
    np.testing.assert_allclose(flipped["floor_v"], mirror_labels.floor_v, atol=1e-3)
    np.testing.assert_allclose(flipped["corner_target"], mirror_labels.corner_target, atol=1e-3)
    rolled = _train.roll_panorama(sample, 5)
    np.testing.assert_array_equal(rolled["floor_v"], np.roll(labels.floor_v, 5))


def test_photometric_changes():
    image = jax.random.uniform(jax.random.PRNGKey(0), (4, 8, 3))
    np.testing.assert_allclose(_train.adjust_photometric(image, 1.0, 1.0, False), image, atol=1e-7)
    np.testing.assert_allclose(_train.adjust_photometric(image, 2.0, 1.0, False), image**2, atol=1e-7)
    grey = np.asarray(_train.adjust_photometric(image, 1.0, 0.5, True))
    np.testing.assert_allclose(grey[..., 0], grey[..., 2])
    np.testing.assert_allclose(grey[..., 1], 0.5 * image @ jnp.array([0.299, 0.587, 0.114]), atol=1e-6)


# ----------------------------------------------------------------------------- training, checkpoints, resume


def test_training_reduces_loss_and_resume_continues(tmp_path):
    straight = ncjax.train(TINY, batches, 24, tmp_path / "a", train_config=TRAIN, checkpoint_every=0, progress=False)
    losses = [h["loss"] for h in straight.history]
    assert np.mean(losses[-4:]) < 0.8 * np.mean(losses[:4]), losses

    first = ncjax.train(TINY, batches, 12, tmp_path / "b", train_config=TRAIN, checkpoint_every=0, progress=False)
    resumed = ncjax.train(TINY, batches, 24, tmp_path / "b", train_config=TRAIN, checkpoint_every=0, progress=False)
    assert first.step == 12 and resumed.step == 24 and len(resumed.history) == 12
    assert [h["loss"] for h in resumed.history] == losses[12:]
    a, b = params_of(straight.model), params_of(resumed.model)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    # Batch norm statistics moved away from their initial values in train mode.
    assert not np.allclose(a["backbone/stem/norm/mean"], 0.0)


def test_checkpoint_round_trip_is_bit_exact(tmp_path):
    model = ncjax.init_model(TINY, seed=0)
    optimizer = _train.make_optimizer(model, TRAIN)
    batch = next(batches(0))
    _train.train_step(model, optimizer, batch, jax.random.fold_in(_train.step_key_root(0), 0), TRAIN)
    path = tmp_path / "ckpt.safetensors"
    save_checkpoint(path, model, optimizer, step=1, train_config_json=TRAIN.to_json())
    loaded, loaded_optimizer, step = load_checkpoint(path, lambda m, j: _train.make_optimizer(m, ncjax.TrainConfig.from_json(j)))
    assert step == 1 and loaded.config == TINY
    assert ncjax.TrainConfig.from_json(read_metadata(path)["train_config"]) == TRAIN
    for saved, restored in [(model, loaded), (optimizer, loaded_optimizer)]:
        a, b = params_of(saved), params_of(restored)
        assert a.keys() == b.keys()
        for k in a:
            assert a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]), k
    ncjax.save_model(model, tmp_path / "model.safetensors")
    weights = params_of(ncjax.load_model(tmp_path / "model.safetensors"))
    assert all(np.array_equal(weights[k], params_of(model)[k]) for k in weights)
    with pytest.raises(ValueError, match="no optimizer state"):
        load_checkpoint(tmp_path / "model.safetensors", lambda m, j: None)
    with pytest.raises(FileNotFoundError):
        ncjax.load_model(tmp_path / "missing.safetensors")


def test_fine_tuning_starts_from_the_weights_with_a_new_corner_encoding(tmp_path):
    model = tiny_model()
    ncjax.save_model(model, tmp_path / "model.safetensors")
    sharp = dataclasses.replace(TINY, corner_base=0.75)
    started = load_weights(tmp_path / "model.safetensors", sharp)
    assert started.config == sharp
    a, b = params_of(model), params_of(started)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="cannot start"):
        load_weights(tmp_path / "model.safetensors", dataclasses.replace(TINY, lstm_hidden=8))
    # Two steps from those weights; the checkpoint then records the new encoding.
    result = ncjax.train(sharp, batches, 2, tmp_path / "ck", train_config=TRAIN, checkpoint_every=0,
                         progress=False, initial_weights=tmp_path / "model.safetensors")
    assert result.step == 2 and load_checkpoint(tmp_path / "ck" / "step_00000002.safetensors")[0].config == sharp


# ----------------------------------------------------------------------------- metrics


def test_boundary_pixel_error_in_1024_pixels():
    width = 256
    truth = jnp.full(width, 40.0)
    error = ncjax.boundary_pixel_error(truth + 1.0, truth + 60.0 - 3.0, truth, truth + 60.0)
    np.testing.assert_allclose(error, 2.0 * 1024 / width)


def test_corner_metrics_on_hand_made_columns():
    target = jnp.array([0.2, 0.96, 1.0, 0.96, 0.2, 0.1, 0.1, 0.1, 0.1, 0.1])
    prob = jnp.array([0.1, 0.4, 0.9, 0.8, 0.7, 0.0, 0.0, 0.0, 0.0, 0.6])
    confusion = ncjax.corner_confusion(prob, target)
    np.testing.assert_array_equal(confusion, [2, 2, 1, 5])  # TP, FP, FN, TN
    scores = ncjax.corner_scores(confusion)
    np.testing.assert_allclose([scores[k] for k in ("precision", "recall", "accuracy", "iou")], [0.5, 2 / 3, 0.7, 0.4])
    assert np.isnan(ncjax.corner_scores(jnp.array([0, 0, 3, 7]))["precision"])

    table = ncjax.network_table(
        jnp.stack([target, target]) * 0 + 10.0, jnp.full((2, 10), 20.0), jnp.stack([prob, target]),
        jnp.array([[11.0] * 10, [10.0] * 10]), jnp.full((2, 10), 20.0), jnp.stack([target, target]),
    )
    # Image 0: ceiling off by 1 px at W = 10 -> 0.5 * 1024 / 10; image 1: exact.
    np.testing.assert_allclose(table["pe_mean"], 0.25 * 102.4, rtol=1e-6)
    np.testing.assert_allclose(table["pe_std"], 0.25 * 102.4, rtol=1e-6)
    np.testing.assert_allclose(table["precision"], 5 / 7, rtol=1e-6)  # TP 2 + 3, FP 2
    np.testing.assert_allclose(table["recall"], 5 / 6, rtol=1e-6)


# ----------------------------------------------------------------------------- prediction


def test_predict_boundaries_input_size_and_errors(monkeypatch, tmp_path):
    model = tiny_model()
    image = np.random.default_rng(0).integers(0, 256, (128, 256, 3), dtype=np.uint8)
    ceiling_v, floor_v, corner_prob = ncjax.predict_boundaries(image, model)
    assert ceiling_v.shape == floor_v.shape == corner_prob.shape == (256,)
    assert np.all((corner_prob >= 0) & (corner_prob <= 1)) and np.all(np.isfinite(ceiling_v))
    batch_ceiling, _, _ = ncjax.predict_boundaries(image[None], model)
    np.testing.assert_allclose(batch_ceiling[0], ceiling_v, atol=1e-5)
    # The default snaps the network's own rows to the edges of the image the network saw: a random image is
    # all noise, so that is the image blurred down to the network's training noise; the corner output is untouched.
    raw = ncjax.predict_boundaries(image, model, edge_snap=None)
    denoised = denoise_for_network(jnp.asarray(image, jnp.float32)[None] / 255.0)[0]
    assert not np.allclose(denoised, image / 255.0, atol=0.05)
    snapped = ncjax.snap_to_edges(denoised, raw[0], raw[1], ncjax.EdgeSnap())
    np.testing.assert_allclose(ceiling_v, snapped[0], atol=1e-4)
    np.testing.assert_allclose(floor_v, snapped[1], atol=1e-4)
    np.testing.assert_array_equal(corner_prob, raw[2])
    assert not np.allclose(ceiling_v, raw[0])
    with pytest.raises(ValueError, match="uint8"):
        ncjax.predict_boundaries(image.astype(np.float32), model)
    monkeypatch.setattr(_predict, "DEFAULT_MODEL_PATH", tmp_path / "compact1024.safetensors")
    with pytest.raises(FileNotFoundError, match="default network weights"):
        ncjax.predict_boundaries(image)


def test_averaged_views_follow_the_panorama_symmetries():
    """The average over views is exactly mirror- and half-turn-equivariant (each view is mapped back)."""
    model = tiny_model()
    model.eval()
    images = jax.random.uniform(jax.random.key(3), (1, TINY.input_height, TINY.input_width, 3))
    width = TINY.input_width
    averaged = _network.predict_views(model, images, 4)
    mirrored = _network.predict_views(model, images[:, :, ::-1], 4)
    turned = _network.predict_views(model, jnp.roll(images, width // 2, axis=2), 4)
    for field, flipped, rolled in zip(averaged, mirrored, turned):
        np.testing.assert_allclose(flipped[:, ::-1], field, atol=1e-5)
        np.testing.assert_allclose(rolled, jnp.roll(field, width // 2, axis=1), atol=1e-5)
    single = _network.predict_views(model, images, 1)
    np.testing.assert_array_equal(single.ceiling_elevation, model(images).ceiling_elevation)
    assert not np.allclose(single.ceiling_elevation, averaged.ceiling_elevation)
    for bad in (0, 3, -2):
        with pytest.raises(ValueError, match="views"):
            ncjax.predict_boundaries(np.zeros((64, 128, 3), np.uint8), model, views=bad)
