"""Non-central HorizonNet: shapes, wrap-awareness, parameter counts, loss, augmentations,
checkpoints, resume, Table netcorExp metrics, predict_boundaries, the EfficientNet-Lite0
backbone, the shipped model's outputs.

One tiny configuration per backbone (ResNet-10 and EfficientNet-Lite0 with a
one-layer LSTM, 64 x 128) is compiled once per jitted function and shared by
the tests (functools.cache); shape and parameter-count tests only trace
(nnx.eval_shape).
"""

import dataclasses
import functools
import itertools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx

import ncjax
import ncjax.network.model
import ncjax.network.predict
import ncjax.synth.labels
import ncjax.training.data
import ncjax.training.loop
from ncjax.network import efficientnet
from ncjax.network.checkpoint import load_checkpoint, load_weights, model_file, read_metadata, save_checkpoint
from ncjax.network.denoise import denoise_for_network
from ncjax.synth.rooms import Room

TINY = ncjax.HorizonNetConfig(
    depth=10, width=8, input_height=64, input_width=128, lstm_hidden=16, lstm_layers=1, dropout=0.1
)
LITE0_TINY = ncjax.HorizonNetConfig(
    backbone="efficientnet_lite0", input_height=64, input_width=128, lstm_hidden=16, lstm_layers=1, dropout=0.1
)
TRAIN = ncjax.TrainConfig(peak_learning_rate=3e-3, warmup_steps=3, total_steps=40)
BATCH = 4


@functools.cache
def tiny_model():
    return ncjax.network.init_model(TINY, seed=0)


@functools.cache
def lite0_model():
    return ncjax.network.init_model(LITE0_TINY, seed=0)


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
        labels = ncjax.synth.room_labels(room, room.camera(TINY.input_width, TINY.input_height))
        colours = jax.random.uniform(k_colour, (3, 3), minval=0.1, maxval=0.9)
        image = ncjax.training.data.paint_panorama(
            labels.ceiling_v, labels.floor_v, labels.wall_index, TINY.input_height, colours
        )
        return {
            "image": image,
            "ceiling_v": labels.ceiling_v,
            "floor_v": labels.floor_v,
            "corner_target": labels.corner_target,
        }

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


