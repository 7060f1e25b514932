"""Rooms + exact labels generated per second (batched, jit(vmap)), on this machine.

uv run python benchmarks/bench_rooms.py [--batch 256] [--width 1024] [--height 512]
"""

import argparse
import time

import jax
import numpy as np

import ncjax


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=512)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"jax {jax.__version__} on {jax.devices()[0].platform}, batch {args.batch}, {args.width}x{args.height}")
    for world in ("manhattan", "atlanta", "mix"):
        config = ncjax.RoomConfig(world=world)

        def rooms_and_labels(key):
            room = ncjax.synth.random_room(key, config)
            return room, ncjax.synth.room_labels(room, room.camera(args.width, args.height))

        generate = jax.jit(jax.vmap(rooms_and_labels))
        keys = jax.random.split(jax.random.key(0), args.batch)
        start = time.perf_counter()
        jax.block_until_ready(generate(keys))
        compile_s = time.perf_counter() - start
        times = []
        for repeat in range(args.repeats):
            keys = jax.random.split(jax.random.key(repeat + 1), args.batch)
            start = time.perf_counter()
            rooms, labels = jax.block_until_ready(generate(keys))
            times.append(time.perf_counter() - start)
        best = min(times)
        ok = float(np.mean(np.asarray(labels.ok)))
        print(
            f"{world:9s}: {args.batch / best:8.1f} rooms+labels/s (best of {args.repeats}, median "
            f"{args.batch / np.median(times):.1f}), compile {compile_s:.1f} s, ok {ok:.3f}"
        )


if __name__ == "__main__":
    main()
