"""Traced programs kept on disk (traced.py): the same numbers as the plain call, and safe fallbacks."""

from __future__ import annotations

import contextlib
import contextvars
import functools
import pickle
import shutil
import threading
import time
import zlib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drivecal as dc
from drivecal.model import _lowered_cache as traced
from drivecal.model import ahead_of_need, outputs_unused, side_by_side

_DIRECTORY = traced.directory


@pytest.fixture()
def store(tmp_path, monkeypatch):
    """An empty store of traced programs; ``_LOADED`` cleared as in a new process."""
    monkeypatch.setattr(traced, "directory", lambda: tmp_path)
    monkeypatch.setattr(traced, "_LOADED", {})
    return tmp_path


@jax.jit
def _f(x, y, *, scale):
    return {"a": jnp.sin(x) * scale + y[0], "b": (jnp.cumsum(y), None)}


def test_kept_program_gives_the_plain_numbers_and_is_reused(store, monkeypatch):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    plain = _f(x, y, scale=2.5)
    first = traced.call(_f, "f", x, y, scale=2.5)
    assert len(list(store.glob("f-*.pkl"))) == 1
    monkeypatch.setattr(traced, "_LOADED", {})  # a new process: loads the program, does not trace
    monkeypatch.setattr(traced, "_export", lambda *a, **k: pytest.fail("traced again"))
    again = traced.call(_f, "f", x, y, scale=2.5)
    for out in (first, again):
        np.testing.assert_array_equal(out["a"], plain["a"])
        np.testing.assert_array_equal(out["b"][0], plain["b"][0])
        assert out["b"][1] is None


def _kept_executable(path: Path):
    return pickle.loads(zlib.decompress(path.read_bytes()))[2]


def test_a_kernel_compiled_here_is_kept_and_a_new_process_runs_it_without_lowering(store, monkeypatch):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    plain = _f(x, y, scale=2.5)
    traced.call(_f, "f", x, y, scale=2.5)
    (path,) = store.glob("f-*.pkl")
    assert _kept_executable(path) is not None
    monkeypatch.setattr(traced, "_LOADED", {})  # a new process
    monkeypatch.setattr(traced, "_runner", lambda *a: pytest.fail("lowered the program again"))
    again = traced.call(_f, "f", x, y, scale=2.5)
    np.testing.assert_array_equal(again["a"], plain["a"])
    np.testing.assert_array_equal(again["b"][0], plain["b"][0])


def test_calls_whose_outputs_are_unused_get_their_kernel_ready_and_run_none(store, monkeypatch):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    plain = _f(x, y, scale=2.5)
    with outputs_unused():  # compiled here, not run: zeros of the outputs' shapes and dtypes
        ready = traced.call(_f, "f", x, y, scale=2.5)
    assert ready["a"].shape == (50,) and ready["a"].dtype == np.float64 and not ready["a"].any()
    assert ready["b"][0].shape == (4,) and ready["b"][1] is None
    monkeypatch.setattr(traced, "_export", lambda *a, **k: pytest.fail("traced again"))
    np.testing.assert_array_equal(traced.call(_f, "f", x, y, scale=2.5)["a"], plain["a"])  # ready: runs now
    monkeypatch.setattr(traced, "_LOADED", {})  # a new process: loads the kept kernel and runs none of it
    with outputs_unused():
        assert not traced.call(_f, "f", x, y, scale=2.5)["b"][0].any()
    np.testing.assert_array_equal(traced.call(_f, "f", x, y, scale=2.5)["b"][0], plain["b"][0])


_CACHE_HIT_SCRIPT = """
import shutil, sys
import jax, jax.numpy as jnp, numpy as np
from drivecal.model import _lowered_cache as traced

@jax.jit
def f(x):
    return {"a": jnp.sin(x) * 2.0 + jnp.cumsum(x)}

x = np.linspace(0.0, 3.0, 50)
plain = np.asarray(f(x)["a"])
folder = traced.directory()
traced.call(f, "f", x)  # compiled here: the kernel goes to the compilation cache, the executable is kept
shutil.rmtree(folder)  # as after an upgrade of drivecal: its programs go, the compilation cache stays
traced._LOADED.clear(); jax.clear_caches()
serialize, hits = traced._serialize, []
traced._serialize = lambda compiled, hit: (hits.append(hit), serialize(compiled, hit))[1]
first = traced.call(f, "f", x)  # traced again, its kernel a compilation-cache hit
assert len(hits) == 1 and hits[0] is not None, hits
traced._LOADED.clear(); jax.clear_caches()
traced._runner = lambda *a: sys.exit("lowered the program again")
again = traced.call(f, "f", x)
assert all(entry is not None for entry in traced._LOADED.values()), "the kept executable failed"
np.testing.assert_array_equal(np.asarray(first["a"]), plain)
np.testing.assert_array_equal(np.asarray(again["a"]), plain)
print("kept and ran")
"""


