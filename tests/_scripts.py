"""Test helper: the repository's scripts (``benchmarks/``, ``experiments/``) imported as modules."""

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).parents[1]


def script_module(folder: str, name: str):
    """The module of ``<folder>/<name>.py``, loaded once and registered in ``sys.modules`` (so that its
    dataclasses resolve). The folder goes first on ``sys.path``, as Python puts a script's folder when it runs
    one, so that the script imports its neighbours (``experiments/common.py``) by name."""
    if name not in sys.modules:
        path = ROOT / folder / f"{name}.py"
        if str(path.parent) not in sys.path:
            sys.path.insert(0, str(path.parent))
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]
