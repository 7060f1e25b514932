"""EfficientNet-Lite0 (ncjax.network.efficientnet): shipped weights, ImageNet classes, features, gradients.

The model is loaded once (functools.cache); each test compiles one small
program (the gradient test a reduced network, see TINY). The ImageNet check
uses scikit-image's sample photos (a dev dependency).
"""

import functools

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from skimage import data

from ncjax.network import efficientnet as effnet

SMALL = (2, 64, 128, 3)  # batch, height, width, channels: cheap to compile, strides up to 32 exact


@functools.cache
def model(circular_width: bool = False) -> effnet.EfficientNet:
    return effnet.load_efficientnet_lite0(circular_width=circular_width)


@functools.cache
def features_fn():
    return nnx.jit(lambda m, x: m.features(x))


def small_images(seed: int = 0) -> jax.Array:
    return jax.random.uniform(jax.random.key(seed), SMALL)


@pytest.mark.slow
def test_shipped_weights_load_in_eval_mode():
    m = model()
    assert effnet.DEFAULT_WEIGHTS_PATH.stat().st_size < 10_000_000  # float16
    params = nnx.state(m, nnx.Param)
    assert sum(x.size for x in jax.tree.leaves(params)) == effnet.count_parameters() == 4_652_008
    assert effnet.count_parameters(classifier=False) == 2_958_848
    assert all(x.dtype == jnp.float32 and np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(nnx.state(m)))
    assert m.stem.norm.use_running_average and m.stem.norm.epsilon == 1e-3
    # the running variances are the checkpoint's, not the initial ones
    assert not np.allclose(np.asarray(m.head.norm.var.get_value()), 1.0)


def test_weight_file_must_match(tmp_path):
    from safetensors.numpy import load_file, save_file

    tensors = load_file(effnet.DEFAULT_WEIGHTS_PATH)
    del tensors["classifier/bias"]
    save_file(tensors, tmp_path / "bad.safetensors", metadata={"format": effnet.WEIGHTS_FORMAT})
    with pytest.raises(ValueError, match="missing"):
        effnet.load_efficientnet_lite0(tmp_path / "bad.safetensors")
    save_file(tensors, tmp_path / "other.safetensors")
    with pytest.raises(ValueError, match="not an EfficientNet-Lite0"):
        effnet.load_efficientnet_lite0(tmp_path / "other.safetensors")


def test_same_padding_is_tensorflows():
    assert effnet.same_padding(224, 3, 2) == (0, 1)
    assert effnet.same_padding(112, 5, 2) == (1, 2)
    assert effnet.same_padding(56, 5, 1) == (2, 2)
    assert effnet.same_padding(7, 3, 2) == (1, 1)  # odd size: output 4
    assert effnet.same_padding(8, 1, 1) == (0, 0)


@pytest.mark.parametrize(("kernel", "stride"), [(3, 1), (3, 2), (5, 2)])
def test_depthwise_conv_is_a_grouped_convolution(kernel, stride):
    conv = effnet.DepthwiseConv(4, kernel, stride, rngs=nnx.Rngs(0))
    x = jax.random.normal(jax.random.key(0), (2, 11, 12, 4))
    expected = jax.lax.conv_general_dilated(
        x,
        conv.kernel.get_value(),
        (stride, stride),
        "VALID",
        dimension_numbers=("NHWC", "HWIO", "NHWC"),
        feature_group_count=4,
    )
    np.testing.assert_allclose(conv(x), expected, atol=1e-5, rtol=1e-5)


def test_pointwise_convolution_is_a_one_by_one_convolution():
    conv = effnet.PointwiseConv(4, 6, rngs=nnx.Rngs(0))
    x = jax.random.normal(jax.random.key(0), (2, 5, 7, 4))
    expected = jax.lax.conv_general_dilated(
        x, conv.kernel.get_value(), (1, 1), "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC")
    )
    assert conv.kernel.get_value().shape == (1, 1, 4, 6)  # nnx.Conv's layout: the same weight files load
    np.testing.assert_allclose(conv(x), expected, atol=1e-5, rtol=1e-5)