def test_a_kernel_the_compilation_cache_supplied_is_kept_with_the_cache_s_bytes(tmp_path):
    """jaxlib 0.9 serialises an executable loaded from the compilation cache without its code (it fails when
    run): where the kernel was a cache hit, the bytes the cache read are kept, and a later process runs them
    without lowering (a fresh process with the caches on, as a user's)."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path)}
    done = subprocess.run([sys.executable, "-c", _CACHE_HIT_SCRIPT], env=env, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0 and "kept and ran" in done.stdout, done.stdout + done.stderr


_LAPACK_SCRIPT = """
import sys
import jax, jax.numpy as jnp, numpy as np
from drivecal.model import _lowered_cache as traced

a = np.array([[4.0, 1.0], [1.0, 3.0]])
solve = jax.jit(lambda a: jnp.linalg.solve(a, a[:, 0]))
sine = jax.jit(lambda a: jnp.sin(a) * 2.0)
if sys.argv[1] == "keep":
    traced.call(solve, "solve", a), traced.call(sine, "sine", a)
    print("kept")
else:  # a new process: the program without LAPACK loads and runs without it, the one with it initialises it
    np.testing.assert_allclose(np.asarray(traced.call(sine, "sine", a)), np.sin(a) * 2.0)
    assert traced._initialize_lapack.cache_info().currsize == 0, "LAPACK initialised for a program without it"
    np.testing.assert_allclose(np.asarray(traced.call(solve, "solve", a)), [1.0, 0.0], atol=1e-15)
    assert traced._initialize_lapack.cache_info().currsize == 1
    assert "scipy.linalg" not in sys.modules, "scipy.linalg's __init__ ran to initialise LAPACK"
    import scipy.linalg  # the package still imports whole, with the BLAS and LAPACK tables JAX read
    assert scipy.linalg.cython_lapack.__name__ == "scipy.linalg.cython_lapack"
    np.testing.assert_allclose(scipy.linalg.solve(a, a[:, 0]), [1.0, 0.0], atol=1e-15)
    print("ran")
