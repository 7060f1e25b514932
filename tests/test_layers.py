"""The package's layering: each module imports from its own floor or lower, and no modules import each other in a
cycle. Read from the sources (``ast``), imports inside functions included; nothing is imported."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).parents[1] / "ncjax"

# The floors of the house, lowest first: a module may import from its own floor or a lower one, never a higher one.
# A module's floor is its subpackage's; the top-level modules (the package's __init__, reconstruction, programs) are
# the public API.
FLOORS = {
    "geometry": 1,  # camera, Plücker lines, linear algebra, gravity, panorama levelling
    "solvers": 2,  # walls and layouts from rays
    "pipeline": 3,  # rows -> walls -> layout
    "network": 4,  # image -> rows
    "io": 5,  # files in and out: images, JSON, meshes, formats
    "viz": 6,  # pictures of a layout
    "synth": 7,  # synthetic rooms and their renders
    "evaluation": 8,  # every metric, and the real-panorama benchmark's scoring
    "training": 9,  # the network's training
    "api": 10,  # ncjax/__init__.py, reconstruction.py, programs.py
    "cli": 11,  # the ncjax command
}
API_MODULES = ("ncjax", "ncjax.reconstruction", "ncjax.programs")


def module_name(path: Path) -> str:
    """``ncjax/pipeline/corners.py`` -> ``ncjax.pipeline.corners``; a package's ``__init__.py`` is the package."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path): path for path in sorted(PACKAGE.rglob("*.py"))}


def floor_name(module: str) -> str:
    """The floor of a module of the package, by its subpackage (the API for the top-level modules)."""
    if module in API_MODULES:
        return "api"
    parts = module.split(".")
    assert len(parts) > 1 and parts[1] in FLOORS, f"{module} is on no floor of FLOORS"
    return parts[1]


def imported_modules(module: str) -> set[str]:
    """The package's modules that ``module`` imports anywhere in its source: a name imported from a package is its
    submodule where one of that name exists, else the package."""
    package = module if MODULES[module].name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(MODULES[module].read_text(), str(MODULES[module]))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{base}" if base else anchor
            found |= {f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names}
    return {name for name in found if name in MODULES and name != module}


IMPORTS = {module: imported_modules(module) for module in MODULES}


def test_every_module_imports_from_its_own_floor_or_lower():
    upward = [
        f"{module} (floor {FLOORS[floor_name(module)]} {floor_name(module)}) imports {target} "
        f"(floor {FLOORS[floor_name(target)]} {floor_name(target)})"
        for module, targets in IMPORTS.items()
        for target in sorted(targets)
        if FLOORS[floor_name(target)] > FLOORS[floor_name(module)]
    ]
    assert not upward, "imports from a higher floor:\n" + "\n".join(upward)


def import_cycles() -> list[list[str]]:
    """The modules that import each other in a cycle, one group per strongly connected component (Tarjan)."""
    index, low, stack, on_stack, groups = {}, {}, [], set(), []

    def visit(module):
        index[module] = low[module] = len(index)
        stack.append(module)
        on_stack.add(module)
        for target in sorted(IMPORTS[module]):
            if target not in index:
                visit(target)
                low[module] = min(low[module], low[target])
            elif target in on_stack:
                low[module] = min(low[module], index[target])
        if low[module] == index[module]:
            group = []
            while not group or group[-1] != module:
                group.append(stack.pop())
                on_stack.discard(group[-1])
            if len(group) > 1:
                groups.append(sorted(group))

    for module in sorted(IMPORTS):
        if module not in index:
            visit(module)
    return groups


def test_no_modules_import_each_other_in_a_cycle():
    cycles = import_cycles()
    assert not cycles, "modules that import each other in a cycle:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_import_reader_resolves_relative_and_absolute_imports():
    assert {
        "ncjax.evaluation.layout_metrics",  # from . import layout_metrics
        "ncjax.evaluation.panorama_labels",  # from .panorama_labels import ...
        "ncjax.pipeline.corners",  # from ..pipeline.corners import ...
    } <= IMPORTS["ncjax.evaluation.panorama_scores"]
    assert "ncjax.geometry.camera" in IMPORTS["ncjax"]
    assert all(floor_name(module) for module in MODULES)


def test_every_import_of_the_package_names_one_of_its_modules():
    """A relative import that names no module (``from .synth import x`` in a subpackage without one) fails only when
    it runs: inside a function, late."""
    dangling = []
    for module, path in MODULES.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level:
                anchor = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                base = f"{anchor}.{node.module}" if node.module else anchor
                if base not in MODULES:
                    dangling.append(f"{module}: from {'.' * node.level}{node.module or ''} import ...")
    assert not dangling, "imports of modules that do not exist:\n" + "\n".join(dangling)


def test_a_reconstruction_s_imports_leave_out_the_network_s_and_the_training_s_libraries():
    """What a new process imports before its first layout through saved programs: neither Flax (the network is built
    only to trace its program) nor the training, synthetic-data or evaluation code; checked in a new interpreter."""
    import subprocess
    import sys

    script = """
import sys
import ncjax
from ncjax.cli.main import build_parser
build_parser("reconstruct")
ncjax.reconstruct_batch, ncjax.HorizonNetConfig, ncjax.EdgeSnap
from ncjax.network.weights import DEFAULT_MODEL_PATH, read_weights
read_weights(DEFAULT_MODEL_PATH)
left_out = ("flax", "optax", "ncjax.training", "ncjax.synth", "ncjax.evaluation")
print(sorted(name for name in left_out if name in sys.modules))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout
    lazy = subprocess.run(
        [sys.executable, "-c", "import sys, ncjax; ncjax.HorizonNet; print('flax' in sys.modules)"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert lazy.stdout.strip() == "True"  # the network's names are there, imported on first use


def test_training_s_imports_leave_out_the_layouts_libraries():
    """``ncjax train`` runs where only the training's packages are (an accelerator's image without shapely, trimesh
    or manifold3d): its command, data, loop and model files import none of them; checked in a new interpreter."""
    import subprocess
    import sys

    script = """
import sys
from ncjax.cli.main import build_parser
build_parser("train")
import ncjax.cli.train, ncjax.training.data, ncjax.training.loop, ncjax.network.checkpoint, ncjax.synth.photoreal
print(sorted(name for name in ("shapely", "trimesh", "manifold3d") if name in sys.modules))
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout
