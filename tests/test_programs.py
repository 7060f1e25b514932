"""Traced programs saved with jax.export and called again without tracing."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncjax import programs


def forget():
    """Forget this process's programs, as a new process would."""
    programs._COMPILED.clear()
    programs._EXPORTED.clear()


def _traced_calls():
    calls = []

    def function(x, pair):
        calls.append(1)  # runs only while tracing
        return {"sum": x + pair[0], "product": x * pair[1], "none": None}

    return function, calls


def test_a_saved_program_is_called_without_tracing_again(tmp_path):
    function, calls = _traced_calls()
    x, pair = jnp.arange(3.0), (jnp.ones(3), jnp.float32(2.0))
    first = programs.call_saved(tmp_path, "k", function, x, pair)
    assert len(calls) == 1 and len(list(tmp_path.glob(f"*{programs.SUFFIX}"))) == 1
    forget()  # as a new process: only the file is left
    second = programs.call_saved(tmp_path, "k", function, x, pair)
    assert len(calls) == 1
    assert second["none"] is None
    np.testing.assert_array_equal(second["sum"], first["sum"])
    np.testing.assert_array_equal(second["product"], np.arange(3.0) * 2)


def test_other_shapes_keys_or_a_broken_file_are_traced_anew(tmp_path):
    function, calls = _traced_calls()
    pair = (jnp.ones(3), jnp.float32(2.0))
    programs.call_saved(tmp_path, "k", function, jnp.zeros(3), pair)
    programs.call_saved(tmp_path, "k", function, jnp.zeros(4), (jnp.ones(4), jnp.float32(2.0)))
    programs.call_saved(tmp_path, "other", function, jnp.zeros(3), pair)
    assert len(calls) == 3 and len(list(tmp_path.glob(f"*{programs.SUFFIX}"))) == 3
    path = programs.program_path(tmp_path, "k", (jnp.zeros(3), pair))
    path.write_bytes(b"not a program")
    forget()
    result = programs.call_saved(tmp_path, "k", function, jnp.full(3, 1.0), pair)
    assert len(calls) == 4
    np.testing.assert_array_equal(result["sum"], np.full(3, 2.0))


def test_an_unwritable_folder_still_gives_the_result(tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("")
    function, _ = _traced_calls()
    result = programs.call_saved(blocked / "programs", "k", function, jnp.ones(2), (jnp.ones(2), jnp.float32(3.0)))
    np.testing.assert_array_equal(result["product"], np.full(2, 3.0))
    assert jax.tree.structure(result) == jax.tree.structure({"sum": 0, "product": 0, "none": None})


def test_result_like_gives_the_result_shapes_without_running_it(tmp_path):
    function, calls = _traced_calls()
    x, pair = jax.ShapeDtypeStruct((3,), jnp.float32), (jnp.ones(3), jnp.float32(2.0))
    like = programs.result_like(tmp_path, "k", function, x, pair)
    assert like["sum"].shape == (3,) and like["product"].dtype == jnp.float32 and like["none"] is None
    path = programs.program_path(tmp_path, "k", (x, pair))
    assert not any(at == path for at, _ in programs._COMPILED)  # read from the program, not compiled
    forget()
    assert programs.result_like(tmp_path, "k", function, x, pair)["sum"].shape == (3,) and len(calls) == 1
    result = programs.load_saved(tmp_path, "k", function, x, pair)(jnp.arange(3.0), pair)
    np.testing.assert_array_equal(result["product"], np.arange(3.0) * 2)


def test_compiler_options_give_another_compilation_of_the_same_program(tmp_path):
    function, calls = _traced_calls()
    x, pair = jnp.arange(3.0), (jnp.ones(3), jnp.float32(2.0))
    plain = programs.load_saved(tmp_path, "k", function, x, pair)
    cheap = programs.load_saved(
        tmp_path, "k", function, x, pair, compiler_options={"xla_backend_optimization_level": 0}
    )
    path = programs.program_path(tmp_path, "k", (x, pair))
    compilations = [options for at, options in programs._COMPILED if at == path]
    assert len(calls) == 1 and sorted(compilations) == [(), (("xla_backend_optimization_level", 0),)]
    np.testing.assert_array_equal(cheap(x, pair)["product"], plain(x, pair)["product"])


class Box(eqx.Module):
    value: jax.Array


def test_a_result_that_would_not_survive_pickling_is_refused(tmp_path):
    with pytest.raises(TypeError, match="Python containers"):
        programs.call_saved(tmp_path, "k", lambda x: Box(x), jnp.ones(2))


def test_a_shipped_program_is_used_without_tracing(tmp_path, monkeypatch):
    function, calls = _traced_calls()
    x, pair = jnp.arange(3.0), (jnp.ones(3), jnp.float32(2.0))
    programs.call_saved(tmp_path / "package", "k", function, x, pair)
    forget()
    monkeypatch.setattr(programs, "SHIPPED_DIRECTORY", tmp_path / "package")
    result = programs.call_saved(tmp_path / "user", "k", function, x, pair)
    assert len(calls) == 1  # the user's folder is empty: the package's program was loaded, not traced
    np.testing.assert_array_equal(result["product"], np.arange(3.0) * 2)


def test_the_shipped_program_is_exported_from_these_sources():
    manifest = json.loads(programs.SHIPPED_MANIFEST.read_text())
    stale = "the shipped program is stale: run `uv run python experiments/export_default_program.py`"
    assert manifest["source_digest"] == programs.source_digest(), stale
    assert manifest["jax"] == jax.__version__, stale
    shipped = sorted(path.name for path in programs.SHIPPED_DIRECTORY.glob(f"*{programs.SUFFIX}"))
    assert shipped == sorted(manifest["programs"]) and len(shipped) == 6


def test_the_background_compilations_are_waited_for_before_the_process_ends():
    """What ``ncjax``'s console script waits for before ``os._exit``: the compilations a first run started for later
    runs (a compilation cut short leaves no marker, and every later run would start it again)."""
    import concurrent.futures
    import threading
    import time

    from ncjax import reconstruction

    assert reconstruction.finish_background_compilations() is False  # nothing started
    release = threading.Event()
    pool = concurrent.futures.ThreadPoolExecutor(1)
    compiling = pool.submit(lambda: release.wait(5.0))
    reconstruction._BACKGROUND.append(compiling)
    threading.Timer(0.2, release.set).start()
    started = time.perf_counter()
    assert reconstruction.finish_background_compilations() is True
    assert compiling.done() and time.perf_counter() - started >= 0.15 and not reconstruction._BACKGROUND
    pool.shutdown()


def test_a_first_process_compiles_cheaply_for_itself_and_optimised_for_the_next_ones(tmp_path, monkeypatch):
    """The geometry's two tiers (``ncjax.reconstruction``): without a process's marker, a route's programs compile with
    the cheap settings; the optimised ones of every asked route compile in the background, once, and inside
    ``background_compilations_deferred`` only at its end; with the markers, the optimised ones are loaded."""
    import ast
    import concurrent.futures
    import os

    from ncjax import reconstruction

    compiled = []

    def recording_load(directory, key, function, *args, compiler_options=None):
        program, *_, prior_kind = ast.literal_eval(key)
        compiled.append((program, prior_kind, compiler_options))
        return lambda *arguments: None

    class RunAtOnce:  # the background pool, synchronous
        def submit(self, function):
            future = concurrent.futures.Future()
            future.set_result(function())
            return future

    programs.use_compilation_cache(os.environ["NCJAX_CACHE"])  # what the CLI and the API switch on
    monkeypatch.setattr(reconstruction, "load_saved", recording_load)
    monkeypatch.setattr(reconstruction, "result_like", lambda *args: None)
    monkeypatch.setattr(reconstruction, "_LATER_POOL", RunAtOnce())
    monkeypatch.setattr(reconstruction, "_STARTED", set())
    route = reconstruction._Route(32, "threefry2x32", "auto", None)
    geometry = reconstruction._SavedGeometry(tmp_path, (1, 64), reconstruction.PipelineConfig(), route)
    cheap, optimised = reconstruction.CHEAP_GEOMETRY_COMPILER_OPTIONS, reconstruction.GEOMETRY_COMPILER_OPTIONS
    geometry.load(None)
    concurrent.futures.wait(geometry.programs[None])
    assert sorted(compiled, key=repr) == [("layouts", None, cheap), ("walls", None, cheap)]
    with reconstruction.background_compilations_deferred():
        geometry.prepare_later_processes((None, "camera_height"))
        assert len(compiled) == 2  # nothing starts inside the block
    assert sorted(compiled[2:], key=repr) == sorted(
        ((program, kind, optimised) for program in ("walls", "layouts") for kind in (None, "camera_height")), key=repr
    )
    geometry.prepare_later_processes((None, "camera_height"))
    assert len(compiled) == 6  # each started once a process
    assert reconstruction.finish_background_compilations() is False  # all done

    def optimised_before(*args, compiler_options=None):
        return compiler_options == optimised

    monkeypatch.setattr(reconstruction, "compiled_before", optimised_before)
    later = reconstruction._SavedGeometry(tmp_path, (1, 64), reconstruction.PipelineConfig(), route)
    later.load("camera_height")
    concurrent.futures.wait(later.programs["camera_height"])
    assert sorted(compiled[6:], key=repr) == [
        ("layouts", "camera_height", optimised),
        ("walls", "camera_height", optimised),
    ]
