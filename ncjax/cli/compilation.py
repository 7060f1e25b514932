"""XLA's persistent compilation cache for the CLI, and telling the user when a run will compile.

The first ``ncjax reconstruct`` with a given image size, batch and settings traces and compiles its
programs (the network's and the geometry's two halves): on 2 CPU cores 20 s to a minute (the
package ships the traced programs of the default settings for 1024 x 512 panoramas, so those only
compile), more than all the rest of the run. Later runs load the traced programs (:mod:`ncjax.programs`)
and the compiled ones from the cache. :class:`CompileLedger` remembers, beside the
cache, which settings this machine has compiled and how long the first call took, so that a run
which is about to compile says so and for about how long, instead of a progress bar at 0%.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import statistics
import time
from collections.abc import Callable, Iterator

from ..io.files import write_atomic

LEDGER_FILE = "ncjax-compiled.json"
# what a first run takes when this machine has no record yet: the default programs on 2 CPU cores
FIRST_RUN_GUESS = "20 s to a minute on 2 CPU cores"


def enable_compilation_cache() -> str | None:
    """Keep XLA's compiled programs in :func:`~ncjax.programs.user_cache_directory` across runs, even where jax's
    cache folder was set otherwise; returns the directory (None: ``NCJAX_CACHE=off``).

    Compilation is most of a first run's time; the persistent cache spares later runs with the same
    image size, batch and settings the compilation; the programs saved in :func:`~ncjax.programs.user_program_directory`
    spare them the tracing.
    """
    from ..programs import use_compilation_cache, user_cache_directory

    directory = user_cache_directory()
    if directory is not None:
        use_compilation_cache(directory)
    return directory


def settings_key(*parts: object) -> str:
    """A short stable key of the settings a program depends on (their ``repr``, with jax's version and the digest
    of ncjax's sources: changed sources trace the program again, and the run then says so)."""
    import jax

    from ..programs import source_digest

    text = repr((source_digest(), jax.__version__, *parts))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class CompileLedger:
    """``{settings key: seconds of the first call}`` of the programs this machine compiled, in the cache folder.

    A missing or unreadable ledger is an empty one: it only decides what the CLI says.
    """

    def __init__(self, directory: str | None):
        self.path = None if directory is None else os.path.join(directory, LEDGER_FILE)
        try:
            if self.path is None:
                raise OSError("the caches are off")
            with open(self.path, encoding="utf-8") as file:
                self.seconds = {str(k): float(v) for k, v in json.load(file).items()}
        except (OSError, ValueError, AttributeError):
            self.seconds = {}

    def notice(self, key: str, what: str) -> str | None:
        """The line to print before a call that compiles ``what`` (None when this machine compiled it before)."""
        if key in self.seconds:
            return None
        # the median first call: one long outlier (a large batch, say) does not make every estimate long
        estimate = f"about {statistics.median(self.seconds.values()):.0f} s here" if self.seconds else FIRST_RUN_GUESS
        return f"compiling {what} (first run with these settings only; {estimate})"

    @contextlib.contextmanager
    def compiling(self, key: str, what: str, say: Callable[[str], object]) -> Iterator[None]:
        """Around the first call of a program: ``say`` the :meth:`notice` if any, then :meth:`record` the
        call's seconds once it returns (a call that raises is not recorded)."""
        notice = self.notice(key, what)
        if notice:
            say(notice)
        started = time.perf_counter()
        yield
        self.record(key, time.perf_counter() - started)

    def record(self, key: str, seconds: float) -> None:
        """Remember that the program of ``key`` is compiled; its first call took ``seconds``."""
        if key in self.seconds:
            return
        self.seconds[key] = round(seconds, 1)
        if self.path is None:
            return
        try:
            os.makedirs(os.path.dirname(self.path), exist_ok=True)
            write_atomic(self.path, json.dumps(self.seconds, indent=1).encode())
        except OSError:
            pass  # a read-only cache folder: the next run prints the notice again, nothing worse