@pytest.mark.slow
def test_imagenet_top5_on_sample_photos():
    photos = [data.chelsea(), data.coffee()]  # a tabby cat; a cup of espresso
    batch = np.stack([cv2.resize(p, (224, 224), interpolation=cv2.INTER_AREA) for p in photos]) / np.float32(255)
    logits = nnx.jit(lambda m, x: m(x))(model(), jnp.asarray(batch, jnp.float32))
    assert logits.shape == (2, 1000)
    top5 = [set(np.argsort(-np.asarray(row))[:5].tolist()) for row in logits]
    assert top5[0] & {281, 282, 285}  # tabby, tiger cat, Egyptian cat
    assert top5[1] & {504, 967, 968}  # coffee mug, espresso, cup


@pytest.mark.slow
def test_features_strides_and_channels():
    config = effnet.LITE0
    assert config.feature_stages() == (1, 2, 4, 6)
    assert config.feature_channels() == effnet.LITE0_FEATURE_CHANNELS == (24, 40, 112, 320)
    maps = features_fn()(model(), small_images())
    assert len(maps) == 4
    batch, height, width, _ = SMALL
    for feature, stride, channels in zip(maps, effnet.FEATURE_STRIDES, config.feature_channels(), strict=True):
        assert feature.shape == (batch, height // stride, width // stride, channels)
        assert bool(jnp.all(jnp.isfinite(feature)))
    # TensorFlow "SAME": sizes that are not multiples of the stride are rounded up
    shapes = nnx.eval_shape(lambda m, x: m.features(x), model(), jax.ShapeDtypeStruct((1, 70, 100, 3), jnp.float32))
    assert [s.shape[1:3] for s in shapes] == [(18, 25), (9, 13), (5, 7), (3, 4)]


# Every kind of block of Lite0 (no expansion, k 3 and 5, strides 1 and 2, a residual block) in 6
# blocks instead of 16: the gradient program compiles in about half the time of the full network's.
TINY = effnet.EfficientNetConfig(
    stages=(
        effnet.StageConfig(1, 3, 1, 16, 1),
        effnet.StageConfig(6, 3, 2, 24, 2),
        effnet.StageConfig(6, 5, 2, 40, 1),
        effnet.StageConfig(6, 3, 2, 80, 1),
        effnet.StageConfig(6, 5, 2, 96, 1),
    ),
    head_channels=64,
    num_classes=10,
)


@pytest.mark.slow
def test_gradients_flow_through_features():
    """Train mode (batch statistics) as in fine-tuning: every trunk weight gets a finite, non-zero gradient."""
    assert TINY.feature_stages() == (1, 2, 3, 4)
    # one compiled initialisation from an "rbg" key is faster than eager threefry on a CPU
    trainable = nnx.jit(lambda: effnet.EfficientNet(TINY, rngs=nnx.Rngs(jax.random.key(0, impl="rbg"))))()
    trainable.train()

    def loss(m, x):
        return sum(jnp.mean(jnp.square(f)) for f in m.features(x))

    grads = nnx.jit(nnx.grad(loss))(trainable, small_images(1))
    for path, g in nnx.to_flat_state(grads):
        g = np.asarray(g.get_value())
        assert np.all(np.isfinite(g)), path
        if path[0] in ("head", "classifier"):  # not part of features
            assert not np.any(g), path
        else:
            assert np.any(g), path


@pytest.mark.slow
def test_circular_width_features_roll_with_the_image():
    """With circular width padding, rolling the image by 32 columns rolls every feature map."""
    images = small_images(2)
    shift = 32
    rolled_images = jnp.roll(images, shift, axis=2)
    maps = features_fn()(model(circular_width=True), jnp.concatenate([images, rolled_images]))
    for feature, stride in zip(maps, effnet.FEATURE_STRIDES, strict=True):
        original, rolled = feature[: SMALL[0]], feature[SMALL[0] :]
        np.testing.assert_allclose(jnp.roll(original, shift // stride, axis=2), rolled, atol=1e-4, rtol=1e-4)
    # zero padding does not have this property at the seam (same program as test_features_strides_and_channels)
    plain, plain_rolled = (features_fn()(model(), x)[0] for x in (images, rolled_images))
    assert not np.allclose(jnp.roll(plain, shift // 4, axis=2), plain_rolled, atol=1e-4)
