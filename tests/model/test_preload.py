"""model._preload: a command's kept programs loaded ahead of need, as the last process that started alike loaded them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from drivecal.model import _preload


def _new_process(monkeypatch):
    """The module's state as in a new process."""
    monkeypatch.setattr(_preload, "_SEQUENCE", [])
    monkeypatch.setattr(_preload, "_ASKED", set())
    monkeypatch.setattr(_preload, "_RECORD", {"path": None, "said": None})
    monkeypatch.setattr(_preload, "_STOP", threading.Event())


@pytest.fixture()
def fresh(monkeypatch):
    """The module's state as in a new process; its exit callbacks collected, not registered."""
    _new_process(monkeypatch)
    at_exit = []
    monkeypatch.setattr(_preload.atexit, "register", lambda fn, *args: at_exit.append((fn, args)))
    return at_exit


def _exit(at_exit):
    for fn, args in reversed(at_exit):  # last registered, first run
        fn(*args)


def test_the_programs_asked_after_the_first_are_recorded_and_loaded_ahead_next_time(tmp_path, fresh, monkeypatch):
    loaded = []
    for key in ("a" * 40, "b" * 40, "a" * 40, "c" * 40):
        _preload.noted(key, tmp_path / f"p-{key[:32]}.pkl", lambda k, p: loaded.append(k))
    _exit(fresh)
    record = _preload.record_path("a" * 40, tmp_path)
    assert json.loads(record.read_text()) == [["b" * 40, f"p-{'b' * 32}.pkl"], ["c" * 40, f"p-{'c' * 32}.pkl"]]
    assert loaded == []  # no record the first time: nothing loaded ahead

    _new_process(monkeypatch)
    fresh.clear()
    _preload.noted("a" * 40, tmp_path / f"p-{'a' * 32}.pkl", lambda k, p: loaded.append((k, p.name)))
    _exit(fresh)  # stops the thread after its loads and joins it; the record said the same: not written again
    assert loaded == [("b" * 40, f"p-{'b' * 32}.pkl"), ("c" * 40, f"p-{'c' * 32}.pkl")]


def test_a_process_that_asks_for_nothing_after_its_first_program_writes_no_record(tmp_path, fresh):
    _preload.noted("a" * 40, tmp_path / "p.pkl", lambda k, p: None)
    _exit(fresh)
    assert list(tmp_path.iterdir()) == []


def test_a_damaged_record_loads_nothing_and_is_written_again(tmp_path, fresh):
    _preload.record_path("a" * 40, tmp_path).write_text("[[1, 2")
    loaded = []
    _preload.noted("a" * 40, tmp_path / "p.pkl", lambda k, p: loaded.append(k))
    _preload.noted("b" * 40, tmp_path / "q.pkl", lambda k, p: loaded.append(k))
    _exit(fresh)
    assert loaded == [] and json.loads(_preload.record_path("a" * 40, tmp_path).read_text()) == [["b" * 40, "q.pkl"]]


def test_the_least_recently_written_records_go_beyond_the_limit(tmp_path, fresh, monkeypatch):
    monkeypatch.setattr(_preload, "MAX_RECORDS", 2)
    for k, key in enumerate(("x" * 40, "y" * 40)):
        _preload.record_path(key, tmp_path).write_text("[]")
        os.utime(_preload.record_path(key, tmp_path), (k, k))
    _preload.noted("a" * 40, tmp_path / "p.pkl", lambda k, p: None)
    _preload.noted("b" * 40, tmp_path / "q.pkl", lambda k, p: None)
    _exit(fresh)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        _preload.record_path(key, tmp_path).name for key in ("a" * 40, "y" * 40))


# Two processes on one store of kept programs: the first calls f, g and h; the second calls f only, and finds g and h
# loaded ahead by then (they were not called), their numbers the plain ones.
_TWO_PROCESSES = """
import sys, threading
import jax, jax.numpy as jnp, numpy as np
from drivecal.model import _lowered_cache as traced

f = jax.jit(lambda x: {"a": jnp.sin(x)})
g = jax.jit(lambda x: {"a": jnp.cos(x) * 2.0})
h = jax.jit(lambda x: {"a": jnp.cumsum(x)})
x = np.linspace(0.0, 3.0, 50)
if sys.argv[1] == "first":
    for fn, name in ((f, "f"), (g, "g"), (h, "h")):
        traced.call(fn, name, x)
    print("called three")
else:
    np.testing.assert_array_equal(np.asarray(traced.call(f, "f", x)["a"]), np.asarray(f(x)["a"]))
    for ahead in [t for t in threading.enumerate() if t.name == "drivecal-preload"]:  # unless done already
        ahead.join()
    names = sorted(path.split("-")[0] for path in (p.name for p in traced.directory().glob("*.pkl")))
    assert len(traced._LOADED) == 3 and names == ["f", "g", "h"], (traced._LOADED, names)
    np.testing.assert_array_equal(np.asarray(traced.call(h, "h", x)["a"]), np.asarray(h(x)["a"]))
    print("loaded ahead")
"""


