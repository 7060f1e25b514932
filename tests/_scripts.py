"""Test helper: the repository's scripts (``benchmarks/``, ``experiments/``) imported as modules."""

import importlib.util
import sys
from pathlib import Path


def script_module(folder: str, name: str):
    """The module of ``<folder>/<name>.py``, loaded once and registered in ``sys.modules`` (so that its
    dataclasses resolve)."""
    if name not in sys.modules:
        path = Path(__file__).parents[1] / folder / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]
