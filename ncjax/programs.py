"""Traced programs kept on disk with ``jax.export``, so that a later process skips tracing.

Tracing the reconstruction (the network and both worlds' geometry, tens of
thousands of operations) takes about 10 s on 2 CPU cores in every new
process, even when XLA's persistent compilation cache
(:func:`ncjax.cli.compilation.enable_compilation_cache`) holds the compiled
program. :func:`call_saved` exports a function's traced program (StableHLO)
once into a folder; a later process deserializes it in well under a second,
and the compilation cache spares it the compiler as well. The package ships
the programs of ``ncjax reconstruct``'s default settings for a 1024 x 512
panorama (:data:`SHIPPED_DIRECTORY`, written by
``experiments/export_default_program.py``), so that even a first run skips
their tracing. :func:`load_saved` compiles (or loads) a program before its
call, so that programs can be loaded in threads at once: XLA loads each on
one core.

By default (:func:`user_program_directory`) the programs live in the user's cache folder, beside XLA's
compilation cache (``$NCJAX_CACHE``, default ``~/.cache/ncjax/xla``; ``NCJAX_CACHE=off`` switches both off).

A saved program is named by the caller's key, the arguments' shapes, dtypes
and tree, the versions of jax and jaxlib, the backend and a digest of
ncjax's own sources, so that a program traced by other code is never reused.
The files are Python pickles (the argument and result trees): like XLA's
cache, the folder must be the user's own.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib
import pickle
import zlib
from collections.abc import Callable
from typing import Any

import jax

from .io.files import write_atomic

SUFFIX = ".jaxexport"
# the programs the package carries; a name not found there is traced as usual
SHIPPED_DIRECTORY = pathlib.Path(__file__).parent / "data" / "programs"
# what the shipped programs were exported from: jax's version and source_digest()
SHIPPED_MANIFEST = SHIPPED_DIRECTORY / "manifest.json"
# NCJAX_CACHE's values that switch the user's caches off
CACHE_OFF = ("off", "none", "0", "false")


def user_cache_directory() -> str | None:
    """XLA's compilation cache of ncjax: ``$NCJAX_CACHE``, default ``~/.cache/ncjax/xla``; None when it says off."""
    directory = os.environ.get("NCJAX_CACHE", os.path.join(os.path.expanduser("~"), ".cache", "ncjax", "xla"))
    return None if directory.strip().lower() in CACHE_OFF else directory


def user_program_directory(enable_compilation_cache: bool = False) -> str | None:
    """The traced programs' folder beside :func:`user_cache_directory` (None when the caches are off).

    Args:
        enable_compilation_cache: also keep XLA's compiled programs in :func:`user_cache_directory`, unless jax's
            ``jax_compilation_cache_dir`` is already set (the user's own cache is kept).
    """
    directory = user_cache_directory()
    if directory is None:
        return None
    if enable_compilation_cache and not jax.config.jax_compilation_cache_dir:
        use_compilation_cache(directory)
    return os.path.join(directory, "programs")


def use_compilation_cache(directory: str) -> None:
    """Keep XLA's compiled programs in ``directory`` across processes, the small ones too (compiling them again
    costs a warm start more than reading them)."""
    jax.config.update("jax_compilation_cache_dir", directory)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


