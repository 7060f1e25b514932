"""Shared test setup.

- Runtime shape/dtype checking of every public ``ncjax`` function through
  jaxtyping + beartype (the annotations are part of the contract).
- ``x64`` fixture: float64 only for the tests that need it.
- Hypothesis profile sized for 2-core CI machines.
- XLA's LLVM backend at -O0: the suite's time is mostly compilation.
- A private XLA compilation cache per process (pytest-xdist runs two): the CLI
  tests switch on the persistent cache (``ncjax.cli.compilation.enable_compilation_cache``)
  for the rest of the session; entries of other runs (other flags, a concurrent
  writer) must not be read back.
"""

import atexit
import gc
import os
import shutil
import tempfile

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# OpenBLAS worker threads busy-wait for each other: on a loaded 2-core machine one
# small LAPACK call can then take seconds. Must be set before jax loads OpenBLAS.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# The suite's time is mostly XLA compilation: LLVM at -O0 compiles about a third faster
# (tests/test_wall.py 141 -> 96 s, the whole suite 18-20 -> 15 min) and every test passes
# as at -O2; timings are measured by benchmarks/, never here.
if "xla_backend_optimization_level" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} --xla_backend_optimization_level=0".strip()
os.environ["NCJAX_CACHE"] = tempfile.mkdtemp(prefix="ncjax-test-xla-")
atexit.register(shutil.rmtree, os.environ["NCJAX_CACHE"], ignore_errors=True)

import jax
import pytest
from hypothesis import HealthCheck, settings
from jaxtyping import install_import_hook

with install_import_hook("ncjax", "beartype.beartype"):
    import ncjax  # noqa: F401  (imported under the type-checking hook)

settings.register_profile(
    "ncjax",
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    derandomize=True,
)
settings.load_profile("ncjax")


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """Drop each test module's compiled programs when it ends.

    The suite compiles hundreds of XLA programs (the pipeline alone in
    several worlds, slot counts and batch sizes); kept for the whole session
    they made a 2-core CI run abort inside XLA's compiler in the last modules.
    """
    yield
    _drop_compiled_programs()


def _drop_compiled_programs():
    jax.clear_caches()
    gc.collect()


def _memory_maps() -> int:
    """Memory mappings of this process (0 where /proc is not available)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


@pytest.fixture(autouse=True)
def _release_compiled_programs_near_the_map_limit():
    """Drop the compiled programs after a test that leaves the process near Linux's limit of 65,530
    memory mappings (``vm.max_map_count``): every compiled XLA program holds some, XLA crashes at the
    limit, and tests/test_pipeline.py alone reached 62,000."""
    yield
    if _memory_maps() > 45_000:
        _drop_compiled_programs()


@pytest.fixture
def x64():
    """Run the test with 64-bit floats enabled."""
    with jax.enable_x64(True):
        yield


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items):
    """An ``extended`` test is also ``slow``: the fast tier (``-m 'not slow'``) leaves it out too."""
    for item in items:
        if item.get_closest_marker("extended"):
            item.add_marker(pytest.mark.slow)
