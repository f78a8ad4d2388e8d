"""A batch's inputs: the bench files named on the command line, asked for from the disk, and the motors in them.

One file per motor, or one Parquet dataset holding many motors: a table with a
``serial`` column of several values is split into its motors (the rows of each
serial, in file order), so a file or a directory of parts written from one fleet
table calibrates as one file per motor would. A part in a directory named
``serial=<serial>`` (a dataset partitioned by serial) without a ``serial``
column is that motor's.
"""

from __future__ import annotations

import glob
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from ..data import FORMATS
from ..errors import DrivecalError


def discover(inputs: Sequence[str | os.PathLike]) -> list[Path]:
    """Bench files named by ``inputs``: files, directories (searched recursively) or glob patterns.

    Returns the files sorted by path, each once.

    Raises:
        DrivecalError: an input that matches nothing.
    """
    return [Path(p) for p in discover_paths(inputs)]


def discover_paths(inputs: Sequence[str | os.PathLike]) -> list[str]:
    """:func:`discover`'s files as strings, in its order (a batch's files are strings from here on).

    Strings throughout, not ``Path`` objects: building, hashing and comparing 10 000 of them took ~0.1 s of
    a batch's start, before any helper had work.
    """
    found: set[str] = set()
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            matches = _bench_files_under(path)  # resolved already
        elif path.is_file():
            matches = [str(path.resolve())]
        else:
            matches = [str(Path(p).resolve()) for p in glob.glob(str(item), recursive=True) if Path(p).is_file()]
        if not matches:
            raise DrivecalError(f"{item}: no bench files ({', '.join(FORMATS)}) found there; "
                                "check the path or pattern.")
        found.update(matches)
    return sorted(found, key=_path_order)


def _path_order(path: str) -> list[str]:
    """The sort key of a resolved path as ``Path`` orders it: component by component (``a/b`` before ``a-b``,
    which a plain string sort puts first), and without case where the system ignores it (Windows)."""
    return os.path.normcase(path).split(os.sep)


def _bench_files_under(directory: Path) -> list[str]:
    """Bench files anywhere below ``directory`` (not into linked directories), resolved.

    One ``scandir`` per directory: a production line's folder holds tens of thousands of files,
    and resolving each path on its own costs ~30 us.
    """
    found, pending = [], [str(directory.resolve())]
    while pending:
        with os.scandir(pending.pop()) as entries:
            for entry in entries:
                if entry.is_dir(follow_symlinks=False):
                    pending.append(entry.path)
                elif os.path.splitext(entry.name)[1].lower() in FORMATS and entry.is_file():
                    found.append(str(Path(entry.path).resolve()) if entry.is_symlink() else entry.path)
    return found


def prefetch(paths: Sequence[str]) -> None:
    """Ask the operating system to read ``paths`` into its page cache now, in the background.

    A chunk's files are then read from memory one after the other instead of each waiting for the
    disk: a file not yet cached took ~0.2 ms to read here, one asked for in advance ~0.05 ms (incl.
    this call's ~0.02 ms), one already cached ~0.03 ms (+0.01 ms for this call). Where the system
    has no ``posix_fadvise`` (macOS, Windows) nothing is done; a file that cannot be opened is left
    to the read that reports it.
    """
    advise = getattr(os, "posix_fadvise", None)
    if advise is None:
        return
    for path in paths:
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            advise(fd, 0, 0, os.POSIX_FADV_WILLNEED)
        except OSError:
            pass
        finally:
            os.close(fd)


def serial_of(path: str, columns: dict) -> str:
    """A single motor's serial: its ``serial`` column's first value, a ``serial=...`` directory, or the file name."""
    if "serial" in columns and columns["serial"].size:
        return str(columns["serial"][0])
    parent = Path(path).parent.name
    return parent.removeprefix("serial=") if parent.startswith("serial=") else Path(path).stem


def motors_in(columns: dict) -> list[tuple[str | None, dict]]:
    """The motors of a table: ``[(None, columns)]`` for one motor, or ``(serial, its rows)`` per serial of a
    table whose ``serial`` column holds several (in order of appearance, each motor's rows in file order)."""
    serial = columns.get("serial")
    if serial is None or serial.size == 0 or not (serial != serial[0]).any():
        return [(None, columns)]
    codes, labels = pd.factorize(serial)  # a blank serial (-1) belongs to no motor: its rows are left out
    order = np.argsort(codes, kind="stable")
    order = order[codes[order] >= 0]
    bounds = np.concatenate([[0], np.cumsum(np.bincount(codes[order], minlength=len(labels)))])
    return [(str(label), {name: values[order[bounds[k]:bounds[k + 1]]] for name, values in columns.items()})
            for k, label in enumerate(labels)]
