"""The process set-up of drivecal/_setup.py: the compilation cache never keeps a kernel that would crash the
process loading it, and XLA:CPU compiles a model's rollout loop as one kernel.

jaxlib 0.9.2's XLA:CPU serialises a kernel of many object files (the saturating flux model's fit, 425
objects) into a cache entry that kills the next process with SIGSEGV while it loads it: every second
saturating fit crashed. The suite runs with the cache off (conftest), so the write check is tested here
on stand-in kernels.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import pytest
from jax._src import compilation_cache

from drivecal import _setup
from drivecal._setup import MAX_CACHED_OBJECTS, SMALL_LOOP_BYTES, with_small_loops


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


def test_the_small_loop_threshold_joins_the_flags_and_leaves_a_users_backend_options_alone():
    option = f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold={SMALL_LOOP_BYTES}"
    assert with_small_loops("") == option
    assert with_small_loops("--xla_force_host_platform_device_count=2") == (
        f"--xla_force_host_platform_device_count=2 {option}")
    own = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=0"
    assert with_small_loops(own) == own


def test_a_loop_over_more_than_xlas_default_bytes_is_compiled_as_one_kernel():
    """The threshold reached XLA: a loop whose iteration moves ~80 kB (XLA:CPU hoists under 1 kB by default)
    is compiled as one kernel (XLA marks its call ``xla_cpu_small_call``), as a model's rollout is."""
    def sweep(x):
        return jax.lax.scan(lambda c, u: (jnp.sin(c) * 0.9 + u, c[0]), jnp.zeros(10_000), x)[1]

    assert "xla_cpu_small_call" in jax.jit(sweep).lower(jnp.ones(50)).compile().as_text()


def test_jax_sees_the_same_jax_packages_without_parsing_every_packages_metadata():
    """JAX's ROCm-plugin search on import reads each installed package's name; drivecal hands it only the
    ``jax*`` packages, named from their folders: the same packages as from their parsed metadata."""
    import importlib.metadata
    import re

    def named(dists):  # PEP 503 names
        return sorted(re.sub(r"[-_.]+", "-", d.metadata["Name"]).lower() for d in dists)

    everything = named(importlib.metadata.distributions())
    expected = [n for n in everything if n.startswith("jax")]
    assert expected and len(expected) < len(everything)  # jax, jaxlib, ... and other packages
    assert named(_setup._jax_distributions()) == expected
    assert importlib.metadata.distributions is _setup._all_distributions  # put back once JAX imported


# A fresh interpreter: drivecal's set-up imports JAX without etils.epath, which stays importable afterwards.
_WITHOUT_REMOTE_PATHS = """
import sys
import drivecal._setup
from jax._src import path
print(path.epath_installed, path.Path.__module__, "etils.epath" in sys.modules, "unittest.mock" in sys.modules)
from etils import epath
print(epath.__name__)
"""


def test_jax_imports_without_etils_epath_which_stays_importable():
    """JAX keeps its local paths with pathlib, not etils.epath (whose import loads unittest.mock and asyncio)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _WITHOUT_REMOTE_PATHS], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["False pathlib False False", "etils.epath"]
