"""Forward and training-step time of Non-central HorizonNet on the CPU (or whatever JAX sees).

    uv run python benchmarks/bench_network.py [--presets paper resnet18 compact]
        [--batches 1 4] [--repeats 3] [--train-presets compact resnet18]
        [--train-size 256 512] [--train-batch 4] [--skip-train]

Forward: eval mode, 512 x 1024 input for every preset; a preset built for
another size (compact: 256 x 512) is timed at its own size and also rebuilt
for 512 x 1024 (its LSTM input grows with the height). Training step:
forward + backward + AdamW update + augmentation, by default at 256 x 512,
batch 4. Times are the median and the best of ``--repeats`` runs after one
warm-up (compilation reported separately). Random weights (the
EfficientNet-Lite0 backbone's are ImageNet's): speed does not depend on them.
Never asserted in tests. The issue's PyTorch reference on the same 2-core
machine class: forward 1.72 s (ResNet-50) and 0.52 s (ResNet-18) at
512 x 1024 batch 1; ResNet-18 training step 1.8 s at 256 x 512 batch 4.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false")

import jax
import jax.numpy as jnp
from flax import nnx

from ncjax import HorizonNetConfig, TrainConfig
from ncjax.network import count_parameters, init_model
from ncjax.training.loop import make_optimizer, step_key_root, train_step


def timed(function, repeats):
    """Seconds of the first call (compilation included), then the median and the best of ``repeats`` calls."""
    start = time.perf_counter()
    jax.block_until_ready(function())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(function())
        times.append(time.perf_counter() - start)
    return first, statistics.median(times), min(times)


def forward_time(config, batch, repeats):
    model = init_model(config)
    model.eval()
    forward = nnx.jit(lambda m, x: m(x))
    images = jax.random.uniform(jax.random.PRNGKey(0), (batch, config.input_height, config.input_width, 3))
    return timed(lambda: forward(model, images), repeats)


def train_step_time(config, batch, repeats):
    model = init_model(config)
    train_config = TrainConfig()
    optimizer = make_optimizer(model, train_config)
    key = jax.random.PRNGKey(0)
    data = {
        "image": jax.random.uniform(key, (batch, config.input_height, config.input_width, 3)),
        "ceiling_v": jnp.full((batch, config.input_width), config.input_height * 0.3),
        "floor_v": jnp.full((batch, config.input_width), config.input_height * 0.7),
        "corner_target": jnp.full((batch, config.input_width), 0.1),
    }
    step = iter(range(10**6))
    return timed(
        lambda: train_step(model, optimizer, data, jax.random.fold_in(step_key_root(0), next(step)), train_config),
        repeats,
    )


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["paper", "resnet18", "compact"])
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--train-presets", nargs="+", default=["compact", "resnet18"])
    parser.add_argument("--train-size", nargs=2, type=int, default=[256, 512], metavar=("HEIGHT", "WIDTH"))
    parser.add_argument("--train-batch", type=int, default=4)
    parser.add_argument("--skip-train", action="store_true")
    args = parser.parse_args()
    print(f"jax {jax.__version__}, devices {jax.devices()}, XLA_FLAGS={os.environ.get('XLA_FLAGS')}")
    for name in args.presets:
        config = HorizonNetConfig.preset(name)
        print(f"{name}: {count_parameters(config):,} parameters", flush=True)
        sizes = {(512, 1024)} | {(config.input_height, config.input_width)}
        for height, width in sorted(sizes, reverse=True):
            sized = dataclasses.replace(config, input_height=height, input_width=width)
            for batch in args.batches:
                compile_s, median, best = forward_time(sized, batch, args.repeats)
                print(
                    f"forward {name:8s} {height}x{width} batch {batch}: median {median:.3f} s, best {best:.3f} s "
                    f"(first call {compile_s:.1f} s)",
                    flush=True,
                )
    if not args.skip_train:
        height, width = args.train_size
        for name in args.train_presets:
            config = dataclasses.replace(HorizonNetConfig.preset(name), input_height=height, input_width=width)
            compile_s, median, best = train_step_time(config, args.train_batch, args.repeats)
            print(
                f"train step {name:8s} {height}x{width} batch {args.train_batch}: median {median:.3f} s, "
                f"best {best:.3f} s (first call {compile_s:.1f} s)",
                flush=True,
            )


if __name__ == "__main__":
    main()
