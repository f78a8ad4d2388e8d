"""The compilation cache never keeps a kernel that would crash the process loading it (drivecal/_setup.py).

jaxlib 0.9.2's XLA:CPU serialises a kernel of many object files (the saturating flux model's fit, 425
objects) into a cache entry that kills the next process with SIGSEGV while it loads it: every second
saturating fit crashed. The suite runs with the cache off (conftest), so the write check is tested here
on stand-in kernels.
"""

from __future__ import annotations

import pytest
from jax._src import compilation_cache

from drivecal import _setup
from drivecal._setup import MAX_CACHED_OBJECTS


class _Kernel:
    """A stand-in compiled kernel: ``serialize()`` holds ``objects`` ELF object files."""

    def __init__(self, objects: int):
        self.objects = objects

    def serialize(self) -> bytes:
        return b"header" + b"\x7fELF object" * self.objects


@pytest.fixture
def written(monkeypatch) -> list[str]:
    """The keys JAX's own cache write was called with, once the check is installed in front of it."""
    keys: list[str] = []
    monkeypatch.setattr(compilation_cache, "put_executable_and_time",
                        lambda key, name, executable, backend, time: keys.append(key))
    _setup._keep_loadable_kernels_only()
    return keys


def test_kernels_of_many_object_files_are_not_written(written):
    for objects in (0, 1, 416, MAX_CACHED_OBJECTS, MAX_CACHED_OBJECTS + 1, 425, 426):
        compilation_cache.put_executable_and_time(f"k{objects}", "jit_fit", _Kernel(objects), None, 1.0)
    assert written == ["k0", "k1", f"k{MAX_CACHED_OBJECTS}"]


def test_the_check_is_installed_once(written):
    checked = compilation_cache.put_executable_and_time
    _setup._keep_loadable_kernels_only()
    assert compilation_cache.put_executable_and_time is checked


def test_a_kernel_the_lowered_cache_keeps_is_serialised_once_and_not_written_twice(written):
    """Compiled while ``model._lowered_cache`` keeps it (``KERNELS.keeping``): its bytes are noted for the lowered
    cache, which keeps them, and JAX's cache does not write a second copy."""
    kernel = _Kernel(3)
    _setup.KERNELS.keeping = True
    try:
        compilation_cache.put_executable_and_time("kept", "jit_fit", kernel, None, 1.0)
    finally:
        _setup.KERNELS.keeping = False
    latest, _setup.KERNELS.latest = _setup.KERNELS.latest, None
    assert written == [] and latest == (kernel, kernel.serialize())
    compilation_cache.put_executable_and_time("plain", "jit_fit", kernel, None, 1.0)
    assert written == ["plain"]