@pytest.mark.slow
@pytest.mark.parametrize("backbone", ncjax.network.config.BACKBONES)
@pytest.mark.parametrize("height, width", [(32, 64), (64, 128), (96, 160), (64, 256)])
def test_output_shapes_follow_input_shape(height, width, backbone):
    config = ncjax.HorizonNetConfig(
        backbone=backbone, depth=10, width=8, input_height=height, input_width=width, lstm_hidden=8
    )
    model = ncjax.network.model.abstract_model(config)
    model.eval()
    images = jax.ShapeDtypeStruct((2, height, width, 3), jnp.float32)
    features = nnx.eval_shape(lambda m, x: m.column_features(x), model, images)
    prediction = nnx.eval_shape(lambda m, x: m(x), model, images)
    assert features.shape == (2, width // 4, ncjax.network.model.column_feature_size(config))
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


@pytest.mark.slow
def test_parameter_counts():
    # PyTorch HorizonNet (ResNet-50, 512 x 1024, LSTM 512) has 81,570,348 parameters:
    # ResNet-50 trunk 23,508,032 + height compression 45,450,720 + LSTM 12,599,296
    # + head 12,300. Flax's LSTM cell has one bias per gate where PyTorch has two
    # (b_ih and b_hh): 4 gates x 512 x 2 directions x 2 layers = 8,192 fewer.
    paper = ncjax.HorizonNetConfig.preset("paper")
    assert ncjax.network.count_parameters(paper) == 81_570_348 - 8_192 == 81_562_156
    abstract = ncjax.network.model.abstract_model(paper)

    def count(node):
        return sum(math.prod(x.shape) for x in jax.tree.leaves(nnx.state(node, nnx.Param)))

    assert count(abstract.backbone) == 25_557_032 - 2_049_000  # torchvision resnet50 minus its fc layer
    assert count(abstract.compressions) == 45_450_720
    assert count(abstract.lstm) == 12_599_296 - 8_192
    assert ncjax.network.model.column_feature_size(paper) == 1024  # HorizonNet's c_last at 512 rows
    assert ncjax.network.count_parameters(ncjax.HorizonNetConfig.preset("compact")) <= 4_000_000


def test_resample_columns_wraps_around():
    width, out = 16, 64
    x = np.random.default_rng(0).normal(size=(width, 3)).astype(np.float32)
    result = np.asarray(ncjax.network.model.resample_columns(jnp.asarray(x), out))
    centres = (np.arange(out) + 0.5) * width / out - 0.5
    expected = np.stack([np.interp(centres, np.arange(width), x[:, c], period=width) for c in range(3)], -1)
    np.testing.assert_allclose(result, expected, atol=1e-6)
    # Rolling the input by one column rolls the output by the factor.
    rolled = np.asarray(ncjax.network.model.resample_columns(jnp.roll(jnp.asarray(x), 1, axis=0), out))
    np.testing.assert_allclose(rolled, np.roll(result, out // width, axis=0), atol=1e-6)


@pytest.mark.slow
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
    elevation = ncjax.geometry.camera.row_to_elevation(rows, 64)
    np.testing.assert_allclose(elevation[2], 0.0, atol=1e-7)  # the horizon is between rows 31 and 32
    np.testing.assert_allclose(ncjax.geometry.camera.elevation_to_row(elevation, 64), rows, atol=1e-5)
    prediction = ncjax.network.BoundaryPrediction(
        jnp.full((1, 8), 0.0), jnp.full((1, 8), -math.pi / 4), jnp.zeros((1, 8))
    )
    ceiling_v, floor_v, corner_prob = ncjax.network.model.prediction_to_rows(prediction, height=64, width=32)
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
    terms = ncjax.training.horizonnet_loss(
        ncjax.network.BoundaryPrediction(*map(jnp.asarray, pred)), ceiling_v, floor_v, target, 32
    )

    def elevation(v):
        return np.pi / 2 - np.pi * (v + 0.5) / 32

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
    target = np.asarray(ncjax.synth.labels.corner_target(corners, np.ones(4, bool), 128))
    distance = np.abs(np.arange(128)[:, None] - corners[None, :])
    distance = np.minimum(distance, 128 - distance).min(axis=1)
    np.testing.assert_allclose(target, 0.96**distance, rtol=1e-5)
    sharp = ncjax.synth.labels.reencode_corner_prob(target, 0.96, 0.7)
    np.testing.assert_allclose(sharp, 0.7**distance, rtol=1e-4, atol=1e-30)
    np.testing.assert_allclose(ncjax.synth.labels.reencode_corner_prob(sharp, 0.7, 0.96), target, rtol=1e-4)
    # Peaks and dips stay where they were (a monotone map); the dip between corners 2 columns apart deepens.
    assert np.array_equal(np.argsort(sharp), np.argsort(target))
    assert sharp[21] < 0.75 * sharp[20] and target[21] > 0.95 * target[20]

    logits = rng.normal(size=(2, 128)).astype(np.float32)
    prediction = ncjax.network.BoundaryPrediction(jnp.zeros((2, 128)), jnp.zeros((2, 128)), jnp.asarray(logits))
    rows = np.full((2, 128), 10.0)
    terms = ncjax.training.horizonnet_loss(prediction, rows, rows, np.stack([target, target]), 64, corner_base=0.7)
    p = 1 / (1 + np.exp(-logits))
    expected = np.mean(-(0.7**distance * np.log(p) + (1 - 0.7**distance) * np.log(1 - p)))
    np.testing.assert_allclose(terms["corner"], expected, rtol=1e-5)


@pytest.mark.slow
def test_augmented_images_match_augmented_labels():
    samples = painted_samples()
    colours = jnp.array([[0.9, 0.8, 0.7], [0.5, 0.6, 0.2], [0.2, 0.3, 0.4]])
    geometric_only = ncjax.TrainConfig(photometric=False)
    augment = jax.jit(ncjax.training.loop.augment_sample, static_argnums=2)
    flips = []
    for i in range(6):
        sample = {k: v[i % 8] for k, v in samples.items()}
        sample["image"] = ncjax.training.data.paint_panorama(
            sample["ceiling_v"], sample["floor_v"], jnp.zeros(128, int), 64, colours
        )
        out = augment(jax.random.PRNGKey(i), sample, geometric_only)
        repainted = ncjax.training.data.paint_panorama(
            out["ceiling_v"], out["floor_v"], jnp.zeros(128, int), 64, colours
        )
        np.testing.assert_allclose(out["image"], repainted, atol=1e-6)
        # The labels are the original ones rolled, possibly after a flip: find which.
        ceiling = np.asarray(sample["ceiling_v"])
        candidates = [
            (f, s)
            for f in (False, True)
            for s in range(128)
            if np.array_equal(np.roll(ceiling[::-1] if f else ceiling, s), out["ceiling_v"])
        ]
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
    room_labels = jax.jit(ncjax.synth.room_labels)
    labels, mirror_labels = room_labels(room, cam), room_labels(mirrored, cam)
    sample = {
        "image": jnp.zeros((64, 128, 3)),
        "ceiling_v": labels.ceiling_v,
        "floor_v": labels.floor_v,
        "corner_target": labels.corner_target,
    }
    flipped = ncjax.training.loop.flip_panorama(sample)
    np.testing.assert_allclose(flipped["ceiling_v"], mirror_labels.ceiling_v, atol=1e-3)
    np.testing.assert_allclose(flipped["floor_v"], mirror_labels.floor_v, atol=1e-3)
    np.testing.assert_allclose(flipped["corner_target"], mirror_labels.corner_target, atol=1e-3)
    rolled = ncjax.training.loop.roll_panorama(sample, 5)
    np.testing.assert_array_equal(rolled["floor_v"], np.roll(labels.floor_v, 5))


@pytest.mark.slow
def test_photometric_augmentation_is_random_augment_and_keeps_the_labels():
    sample = {k: v[0] for k, v in painted_samples().items()}
    no_geometry = ncjax.TrainConfig(roll=False, flip=False)

    @jax.jit
    def both(key):
        expected = ncjax.synth.random_augment(jax.random.split(key, 3)[2], sample["image"], no_geometry.augment)
        return ncjax.training.loop.augment_sample(key, sample, no_geometry), expected

    out, expected = both(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(out["image"], expected)
    for label in ncjax.training.loop.LABEL_KEYS:
        np.testing.assert_array_equal(out[label], sample[label])


def test_train_config_json_round_trip_and_older_configurations():
    augment = ncjax.synth.AugmentConfig(jpeg_quality=(5.0, 30.0), seam_count=2, jpeg_chroma_subsampling=False)
    config = ncjax.TrainConfig(peak_learning_rate=3e-4, photometric=False, augment=augment)
    restored = ncjax.TrainConfig.from_json(config.to_json())
    assert restored == config and hash(restored) == hash(config)
    # An older checkpoint's settings: no augment, the photometric settings it replaced.
    old = {**json.loads(ncjax.TrainConfig(warmup_steps=7).to_json()), "max_gamma": 1.5, "max_brightness": 0.2}
    del old["augment"], old["photometric"]
    old["greyscale_probability"] = 0.1
    assert ncjax.TrainConfig.from_json(json.dumps(old)) == ncjax.TrainConfig(warmup_steps=7)


# ----------------------------------------------------------------------------- training, checkpoints, resume


@pytest.mark.extended
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


@pytest.mark.slow
def test_time_budget_stops_after_a_step_with_a_checkpoint_to_resume(tmp_path):
    stopped = ncjax.train(
        TINY, batches, 3, tmp_path, train_config=TRAIN, checkpoint_every=0, progress=False, time_budget=0.0
    )
    assert stopped.step == 1 and [h["step"] for h in stopped.history] == [1]
    assert ncjax.training.loop.latest_checkpoint(tmp_path).name == "step_00000001.safetensors"
    resumed = ncjax.train(TINY, batches, 3, tmp_path, train_config=TRAIN, checkpoint_every=0, progress=False)
    assert resumed.step == 3 and [h["step"] for h in resumed.history] == [2, 3]
    assert ncjax.training.loop.latest_checkpoint(tmp_path).name == "step_00000003.safetensors"


@pytest.mark.slow
def test_checkpoint_round_trip_is_bit_exact(tmp_path):
    model = ncjax.network.init_model(TINY, seed=0)
    optimizer = ncjax.training.loop.make_optimizer(model, TRAIN)
    batch = next(batches(0))
    ncjax.training.loop.train_step(
        model, optimizer, batch, jax.random.fold_in(ncjax.training.loop.step_key_root(0), 0), TRAIN
    )
    path = tmp_path / "ckpt.safetensors"
    save_checkpoint(path, model, optimizer, step=1, train_config_json=TRAIN.to_json())
    loaded, loaded_optimizer, step = load_checkpoint(
        path, lambda m, j: ncjax.training.loop.make_optimizer(m, ncjax.TrainConfig.from_json(j))
    )
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


@pytest.mark.slow
def test_model_weights_are_the_files_tensors_and_rebuild_the_same_network(tmp_path):
    from ncjax.network.checkpoint import model_from_weights, model_weights

    model = ncjax.network.init_model(TINY, seed=0)
    model.eval()
    ncjax.save_model(model, tmp_path / "model.safetensors")
    from_file, from_model = model_weights(tmp_path / "model.safetensors"), model_weights(model)
    assert from_file.config == from_model.config == TINY
    assert from_file.tensors.keys() == from_model.tensors.keys()
    assert all(np.array_equal(from_file.tensors[k], from_model.tensors[k]) for k in from_file.tensors)
    assert model_weights(tmp_path / "model.safetensors") is from_file  # an unchanged file is read once
    rebuilt = model_from_weights(from_file)
    original, restored = params_of(model), params_of(rebuilt)
    assert rebuilt.config == TINY and original.keys() == restored.keys()
    norms = [node for _, node in nnx.iter_graph(rebuilt) if isinstance(node, nnx.BatchNorm)]
    assert norms and all(norm.use_running_average for norm in norms)  # eval mode
    assert all(np.array_equal(original[k], restored[k]) for k in original)
    name = next(iter(from_file.tensors))
    broken = from_file._replace(tensors=from_file.tensors | {name: from_file.tensors[name][..., :1]})
    with pytest.raises(ValueError, match=f"{name} is float32"):
        model_from_weights(broken)


def test_a_half_precision_model_file_is_half_the_size_and_reads_back_as_float32(tmp_path):
    from ncjax.network.weights import read_metadata, read_weights

    model = tiny_model()
    ncjax.save_model(model, tmp_path / "full.safetensors")
    ncjax.save_model(model, tmp_path / "half.safetensors", dtype="float16")
    full, half = ((tmp_path / name).stat().st_size for name in ("full.safetensors", "half.safetensors"))
    assert half < 0.55 * full
    assert read_metadata(tmp_path / "half.safetensors")["weights_dtype"] == "float16"
    original, restored = params_of(model), params_of(ncjax.load_model(tmp_path / "half.safetensors"))
    assert original.keys() == restored.keys()
    for name, value in original.items():
        assert restored[name].dtype == value.dtype == np.float32, name
        np.testing.assert_array_equal(restored[name], value.astype(np.float16).astype(np.float32), err_msg=name)
    assert all(v.dtype == np.float32 for v in read_weights(tmp_path / "half.safetensors").tensors.values())
    with pytest.raises(ValueError, match="weights_dtype must be one of float32, float16"):
        ncjax.save_model(model, tmp_path / "bad.safetensors", dtype="int8")
    too_large = ncjax.load_model(tmp_path / "full.safetensors")  # a copy: ``model`` is shared
    _, variable = next(iter(nnx.to_flat_state(nnx.state(too_large, nnx.Param))))
    variable.set_value(variable.get_value().at[...].set(1e6))  # beyond float16's largest, 65504
    with pytest.raises(ValueError, match="beyond float16's range"):
        ncjax.save_model(too_large, tmp_path / "bad.safetensors", dtype="float16")
    assert not (tmp_path / "bad.safetensors").exists()


def test_shipped_models_load_by_name_and_an_unknown_name_says_what_ships():
    from ncjax.network.weights import shipped_models

    assert "compact1024" in shipped_models()
    assert "efficientnet_lite0_imagenet" not in shipped_models()  # a backbone's weights, not a layout network
    assert model_file("compact1024").name == "compact1024.safetensors"
    with pytest.raises(FileNotFoundError, match="shipped: .*compact1024"):
        model_file("no-such-model")


@pytest.mark.extended
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
    result = ncjax.train(
        sharp,
        batches,
        2,
        tmp_path / "ck",
        train_config=TRAIN,
        checkpoint_every=0,
        progress=False,
        initial_weights=tmp_path / "model.safetensors",
    )
    assert result.step == 2 and load_checkpoint(tmp_path / "ck" / "step_00000002.safetensors")[0].config == sharp


# ----------------------------------------------------------------------------- metrics


def test_boundary_pixel_error_in_1024_pixels():
    width = 256
    truth = jnp.full(width, 40.0)
    error = ncjax.evaluation.boundary_pixel_error(truth + 1.0, truth + 60.0 - 3.0, truth, truth + 60.0)
    np.testing.assert_allclose(error, 2.0 * 1024 / width)


def test_corner_metrics_on_hand_made_columns():
    target = jnp.array([0.2, 0.96, 1.0, 0.96, 0.2, 0.1, 0.1, 0.1, 0.1, 0.1])
    prob = jnp.array([0.1, 0.4, 0.9, 0.8, 0.7, 0.0, 0.0, 0.0, 0.0, 0.6])
    confusion = ncjax.evaluation.corner_confusion(prob, target)
    np.testing.assert_array_equal(confusion, [2, 2, 1, 5])  # TP, FP, FN, TN
    scores = ncjax.evaluation.corner_scores(confusion)
    np.testing.assert_allclose([scores[k] for k in ("precision", "recall", "accuracy", "iou")], [0.5, 2 / 3, 0.7, 0.4])
    assert np.isnan(ncjax.evaluation.corner_scores(jnp.array([0, 0, 3, 7]))["precision"])

    table = ncjax.evaluation.network_table(
        jnp.stack([target, target]) * 0 + 10.0,
        jnp.full((2, 10), 20.0),
        jnp.stack([prob, target]),
        jnp.array([[11.0] * 10, [10.0] * 10]),
        jnp.full((2, 10), 20.0),
        jnp.stack([target, target]),
    )
    # Image 0: ceiling off by 1 px at W = 10 -> 0.5 * 1024 / 10; image 1: exact.
    np.testing.assert_allclose(table["pe_mean"], 0.25 * 102.4, rtol=1e-6)
    np.testing.assert_allclose(table["pe_std"], 0.25 * 102.4, rtol=1e-6)
    np.testing.assert_allclose(table["precision"], 5 / 7, rtol=1e-6)  # TP 2 + 3, FP 2
    np.testing.assert_allclose(table["recall"], 5 / 6, rtol=1e-6)


# ----------------------------------------------------------------------------- prediction


@pytest.mark.slow
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
    snapped = ncjax.network.snap_to_edges(denoised, raw[0], raw[1], ncjax.EdgeSnap())
    np.testing.assert_allclose(ceiling_v, snapped[0], atol=1e-4)
    np.testing.assert_allclose(floor_v, snapped[1], atol=1e-4)
    np.testing.assert_array_equal(corner_prob, raw[2])
    assert not np.allclose(ceiling_v, raw[0])
    with pytest.raises(ValueError, match="uint8"):
        ncjax.predict_boundaries(image.astype(np.float32), model)
    monkeypatch.setattr(ncjax.network.predict, "DEFAULT_MODEL_PATH", tmp_path / "compact1024.safetensors")
    with pytest.raises(FileNotFoundError, match="default network weights"):
        ncjax.predict_boundaries(image)


@pytest.mark.slow
def test_averaged_views_follow_the_panorama_symmetries():
    """The average over views is exactly mirror- and half-turn-equivariant (each view is mapped back)."""
    model = tiny_model()
    model.eval()
    images = jax.random.uniform(jax.random.key(3), (1, TINY.input_height, TINY.input_width, 3))
    width = TINY.input_width
    averaged = ncjax.network.model.predict_views(model, images, 4)
    mirrored = ncjax.network.model.predict_views(model, images[:, :, ::-1], 4)
    turned = ncjax.network.model.predict_views(model, jnp.roll(images, width // 2, axis=2), 4)
    for field, flipped, rolled in zip(averaged, mirrored, turned, strict=True):
        np.testing.assert_allclose(flipped[:, ::-1], field, atol=1e-5)
        np.testing.assert_allclose(rolled, jnp.roll(field, width // 2, axis=1), atol=1e-5)
    # Against the network run on every view, mapped back: with rolls of a multiple of 32 columns (4 and 8 views;
    # 8 rolls by a quarter turn, which tells the two directions apart) the backbone runs on the image and its
    # mirror image only; with other rolls (6 views) on every view.
    for views in (4, 6, 8):
        shifts = [width * i // (views // 2) for i in range(views // 2)]
        expected = []
        for shift in shifts:
            for mirror in (False, True):
                view = jnp.roll(images, shift, axis=2)
                out = model(view[:, :, ::-1] if mirror else view)
                expected.append([jnp.roll(x[:, ::-1] if mirror else x, -shift, axis=1) for x in out])
        computed = ncjax.network.model.predict_views(model, images, views)
        for field, views_of_field in zip(computed, zip(*expected, strict=True), strict=True):
            np.testing.assert_allclose(field, jnp.mean(jnp.stack(views_of_field), 0), atol=1e-5)
    single = ncjax.network.model.predict_views(model, images, 1)
    np.testing.assert_array_equal(single.ceiling_elevation, model(images).ceiling_elevation)
    assert not np.allclose(single.ceiling_elevation, averaged.ceiling_elevation)
    for bad in (0, 3, -2):
        with pytest.raises(ValueError, match="views"):
            ncjax.predict_boundaries(np.zeros((64, 128, 3), np.uint8), model, views=bad)


# ----------------------------------------------------------------------------- the EfficientNet-Lite0 backbone


@pytest.mark.slow
def test_shipped_model_outputs_are_unchanged():
    """``compact1024`` (written before the backbone choice existed) loads as the ResNet network it was
    and gives the outputs it gave then (values computed with the code of that time)."""
    assert ncjax.network.predict.DEFAULT_MODEL_PATH == model_file("lite0-1024")
    path = model_file("compact1024")
    assert "backbone" not in json.loads(read_metadata(path)["config"])
    model = ncjax.load_model(path)
    assert model.config == ncjax.HorizonNetConfig.preset("compact1024") and model.config.backbone == "resnet"
    rows, columns, channels = np.arange(512)[:, None, None], np.arange(64)[None, :, None], np.arange(3)
    image = 0.5 + 0.25 * np.sin(0.037 * rows + channels) + 0.2 * np.cos(0.21 * columns + 2 * channels)
    prediction = nnx.jit(lambda m, x: m(x))(model, jnp.asarray(image, jnp.float32)[None])
    expected = {
        "ceiling_elevation": [0.837494, 0.937519, 0.989915, 1.013732, 1.012165, 0.996485, 0.982058, 0.929809],
        "floor_elevation": [-0.819735, -0.913908, -0.966203, -0.987449, -0.982400, -0.967805, -0.954718, -0.900652],
        "corner_logit": [-0.922056, -0.898291, -0.762826, -0.708173, -0.714452, -0.669154, -0.563618, -0.614401],
    }
    for field, values in expected.items():
        np.testing.assert_allclose(np.asarray(getattr(prediction, field))[0, ::8], values, atol=1e-5)


def test_efficientnet_backbone_configuration():
    lite0, compact = (ncjax.HorizonNetConfig.preset(name) for name in ("lite0-1024", "compact1024"))
    assert lite0.backbone == "efficientnet_lite0" and compact.backbone == "resnet"
    assert dataclasses.replace(lite0, backbone="resnet") == compact  # same input size, LSTM and heads
    assert ncjax.network.model.stage_channels(lite0) == efficientnet.LITE0_FEATURE_CHANNELS == (24, 40, 112, 320)
    # Maps of 128, 64, 32 and 16 rows compressed to 8, 4, 2 and 1 rows of 3, 5, 14 and 40 channels.
    assert ncjax.network.model.column_feature_size(lite0) == 3 * 8 + 5 * 4 + 14 * 2 + 40 * 1
    assert ncjax.HorizonNetConfig.from_json(lite0.to_json()) == lite0
    # Files written before the backbone field existed hold ResNet networks.
    old_fields = {k: v for k, v in json.loads(compact.to_json()).items() if k != "backbone"}
    assert ncjax.HorizonNetConfig.from_json(json.dumps(old_fields)) == compact
    with pytest.raises(ValueError, match="backbone"):
        ncjax.HorizonNetConfig(backbone="efficientnet_b7")


@pytest.mark.slow
def test_efficientnet_backbone_parameter_counts():
    lite0 = ncjax.HorizonNetConfig.preset("lite0-1024")
    backbone = ncjax.network.model.abstract_model(lite0).backbone
    assert set(nnx.state(backbone)) == {"stem", "stages"}  # no head convolution, no classifier
    with pytest.raises(ValueError, match="without its classifier"):
        backbone(jnp.zeros((1, 32, 64, 3)))
    assert sum(math.prod(x.shape) for x in jax.tree.leaves(nnx.state(backbone, nnx.Param))) == 2_958_848
    assert efficientnet.count_parameters(classifier=False) == 2_958_848
    assert ncjax.network.count_parameters(lite0) == 4_300_934
    assert ncjax.network.count_parameters(ncjax.HorizonNetConfig.preset("compact1024")) == 3_907_848


@pytest.mark.slow
def test_init_model_starts_the_efficientnet_backbone_from_imagenet():
    model, other_seed = lite0_model(), ncjax.network.init_model(LITE0_TINY, seed=1)
    imagenet = params_of(efficientnet.load_efficientnet_lite0(circular_width=True))
    backbone = params_of(model.backbone)
    assert backbone.keys() == {k for k in imagenet if not k.startswith(("head/", "classifier/"))}
    for name, value in backbone.items():  # weights and batch-norm statistics
        np.testing.assert_array_equal(value, imagenet[name], err_msg=name)
    assert all(np.array_equal(value, params_of(other_seed.backbone)[name]) for name, value in backbone.items())
    # The rest is random, from the seed; the model starts in train mode.
    assert not np.array_equal(model.head.kernel.get_value(), other_seed.head.kernel.get_value())
    assert not other_seed.backbone.stem.norm.use_running_average


@pytest.mark.slow
def test_efficientnet_backbone_features_roll_with_the_panorama():
    model = lite0_model()
    model.eval()
    images = jax.random.uniform(jax.random.PRNGKey(1), (2, LITE0_TINY.input_height, LITE0_TINY.input_width, 3))
    prediction = nnx.jit(lambda m, x: m(x))(model, images)
    assert all(p.shape == (2, LITE0_TINY.input_width) and np.all(np.isfinite(p)) for p in prediction)
    features = nnx.jit(lambda m, x: m.column_features(x))
    reference = np.asarray(features(model, images))
    assert reference.shape == (2, LITE0_TINY.input_width // 4, ncjax.network.model.column_feature_size(LITE0_TINY))
    for shift in (32, 96):
        rolled = np.asarray(features(model, jnp.roll(images, shift, axis=2)))
        np.testing.assert_allclose(rolled, np.roll(reference, shift // LITE0_TINY.step_cols, axis=1), atol=1e-4)


@pytest.mark.slow
def test_efficientnet_backbone_model_round_trip(tmp_path):
    model = lite0_model()
    ncjax.save_model(model, tmp_path / "lite0.safetensors")
    assert json.loads(read_metadata(tmp_path / "lite0.safetensors")["config"])["backbone"] == "efficientnet_lite0"
    loaded = ncjax.load_model(tmp_path / "lite0.safetensors")
    assert loaded.config == LITE0_TINY
    a, b = params_of(model), params_of(loaded)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)


@pytest.mark.slow
def test_micro_batches_give_the_whole_batch_gradient():
    """Eval-mode batch norm and no dropout: a step over 2 or 4 micro-batches moves every weight as one over the
    whole batch (plain gradient descent, so the moves are the gradients); train mode updates the statistics."""
    with pytest.raises(ValueError, match="micro_batches"):
        ncjax.TrainConfig(micro_batches=0)
    moves, losses = {}, {}
    for parts in (1, 2, 4):
        model = nnx.clone(tiny_model())
        model.eval()
        before = params_of(model)
        optimizer = nnx.Optimizer(model, optax.sgd(1.0), wrt=nnx.Param)
        train_config = dataclasses.replace(TRAIN, micro_batches=parts)
        terms = ncjax.training.loop.train_step(model, optimizer, next(batches(0)), jax.random.key(3), train_config)
        losses[parts] = float(terms["loss"])
        after = params_of(model)
        moves[parts] = {name: after[name] - before[name] for name in after}
    assert np.abs(moves[1]["head/kernel"]).max() > 1e-4
    for parts in (2, 4):
        assert losses[parts] == pytest.approx(losses[1], rel=1e-5)
        for name, whole in moves[1].items():
            np.testing.assert_allclose(moves[parts][name], whole, rtol=1e-3, atol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match="micro-batches"):
        ncjax.training.loop.train_step(
            model, optimizer, next(batches(0)), jax.random.key(3), dataclasses.replace(TRAIN, micro_batches=3)
        )
    model.train()
    statistics = {name: value for name, value in params_of(model).items() if name.endswith("/mean")}
    ncjax.training.loop.train_step(
        model, optimizer, next(batches(0)), jax.random.key(3), dataclasses.replace(TRAIN, micro_batches=2)
    )
    assert statistics and all(not np.array_equal(params_of(model)[name], value) for name, value in statistics.items())


@pytest.mark.slow
@pytest.mark.parametrize(("backbone_scale", "head_scale"), [(0.25, 1.0), (1.0, 0.5)])
def test_learning_rate_scales_scale_the_updates_of_their_part(backbone_scale, head_scale):
    """One AdamW update: the backbone moves ``backbone_scale`` times as far as with the full learning rate, the
    rest (compressions, LSTM, head) ``head_scale`` times."""
    steps = {}
    for scales in ((1.0, 1.0), (backbone_scale, head_scale)):
        model = nnx.clone(tiny_model())
        before = params_of(model)
        train_config = dataclasses.replace(
            TRAIN, warmup_steps=0, backbone_learning_rate_scale=scales[0], head_learning_rate_scale=scales[1]
        )
        optimizer = ncjax.training.loop.make_optimizer(model, train_config)
        # Gradients of ones; jitted, an update compiles faster than its eager ops.
        nnx.jit(lambda o, m: o.update(m, jax.tree.map(jnp.ones_like, nnx.state(m, nnx.Param))))(optimizer, model)
        after = params_of(model)
        steps[scales] = {name: after[name] - before[name] for name in after}
    full, scaled = steps[(1.0, 1.0)], steps[(backbone_scale, head_scale)]
    assert np.all(full["backbone/stem/conv/conv/kernel"] < 0) and np.all(full["head/kernel"] < 0)
    for name, step in full.items():
        scale = backbone_scale if name.startswith("backbone/") else head_scale
        np.testing.assert_allclose(scaled[name], scale * step, atol=1e-7, err_msg=name)


@pytest.mark.parametrize(
    ("backbone_scale", "head_scale", "message"),
    [(-0.1, 1.0, "backbone_learning_rate_scale"), (1.0, -1.0, "head_learning_rate_scale"), (0.0, 0.0, "both 0")],
)
def test_learning_rate_scales_are_checked(backbone_scale, head_scale, message):
    with pytest.raises(ValueError, match=message):
        ncjax.TrainConfig(backbone_learning_rate_scale=backbone_scale, head_learning_rate_scale=head_scale)


def parameters_around_a_train_step(model, train_config):
    """The model's parameters and statistics before and after one train step in its configured train mode."""
    ncjax.training.loop.set_train_mode(model, train_config)
    optimizer = ncjax.training.loop.make_optimizer(model, train_config)
    before = params_of(model)
    key = jax.random.fold_in(ncjax.training.loop.step_key_root(0), 0)
    terms = ncjax.training.loop.train_step(model, optimizer, next(batches(0)), key, train_config)
    assert np.isfinite(float(terms["loss"]))
    return before, params_of(model)


@pytest.mark.slow
def test_frozen_head_keeps_its_weights_statistics_and_dropout_off_in_a_train_step():
    """Head scale 0: only the backbone learns; the compressions' batch-norm statistics stay, dropout is off."""
    frozen = dataclasses.replace(TRAIN, warmup_steps=0, head_learning_rate_scale=0.0)
    model = nnx.clone(tiny_model())
    before, after = parameters_around_a_train_step(model, frozen)
    assert model.lstm.dropout.deterministic and not model.backbone.stem.norm.use_running_average
    rest = [name for name in before if not name.startswith("backbone/")]
    assert "compressions/0/norms/0/mean" in rest and "head/kernel" in rest
    for name in rest:
        np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    assert not np.array_equal(after["backbone/stem/conv/conv/kernel"], before["backbone/stem/conv/conv/kernel"])
    assert not np.array_equal(after["backbone/stem/norm/mean"], before["backbone/stem/norm/mean"])


@pytest.mark.extended
def test_frozen_efficientnet_backbone_keeps_its_weights_in_a_train_step():
    frozen = dataclasses.replace(TRAIN, warmup_steps=0, backbone_learning_rate_scale=0.0)
    model = nnx.clone(lite0_model())
    before, after = parameters_around_a_train_step(model, frozen)
    # Weights and batch-norm statistics: the frozen backbone stays in eval mode.
    backbone = [name for name in before if name.startswith("backbone/")]
    assert "backbone/stem/norm/mean" in backbone
    for name in backbone:
        np.testing.assert_array_equal(after[name], before[name], err_msg=name)
    assert not np.array_equal(after["head/kernel"], before["head/kernel"])
    assert not np.array_equal(after["lstm/forward/0/cell/dense_i/kernel"], before["lstm/forward/0/cell/dense_i/kernel"])
    # Scale 1 trains it: its batch-norm statistics follow the data.
    ncjax.training.loop.set_train_mode(model, TRAIN)
    assert not model.backbone.stem.norm.use_running_average
