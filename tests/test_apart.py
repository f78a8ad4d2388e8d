"""_apart: a package's compiled modules without its ``__init__`` (SciPy's array-API layer, ~0.15 s a process)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from drivecal._apart import import_apart

# A fresh interpreter: the modules alone while the block runs, nothing of the package left after it; the package
# then imports whole, the same module objects as its attributes.
_APART_THEN_PACKAGE = """
import sys
from drivecal._apart import import_apart
with import_apart("scipy.linalg", ("cython_blas", "cython_lapack")) as (blas, lapack):
    print(sys.modules["scipy.linalg.cython_blas"] is blas, "numpy.testing" in sys.modules, blas.__name__,
          lapack.__name__)
print(sorted(name for name in sys.modules if name.startswith("scipy.linalg")))
import scipy.linalg
print(scipy.linalg.cython_blas is blas, scipy.linalg.cython_lapack is lapack, scipy.linalg.det([[2.0, 0.0], [0.0, 3.0]]))
"""


def test_modules_load_without_their_package_which_still_imports_whole_with_the_same_modules():
    proc = subprocess.run([sys.executable, "-c", _APART_THEN_PACKAGE], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["True False scipy.linalg.cython_blas scipy.linalg.cython_lapack", "[]",
                                        "True True 6.0"]


def test_a_package_already_imported_gives_its_own_modules_and_keeps_them():
    import json
    import json.decoder

    with import_apart("json", ("decoder", "scanner")) as modules:
        assert modules == (json.decoder, sys.modules["json.scanner"])
    assert sys.modules["json"] is json and sys.modules["json.decoder"] is json.decoder


def test_a_package_the_stand_in_cannot_take_is_imported_as_usual():
    """A plain module is no package: no stand-in can hold a sub-module of it; the usual import says why."""
    sys.modules.pop("colorsys", None)
    with pytest.raises(ModuleNotFoundError):
        with import_apart("colorsys", ("nothing",)):
            pass
    assert "colorsys" in sys.modules


# A fresh interpreter: a thread that imports the package while the block runs waits for it, then imports it whole.
_ANOTHER_THREAD = """
import importlib, threading
from drivecal._apart import import_apart
got = []
with import_apart("scipy.linalg", ("cython_blas",)) as (blas,):
    thread = threading.Thread(target=lambda: got.append(importlib.import_module("scipy.linalg")))
    thread.start()
    thread.join(0.5)
    print("waits" if thread.is_alive() else "did not wait")
thread.join()
print(got[0].det([[2.0, 0.0], [0.0, 3.0]]), got[0].cython_blas is blas)
"""


def test_a_thread_importing_the_package_meanwhile_waits_and_gets_it_whole():
    proc = subprocess.run([sys.executable, "-c", _ANOTHER_THREAD], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["waits", "6.0 True"]