@functools.cache
def source_digest() -> str:
    """SHA-256 of ncjax's Python sources."""
    root = pathlib.Path(__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def program_path(directory: str | os.PathLike, key: str, args: tuple) -> pathlib.Path:
    """Where the program of ``key`` for arguments like ``args`` is saved."""
    leaves, tree = jax.tree.flatten(args)
    signature = [(tuple(x.shape), str(x.dtype)) for x in leaves]
    text = repr((key, str(tree), signature, jax.__version__, jax.lib.__version__, jax.default_backend()))
    name = hashlib.sha256((text + source_digest()).encode()).hexdigest()[:24]
    return pathlib.Path(directory) / f"{name}{SUFFIX}"


def call_saved(directory: str | os.PathLike, key: str, function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)``, run through its traced program saved in ``directory``: :func:`load_saved`, then the call.

    Raises:
        TypeError: ``function``'s result is not made of Python's own containers.
    """
    return load_saved(directory, key, function, *args)(*args)


def load_saved(
    directory: str | os.PathLike,
    key: str,
    function: Callable[..., Any],
    *args: Any,
    compiler_options: dict[str, Any] | None = None,
) -> Callable[..., Any]:
    """``function`` for arguments like ``args``, compiled from its traced program saved in ``directory``.

    The program is loaded when a process saved it before (:func:`program_path`)
    or the package ships it (:data:`SHIPPED_DIRECTORY`), else traced, exported
    and saved (a folder that cannot be written only costs the next process the
    tracing again), and compiled (or loaded from XLA's cache) here, before any
    call: another thread may load a program while this one runs another one.

    Args:
        directory: the folder of the saved programs.
        key: what else ``function`` depends on (static settings), as text.
        function: a function of pytrees of arrays, traceable by ``jax.jit``, that returns Python's own
            containers (tuples, lists, dicts, None) of arrays: the result's tree is pickled, and a custom
            pytree node (an ``equinox.Module``, say) may not come back the same.
        *args: its arguments: pytrees whose leaves are arrays or ``jax.ShapeDtypeStruct``.
        compiler_options: XLA's options for this compilation (``jax.stages.Lowered.compile``'s), part of
            the compilation cache's key.

    Returns:
        A function of arguments of the same trees, shapes and dtypes as ``args`` that returns what
        ``function`` returns.

    Raises:
        TypeError: ``function``'s result is not made of Python's own containers.
    """
    path = program_path(directory, key, args)
    options = tuple(sorted((compiler_options or {}).items()))
    if (path, options) not in _COMPILED:
        exported, out_tree = _exported_program(path, function, args)
        lowered = jax.jit(exported.call).lower(*exported.in_avals)
        _COMPILED[path, options] = lowered.compile(compiler_options=compiler_options), out_tree
        if jax.config.jax_compilation_cache_dir:  # the compiled program outlives this process: say so
            _save_marker(_compiled_marker(path, options))
    compiled, out_tree = _COMPILED[path, options]

    def call(*arguments: Any) -> Any:
        return jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(arguments)))

    return call


def compiled_before(
    directory: str | os.PathLike, key: str, *args: Any, compiler_options: dict[str, Any] | None = None
) -> bool:
    """Whether a process compiled :func:`load_saved`'s program of these arguments and options with XLA's
    persistent cache on (a marker beside the saved programs; the cache itself may have been emptied since)."""
    options = tuple(sorted((compiler_options or {}).items()))
    return _compiled_marker(program_path(directory, key, args), options).exists()


def _compiled_marker(path: pathlib.Path, options: tuple) -> pathlib.Path:
    digest = hashlib.sha256(repr(options).encode()).hexdigest()[:8]
    return path.with_name(f"{path.stem}.{digest}.compiled")


def _save_marker(path: pathlib.Path) -> None:
    try:
        os.makedirs(path.parent, exist_ok=True)
        path.touch()
    except OSError:
        pass  # a folder that cannot be written: a later process compiles in the background again


def result_like(directory: str | os.PathLike, key: str, function: Callable[..., Any], *args: Any) -> Any:
    """The shapes and dtypes of what :func:`load_saved`'s program returns, as ``jax.ShapeDtypeStruct`` leaves.

    Read from the saved program without compiling it (traced and saved first if there is none): the next
    program's arguments can be loaded before this one runs.
    """
    exported, out_tree = _exported_program(program_path(directory, key, args), function, args)
    return jax.tree.unflatten(out_tree, [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in exported.out_avals])


def _exported_program(path: pathlib.Path, function: Callable[..., Any], args: tuple) -> tuple[Any, Any]:
    """The program at ``path``: this process's, the user's, the package's, or traced and saved now."""
    if path not in _EXPORTED:
        saved = _load(path)
        if saved is None:
            saved = _load(SHIPPED_DIRECTORY / path.name)
        if saved is None:
            leaves, in_tree = jax.tree.flatten(args)
            saved = _export(function, in_tree, leaves)
            _save(path, *saved)
        _EXPORTED[path] = saved
    return _EXPORTED[path]


# the programs this process has loaded or exported: path -> (jax.export.Exported, result tree)
_EXPORTED: dict[pathlib.Path, tuple[Any, Any]] = {}
# the programs this process has compiled: (path, compiler options) -> (compiled program, result tree)
_COMPILED: dict[tuple[pathlib.Path, tuple], tuple[Any, Any]] = {}


def _export(function, in_tree, leaves) -> tuple[jax.export.Exported, Any]:
    out_trees = []

    def flat(*flat_args):
        leaves_out, out_tree = jax.tree.flatten(function(*jax.tree.unflatten(in_tree, flat_args)))
        out_trees.append(out_tree)
        return leaves_out

    exported = jax.export.export(jax.jit(flat))(*leaves)
    try:
        survives = pickle.loads(pickle.dumps(out_trees[0])) == out_trees[0]
    except (pickle.PicklingError, AttributeError, TypeError):
        survives = False
    if not survives:
        raise TypeError(f"a saved program must return Python containers of arrays, not {out_trees[0]}")
    return exported, out_trees[0]


def _save(path: pathlib.Path, exported: jax.export.Exported, out_tree: Any) -> None:
    """Write a program for :func:`_load`; a folder that cannot be written is left as it is."""
    try:
        os.makedirs(path.parent, exist_ok=True)
        write_atomic(str(path), zlib.compress(pickle.dumps((bytes(exported.serialize()), out_tree))))
    except OSError:
        pass


def _load(path: pathlib.Path) -> tuple[jax.export.Exported, Any] | None:
    """The saved program at ``path``, or None when there is none or it cannot be read."""
    try:
        with open(path, "rb") as file:
            serialized, out_tree = pickle.loads(zlib.decompress(file.read()))
        return jax.export.deserialize(bytearray(serialized)), out_tree
    except Exception:  # a missing, truncated or foreign file is traced again, whatever broke
        return None
