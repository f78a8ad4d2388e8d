"""Compiled modules of a package used without running the package's ``__init__``.

SciPy's sub-packages (``scipy.special``, ``scipy.linalg``) load an array-API layer in their
``__init__`` that clones NumPy's namespace (``numpy.f2py``, ``numpy.testing``, ``numpy.core``,
``pydoc``, ...): 0.1-0.2 s of a process that needs only a compiled module inside them (the
special functions of ``_stats``; the BLAS and LAPACK tables JAX's CPU kernels read, which
``model._lowered_cache`` loads). :func:`import_apart` imports such modules under a stand-in for
their package (its spec, not run) and takes the stand-in and what was imported under it away
again when done: a later ``import scipy.linalg`` runs the package as usual, imports its modules
again and finds the same module objects (a Cython module gives the one it created first; the
tests hold it), now attributes of the package as in any process.
"""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import sys
import threading
from collections.abc import Iterator
from types import ModuleType

_LOCK = threading.Lock()


@contextlib.contextmanager
def import_apart(package: str, names: tuple[str, ...]) -> Iterator[tuple[ModuleType, ...]]:
    """The modules ``package.name`` for each of ``names``, imported without running ``package``'s ``__init__``.

    They are in ``sys.modules`` while the ``with`` block runs (code that imports them by name finds
    them there), and taken out of it with the stand-in package when it ends. Meanwhile this thread
    holds the package's import lock: another thread that imports the package waits, and imports it
    whole once the stand-in is gone (the block must not wait for a thread importing it). Where
    ``package`` is already imported, or the stand-in fails (another layout of the package), the
    package is imported as usual and its modules given, left in place.
    """
    parent = package.rpartition(".")[0]
    if parent:  # imported first, not while the package's lock is held (as any import of the package does)
        importlib.import_module(parent)
    with _LOCK, _package_lock(package):
        before = set(sys.modules)
        stand_in = None
        if package not in sys.modules:
            try:
                spec = importlib.util.find_spec(package)
                spec._initializing = True  # type: ignore[union-attr]  # importers wait for the package's lock
                stand_in = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
                sys.modules[package] = stand_in
                modules = tuple(importlib.import_module(f"{package}.{name}") for name in names)
            except Exception:  # noqa: BLE001 - whatever the layout does, the package's own import is the answer
                _take_away(package, before)
                stand_in = None
        if stand_in is None:  # the package's lock is this thread's: it may take it again
            importlib.import_module(package)
            modules = tuple(importlib.import_module(f"{package}.{name}") for name in names)
        try:
            yield modules
        finally:
            if stand_in is not None and sys.modules.get(package) is stand_in:
                _take_away(package, before)


def _package_lock(package: str) -> contextlib.AbstractContextManager:
    """The import lock of ``package`` (held by a thread importing it): held, another thread's import of the package
    finds the stand-in marked as being imported and waits for it, then imports the package whole."""
    manager = getattr(importlib._bootstrap, "_ModuleLockManager", None)  # type: ignore[attr-defined]
    return manager(package) if manager is not None else contextlib.nullcontext()


def _take_away(package: str, before: set[str]) -> None:
    """Remove ``package`` and the modules imported under it since ``before`` from ``sys.modules``."""
    for name in set(sys.modules) - before:
        if name == package or name.startswith(package + "."):
            del sys.modules[name]
