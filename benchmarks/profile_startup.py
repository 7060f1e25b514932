"""Where a warm ``ncjax reconstruct`` spends its time, and whether loading its compiled program uses both cores.

Fills a compilation cache with one ``ncjax reconstruct`` of the demo panorama (default settings, a new
process), then runs the same command in this process with that cache and prints:

- the seconds until the command starts (imports) and of the whole command;
- each compiled program loaded from XLA's cache that took 10 ms or more, with its wall and CPU seconds;
- for the largest one, one load and two concurrent loads (threads) of the same cache entry, wall and
  CPU seconds: a load that runs on one core takes about as long twice at once, with twice the CPU.

The loads are timed by wrapping ``jax._src.compilation_cache.get_executable_and_time``, a private
function of jax (0.10): the script fails clearly if it moves.

    uv run python benchmarks/profile_startup.py [--cache DIR]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time

START = time.perf_counter()

from ncjax.cli.demo import DEMO_DIR  # noqa: E402
from ncjax.cli.main import main as ncjax_main  # noqa: E402

IMPORTED = time.perf_counter()


def timed(function, *args, **kwargs):
    """``function(*args, **kwargs)`` and its wall and CPU seconds."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def concurrent_loads(load, count: int, *args, **kwargs) -> tuple[float, float]:
    """Wall and CPU seconds of ``count`` calls of ``load`` at once, one thread each."""
    threads = [threading.Thread(target=load, args=args, kwargs=kwargs) for _ in range(count)]

    def run():
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()

    _, wall, cpu = timed(run)
    return wall, cpu


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", help="the compilation cache to fill and use (default: a new temporary one)")
    args = parser.parse_args(argv)
    from jax._src import compilation_cache

    load = getattr(compilation_cache, "get_executable_and_time", None)
    if load is None:
        raise SystemExit("jax._src.compilation_cache.get_executable_and_time is gone: update this script")
    image = str(next(DEMO_DIR.glob("*.png")))
    with tempfile.TemporaryDirectory() as work:
        cache = args.cache or os.path.join(work, "cache")
        command = ["reconstruct", image, "--rc", "auto", "--out", os.path.join(work, "out")]
        print("filling the cache (one ncjax reconstruct in a new process) ...", flush=True)
        environment = os.environ | {"NCJAX_CACHE": cache}
        subprocess.run([sys.executable, "-m", "ncjax.cli", *command], env=environment, check=True, capture_output=True)
        os.environ["NCJAX_CACHE"] = cache
        loads = []

        def load_and_time(cache_key, *rest, **kwargs):
            result, wall, cpu = timed(load, cache_key, *rest, **kwargs)
            loads.append((cache_key, wall, cpu, rest, kwargs))
            return result

        compilation_cache.get_executable_and_time = load_and_time
        try:
            _, total, _ = timed(ncjax_main, command)
        finally:
            compilation_cache.get_executable_and_time = load
        print(f"imports: {IMPORTED - START:.2f} s; the command: {total:.2f} s (the process's exit not included)")
        print("compiled programs loaded from the cache (wall / CPU s):")
        for key, wall, cpu, _, _ in loads:
            if wall >= 0.01:
                print(f"  {key.split('-')[0]}: {wall:.2f} / {cpu:.2f}")
        small = [entry for entry in loads if entry[1] < 0.01]
        print(f"  and {len(small)} small ones, {sum(entry[1] for entry in small):.3f} s in all")
        key, _, _, rest, kwargs = max(loads, key=lambda entry: entry[1])
        print(f"the largest, {key.split('-')[0]}, loaded again (wall / CPU s):")
        for count in (1, 2, 1, 2):
            wall, cpu = concurrent_loads(load, count, key, *rest, **kwargs)
            print(f"  {count} at once: {wall:.2f} / {cpu:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
