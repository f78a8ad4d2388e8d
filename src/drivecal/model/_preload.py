"""The kept programs a command loaded last time, loaded ahead of need from its first one on.

A warm command loads each kept program (``model._lowered_cache``) when it first calls it: XLA
deserialises it, 0.1-0.4 s a program here. A command's programs come in steps (a fit's, then its
score tests', then those of the effects the tests chose, and again), and each step waits for its
loads while the other core idles: a warm ``drivecal fit examples/inverter_bench.csv`` loads 13
programs in three such steps. A command of the same shape loads the same programs in the same order
(a factory line fitting one plan, a user fitting a bench again). So the first program a process
loads names, in a small record beside the programs (``next-KEY.json``), those loaded after it in
the last process that started with it, and the next process that starts with it loads them in a
thread from the start, in that order. Programs listed before and not asked for this time stay listed
after them: two commands that start alike and then differ (``fit examples/bench.csv``, whose data need
no bench effect, and ``fit examples/inverter_bench.csv``, which then loads the effects' programs), run
in turns, each find theirs. A program loaded and not needed costs CPU on the other core,
never a number: it is the same program whoever loads it. Only a top-level process does it (a
batch's helpers load the batch's solve and little else).
"""

from __future__ import annotations

import atexit
import json
import os
import sys
import threading
from pathlib import Path
from typing import Callable

from .. import _exit
from .._io import write_bytes

#: Records kept in the programs' folder; beyond this the least recently written go.
MAX_RECORDS = 32
#: Programs a record lists at most.
MAX_LISTED = 32

_LOCK = threading.Lock()
#: (key, file name) of each program this process asked for, in the order first asked.
_SEQUENCE: list[tuple[str, str]] = []
_ASKED: set[str] = set()
#: The record of this process's first program: its path and what it said (None: no record read).
_RECORD: dict[str, Path | list | None] = {"path": None, "said": None}
#: Set at exit: the thread loading ahead stops after the program it is loading.
_STOP = threading.Event()


def record_path(first: str, folder: Path) -> Path:
    """The record of the programs loaded after the program of key ``first`` (kept in ``folder``)."""
    return folder / f"next-{first[:32]}.json"


def noted(key: str, path: Path, load: Callable[[str, Path], object]) -> None:
    """Note that the program of ``key`` (kept at ``path``) is asked for; on the process's first, start loading ahead.

    ``load(key, path)`` loads a kept program where it is not loaded yet (absent: nothing).
    """
    if key in _ASKED:  # every call of a program comes here: asked before, nothing to do
        return
    with _LOCK:
        if key in _ASKED:
            return
        _ASKED.add(key)
        _SEQUENCE.append((key, path.name))
        if len(_SEQUENCE) > 1 or _a_helper():
            return
        _RECORD["path"] = record_path(key, path.parent)
    said = _read(_RECORD["path"])
    _RECORD["said"] = said
    atexit.register(_save)
    if said:
        thread = threading.Thread(target=_load_ahead, args=(said, path.parent, load), name="drivecal-preload",
                                  daemon=True)
        atexit.register(_stop, thread)  # runs before _save (last registered, first run)
        thread.start()


def _a_helper() -> bool:
    """Whether this process was started by ``multiprocessing`` (which it then has imported: not importing it here)."""
    started = sys.modules.get("multiprocessing")
    return started is not None and started.parent_process() is not None


def _read(path: Path) -> list[tuple[str, str]] | None:
    """The (key, file name) pairs a record lists; None where there is none or it cannot be read."""
    try:
        said = json.loads(path.read_text())
        return [(str(k), str(n)) for k, n in said if "/" not in str(n)]
    except (OSError, ValueError, TypeError):
        return None


def _load_ahead(said: list[tuple[str, str]], folder: Path, load: Callable[[str, Path], object]) -> None:
    for key, name in said:
        with _LOADING:
            if _STOP.is_set():
                return
            try:
                load(key, folder / name)
            except Exception:  # noqa: BLE001 - loading ahead is a guess: the program's own call loads it, or says why
                return


#: Held while a program is loaded ahead, and by a fork (a batch's helpers): no child starts with a thread of its
#: parent inside XLA's loader, whose locks it would hold in the child for ever.
_LOADING = threading.Lock()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_LOADING.acquire, after_in_parent=_LOADING.release, after_in_child=_LOADING.release)


def _stop(thread: threading.Thread) -> None:
    """Stop loading ahead; wait for the program being loaded where the interpreter's teardown follows (``_exit``)."""
    _STOP.set()
    if not _exit.WITHOUT_TEARDOWN:
        thread.join()


def _save() -> None:
    """Write the record of this process's first program, where it changed: the programs asked for after it, then
    those the record listed that this process did not ask for (at most :data:`MAX_LISTED`)."""
    path = _RECORD["path"]
    with _LOCK:
        after = _SEQUENCE[1:]
    said = _RECORD["said"] or []
    after = (after + [entry for entry in said if entry[0] not in _ASKED])[:MAX_LISTED]
    if path is None or after == said:
        return
    try:
        write_bytes(path, json.dumps(after).encode())
        records = sorted(path.parent.glob("next-*.json"), key=_age)
        for old in records[:-MAX_RECORDS]:  # the least recently written go
            old.unlink(missing_ok=True)
    except OSError:
        pass


def _age(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0