def test_a_second_process_loads_ahead_what_the_first_one_loaded_after_its_first_program(tmp_path):
    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path)}
    for step, said in (("first", "called three"), ("second", "loaded ahead")):
        done = subprocess.run([sys.executable, "-c", _TWO_PROCESSES, step], env=env, capture_output=True, text=True,
                              timeout=300)
        assert done.returncode == 0 and said in done.stdout, done.stdout + done.stderr


def test_programs_listed_and_not_asked_for_stay_listed_after_those_asked_for(tmp_path, fresh, monkeypatch):
    """Two commands that start alike and then differ, run in turns: the record keeps both's programs, this one's first."""
    record = _preload.record_path("a" * 40, tmp_path)
    record.write_text(json.dumps([["b" * 40, "b.pkl"], ["c" * 40, "c.pkl"]]))
    loaded = []
    _preload.noted("a" * 40, tmp_path / "a.pkl", lambda k, p: loaded.append(p.name))
    _preload.noted("d" * 40, tmp_path / "d.pkl", lambda k, p: loaded.append(p.name))
    _preload.noted("c" * 40, tmp_path / "c.pkl", lambda k, p: loaded.append(p.name))
    _exit(fresh)
    assert loaded == ["b.pkl", "c.pkl"]
    assert json.loads(record.read_text()) == [["d" * 40, "d.pkl"], ["c" * 40, "c.pkl"], ["b" * 40, "b.pkl"]]
    monkeypatch.setattr(_preload, "MAX_LISTED", 2)
    _new_process(monkeypatch)
    fresh.clear()
    _preload.noted("a" * 40, tmp_path / "a.pkl", lambda k, p: None)
    _preload.noted("e" * 40, tmp_path / "e.pkl", lambda k, p: None)
    _exit(fresh)
    assert json.loads(record.read_text()) == [["e" * 40, "e.pkl"], ["d" * 40, "d.pkl"]]


def test_the_drivecal_program_does_not_wait_at_exit_for_a_program_being_loaded(tmp_path, fresh, monkeypatch):
    """It ends without the interpreter's teardown (``_exit``): the thread is told to stop, not waited for."""
    _preload.record_path("a" * 40, tmp_path).write_text(json.dumps([["b" * 40, "b.pkl"], ["c" * 40, "c.pkl"]]))
    loading, release, loaded = threading.Event(), threading.Event(), []

    def slow(key, path):
        loading.set()
        release.wait(10)
        loaded.append(path.name)

    _preload.noted("a" * 40, tmp_path / "a.pkl", slow)
    assert loading.wait(10)
    monkeypatch.setattr(_preload._exit, "WITHOUT_TEARDOWN", True)
    _exit(fresh)  # returns while "b" is being loaded
    assert loaded == []
    release.set()
    next(t for t in threading.enumerate() if t.name == "drivecal-preload").join(10)
    assert loaded == ["b.pkl"]  # stopped after the program it was loading


@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")  # JAX's warning: the child runs no JAX
def test_a_fork_waits_for_the_program_being_loaded_ahead(tmp_path, fresh):
    """A child process never starts with its parent's thread inside XLA's loader (its locks held for ever there)."""
    _preload.record_path("a" * 40, tmp_path).write_text(json.dumps([["b" * 40, "b.pkl"]]))
    loading, release, order = threading.Event(), threading.Event(), []

    def slow(key, path):
        loading.set()
        release.wait(10)
        order.append("loaded")

    _preload.noted("a" * 40, tmp_path / "a.pkl", slow)
    assert loading.wait(10)
    threading.Timer(0.3, lambda: (order.append("released"), release.set())).start()
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)
    order.append("forked")
    assert order == ["released", "loaded", "forked"]
    _exit(fresh)