"""


def test_a_kept_program_initialises_lapack_where_it_calls_it_and_only_there(tmp_path):
    """A kept kernel calling LAPACK crashes a process whose LAPACK kernels are not initialised (jax#29610); one that
    calls none loads without them (a warm fit: ~0.1 s of importing SciPy's BLAS). Where they are initialised,
    SciPy's BLAS and LAPACK tables load without ``scipy.linalg``'s ``__init__`` (~0.15 s), which imports as usual later."""
    import os
    import subprocess
    import sys

    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path)}
    for step, said in (("keep", "kept"), ("run", "ran")):
        done = subprocess.run([sys.executable, "-c", _LAPACK_SCRIPT, step], env=env, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0 and said in done.stdout, done.stdout + done.stderr


def test_a_program_jitted_with_compiler_options_is_kept_and_compiled_with_them(store, monkeypatch):
    """The exported program does not carry the jit's XLA options: the kept entry compiles with them again,
    under a key of its own."""
    options = {"xla_cpu_use_fusion_emitters": False}
    with_options = jax.jit(_f.__wrapped__, static_argnames=("scale",), compiler_options=options)
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    plain = with_options(x, y, scale=2.5)
    seen = []
    runner = traced._runner
    monkeypatch.setattr(traced, "_runner", lambda exported, opts=None: (seen.append(opts), runner(exported, opts))[1])
    first = traced.call(with_options, "f", x, y, scale=2.5, compiler_options=options)
    traced.call(_f, "f", x, y, scale=2.5)
    assert seen == [options, None]
    assert len(list(store.glob("f-*.pkl"))) == 2
    path = next(p for p in store.glob("f-*.pkl") if pickle.loads(zlib.decompress(p.read_bytes()))[3] == options)
    path.write_bytes(zlib.compress(pickle.dumps(pickle.loads(zlib.decompress(path.read_bytes()))[:2] + (None, options))))
    monkeypatch.setattr(traced, "_LOADED", {})  # a new process, the executable not kept: lowered with the options
    again = traced.call(with_options, "f", x, y, scale=2.5, compiler_options=options)
    assert seen[-1] == options
    for out in (first, again):
        np.testing.assert_array_equal(out["a"], plain["a"])


def test_run_once_options_use_level_1_for_the_dead_time_s_rollout_and_legacy_emitters_for_both():
    """A program run once compiles at LLVM's level 0 with the legacy emitters; with the dead time's rollout (tens of
    milliseconds a run, a fit runs it at every step) at level 1 (as fast to run as level 2, quicker to compile),
    still with the legacy emitters (half the compile)."""
    assert traced.run_once_options(False) == traced.RUN_ONCE
    assert traced.RUN_ONCE == {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
    assert traced.LEGACY_EMITTERS == {"xla_cpu_use_fusion_emitters": False}
    assert traced.run_once_options(True) == {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": False}


def test_with_caching_off_the_plain_call_is_compiled_with_the_options(monkeypatch):
    """Caching off (as the suite runs), a call with XLA options jits the function it wraps with them, once:
    the numbers are those of the kept program (a batch's solve: XLA's legacy emitters)."""
    options = {"xla_cpu_use_fusion_emitters": False}
    monkeypatch.setattr(traced, "directory", lambda: None)
    monkeypatch.setattr(traced, "_PLAIN", {})
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    expected = jax.jit(_f.__wrapped__, static_argnames=("scale",), compiler_options=options)(x, y, scale=2.5)
    for _ in range(2):
        out = traced.call(_f, "f", x, y, scale=2.5, compiler_options=options)
        np.testing.assert_array_equal(out["a"], expected["a"])
    assert list(traced._PLAIN) == [(_f, tuple(options.items()), ("scale",))]
    traced.call(_f, "f", x, y, scale=2.5)  # no options: the function as it is
    assert len(traced._PLAIN) == 1


def test_key_separates_shapes_statics_and_dtypes(store):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    traced.call(_f, "f", x, y, scale=2.5)
    traced.call(_f, "f", x, y, scale=3.0)
    traced.call(_f, "f", x[:10], y, scale=2.5)
    traced.call(_f, "f", x.astype(np.float32), y, scale=2.5)
    assert len(list(store.glob("f-*.pkl"))) == 4


def test_tracers_damaged_entries_and_cache_off_take_the_plain_call(store, monkeypatch):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    inside = jax.jit(lambda x: traced.call(_f, "f", x, y, scale=2.5)["a"])(x)
    np.testing.assert_array_equal(inside, _f(x, y, scale=2.5)["a"])
    assert not list(store.glob("*.pkl"))  # traced under jit: nothing kept
    traced.call(_f, "f", x, y, scale=2.5)
    (path,) = store.glob("f-*.pkl")
    path.write_bytes(b"damaged")
    monkeypatch.setattr(traced, "_LOADED", {})
    np.testing.assert_array_equal(traced.call(_f, "f", x, y, scale=2.5)["a"], _f(x, y, scale=2.5)["a"])
    # DRIVECAL_JAX_CACHE=0: no store, the plain call
    monkeypatch.setenv("DRIVECAL_JAX_CACHE", "0")
    assert _DIRECTORY() is None
    monkeypatch.setattr(traced, "directory", _DIRECTORY)
    monkeypatch.setattr(traced, "_export", lambda *a, **k: pytest.fail("exported with the cache off"))
    np.testing.assert_array_equal(traced.call(_f, "f", x, y, scale=2.5)["a"], _f(x, y, scale=2.5)["a"])


def _counting_exports(monkeypatch, barrier=None, stage="_export"):
    """``stage`` (``_export``, or ``_compiled``: its compilation) wrapped: how many run, and the most at once
    (each waits at ``barrier``, else 50 ms)."""
    export, lock, seen = getattr(traced, stage), threading.Lock(), {"calls": 0, "active": 0, "most": 0}

    def counted(*args, **kwargs):
        with lock:
            seen["calls"] += 1
            seen["active"] += 1
            seen["most"] = max(seen["most"], seen["active"])
        try:
            barrier.wait(timeout=30) if barrier is not None else time.sleep(0.05)
            return export(*args, **kwargs)
        finally:
            with lock:
                seen["active"] -= 1

    monkeypatch.setattr(traced, stage, counted)
    return seen


def test_threads_asking_for_one_program_at_once_export_it_once(store, monkeypatch):
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    seen = _counting_exports(monkeypatch)
    outs = side_by_side([lambda: traced.call(_f, "f", x, y, scale=2.5)] * 4)
    assert seen["calls"] == 1
    for out in outs:
        np.testing.assert_array_equal(out["a"], _f(x, y, scale=2.5)["a"])


def test_work_ahead_of_need_compiles_one_program_at_a_time(store, monkeypatch):
    """Marked ``ahead_of_need``, new programs trace and compile one after the other; unmarked, they trace one
    after the other and compile side by side."""
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    scales = (1.0, 2.0, 3.0)
    # unmarked: all three meet inside their compilations (a barrier of three: they would time out one after
    # the other)
    seen = _counting_exports(monkeypatch, threading.Barrier(3), stage="_compiled")
    side_by_side([lambda s=s: traced.call(_f, "f", x, y, scale=s) for s in scales])
    assert seen["calls"] == 3 and seen["most"] == 3
    monkeypatch.undo()  # a new store, as in a new process
    (store / "ahead").mkdir()
    monkeypatch.setattr(traced, "directory", lambda: store / "ahead")
    monkeypatch.setattr(traced, "_LOADED", {})
    seen = _counting_exports(monkeypatch)
    with ahead_of_need():
        outs = side_by_side([lambda s=s: traced.call(_f, "f", x, y, scale=s) for s in scales])
    assert seen["calls"] == 3 and seen["most"] == 1
    for s, out in zip(scales, outs):
        np.testing.assert_array_equal(out["a"], _f(x, y, scale=s)["a"])
    # kept programs load side by side, marked or not: no export at all
    monkeypatch.setattr(traced, "_LOADED", {})
    with ahead_of_need():
        side_by_side([lambda s=s: traced.call(_f, "f", x, y, scale=s) for s in scales])
    assert seen["calls"] == 3


def test_a_call_needed_now_never_waits_behind_the_queue_of_work_ahead_of_need(store, monkeypatch):
    """An ahead-of-need thread waiting for its turn to export holds no key's lock: the caller that needs the
    same program now exports it at once (beside the compilation ahead of need under way), and the waiting
    thread then finds it."""
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    go, compiled, exports = threading.Event(), traced._compiled, _counting_exports(monkeypatch)
    compiling = []

    def held(*args):
        compiling.append(len(compiling))
        if len(compiling) == 1:  # the first program ahead of need compiles, in its turn, until ``go``
            go.wait(60)
        return compiled(*args)

    monkeypatch.setattr(traced, "_compiled", held)
    try:
        with ahead_of_need():
            busy = threading.Thread(target=_in_this_context(lambda: traced.call(_f, "f", x, y, scale=9.0)))
            busy.start()
            deadline = time.monotonic() + 60
            while not compiling and time.monotonic() < deadline:
                time.sleep(0.01)
            ahead = threading.Thread(target=_in_this_context(lambda: traced.call(_f, "f", x, y, scale=2.5)))
            ahead.start()
            ahead.join(timeout=0.5)
            assert ahead.is_alive() and exports["calls"] == 1  # queued for its turn
        now = threading.Thread(target=lambda: traced.call(_f, "f", x, y, scale=2.5))
        now.start()
        now.join(timeout=30)
        assert not now.is_alive() and exports["calls"] == 2 and not go.is_set()
    finally:
        go.set()
    busy.join(timeout=60)
    ahead.join(timeout=60)
    assert not ahead.is_alive() and exports["calls"] == 2  # it found the program exported


def test_work_ahead_of_need_keeps_no_turn_while_another_thread_exports_its_program(store, monkeypatch):
    """A thread ahead of need whose program another thread is exporting waits for it without its turn:
    the next program ahead of need is traced meanwhile."""
    x, y = np.linspace(0.0, 3.0, 50), np.arange(4.0)
    seen = _counting_exports(monkeypatch)
    locks, turn = [], traced._turn

    @contextlib.contextmanager
    def turn_once_another_exports():
        if not locks:  # the first thread's program: a thread that needs it takes it now, to export it
            (lock,) = traced._KEY_LOCKS.values()
            lock.acquire()
            locks.append(lock)
        with turn():
            yield

    monkeypatch.setattr(traced, "_turn", turn_once_another_exports)
    monkeypatch.setattr(traced, "_KEY_LOCKS", {})
    try:
        with ahead_of_need():
            waiting = threading.Thread(target=_in_this_context(lambda: traced.call(_f, "f", x, y, scale=1.0)))
            waiting.start()
            waiting.join(timeout=0.5)
            assert waiting.is_alive() and locks
            other = threading.Thread(target=_in_this_context(lambda: traced.call(_f, "f", x, y, scale=2.0)))
            other.start()
            other.join(timeout=10)
            assert not other.is_alive() and seen["calls"] == 1  # not behind the waiting thread's turn
    finally:
        for lock in locks:
            lock.release()
    waiting.join(timeout=60)
    assert not waiting.is_alive() and seen["calls"] == 2  # the other thread only held the lock: exported now


def _in_this_context(job):
    """``job`` to run in a thread, in a copy of this context (its ahead-of-need mark)."""
    return functools.partial(contextvars.copy_context().run, job)


def test_sensitivity_jacobian_kept_equals_plain(store, truth, monkeypatch):
    exp = dc.Experiment.from_plan(dc.locked_q_step_plan())
    kept = np.asarray(dc.sensitivity_jacobian(truth, exp))
    with monkeypatch.context() as m:
        m.setattr(traced, "directory", lambda: None)  # no store: the plain jitted call
        plain = np.asarray(dc.sensitivity_jacobian(truth, exp))
    np.testing.assert_array_equal(kept, plain)
    assert len(list(store.glob("sensitivity_jacobian-*.pkl"))) == 1


def test_store_keeps_the_most_recently_used(store, monkeypatch):
    monkeypatch.setattr(traced, "_MAX_ENTRIES", 2)
    y = np.arange(4.0)
    for n in (5, 6, 7):
        traced.call(_f, "f", np.ones(n), y, scale=1.0)
    assert len(list(store.glob("f-*.pkl"))) == 2


def test_fingerprint_covers_every_source_file_of_the_package(tmp_path, monkeypatch):
    """Every .py of every sub-package is in the key: an edit anywhere changes it (stale programs never load)."""
    import drivecal

    package = Path(drivecal.__file__).resolve().parent
    on_disk = sorted(package.rglob("*.py"))
    assert traced.source_files() == on_disk
    assert any(p.parent != package for p in on_disk)  # sub-packages are there, and read
    # An edit in a sub-package changes the fingerprint.
    copy = tmp_path / "drivecal"
    shutil.copytree(package, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(traced, "package_root", lambda: copy)
    traced._read_fingerprint.cache_clear()
    try:
        before = traced._fingerprint()
        deep = copy / "fitting" / "_fit.py"
        deep.write_text(deep.read_text() + "\n# edited\n")
        traced._read_fingerprint.cache_clear()
        assert traced._fingerprint() != before
    finally:
        traced._read_fingerprint.cache_clear()


def test_python_floats_and_float64_arrays_share_one_compiled_program(monkeypatch):
    """A motor's fields are Python floats where a file set them, float64 arrays where a fit did: one kernel.

    Fails without ``_strongly_typed``: ``jit`` traces and compiles a weakly typed argument anew.
    """
    monkeypatch.setattr(traced, "directory", lambda: None)  # the plain call, as in the suite

    traces = []

    @jax.jit
    def scaled(x, y):
        traces.append(jax.typeof(x))  # runs once a trace
        return x * y

    y = np.arange(3.0)
    first = traced.call(scaled, "scaled", 2.0, y)
    second = traced.call(scaled, "scaled", jnp.asarray(2.0), y)  # weakly typed too
    third = traced.call(scaled, "scaled", np.float64(2.0), y)
    assert len(traces) == 1 and not traces[0].weak_type
    for out in (second, third):
        np.testing.assert_array_equal(out, first)
