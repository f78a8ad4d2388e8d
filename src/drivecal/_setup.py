"""Process set-up every numeric sub-package needs first: float64, XLA's small-loop threshold and the compilation cache.

Imported by each sub-package's ``__init__`` before anything of JAX runs
(``from .. import _setup``), so ``import drivecal`` itself stays light (the
CLI's ``--help`` never imports JAX). Fisher matrices need float64, so drivecal
switches JAX to double precision for the whole process.
"""

from __future__ import annotations

import importlib.metadata
import os
import sys
import threading
from pathlib import Path
from typing import Any


def cache_enabled() -> bool:
    """Whether the on-disk compilation cache is on (``DRIVECAL_JAX_CACHE=0`` turns it off)."""
    return os.environ.get("DRIVECAL_JAX_CACHE", "1").strip().lower() not in ("0", "off", "false", "no")


#: XLA:CPU compiles a while loop that accesses fewer bytes than this as one kernel (its small-while-loop
#: hoisting; 1 kB by default). Above it, each iteration dispatches its fused operations one by one, and a
#: model's rollout (a scan over the samples, a few scalar states and their tangents) is nearly all dispatch:
#: examples/inverter_bench.csv's dead-time Jacobian (1 400 samples, 4 RK4 sub-steps) ran in 143 ms, as one
#: kernel in 18 ms, the same numbers to 4e-18 relative; 11 200 samples, 1.1 s -> 0.2 s. Large enough for a
#: batch's chunk too, which ran as fast (docs/performance.md, stop 61).
SMALL_LOOP_BYTES = 100_000_000


def with_small_loops(flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with :data:`SMALL_LOOP_BYTES` as XLA:CPU's small-loop threshold; where
    ``flags`` already set XLA's backend options (a user's own), unchanged."""
    if "xla_backend_extra_options" in flags:
        return flags
    option = f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold={SMALL_LOOP_BYTES}"
    return f"{flags} {option}".strip()


if cache_enabled():
    # XLA:CPU logs a harmless machine-feature line at ERROR level on every
    # cache hit; keep C++ logging to fatal errors unless the user chose a level.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")
# Read by XLA once, when JAX starts its CPU backend (after this import, at the first computation); JAX's
# compilation cache keys on it, so kernels compiled without it are not loaded with it. A process that started
# JAX before importing drivecal (importing jaxonomy does) keeps XLA's flags as they were: rollouts as slow as
# before, their numbers the same to rounding.
os.environ["XLA_FLAGS"] = with_small_loops(os.environ.get("XLA_FLAGS", ""))


def _jax_distributions(**kwargs: Any):
    """``importlib.metadata.distributions``, only the installed packages whose name starts with "jax".

    JAX 0.9.2 looks for a ROCm plugin (a package named ``jax-rocm*-plugin``) on import by parsing the
    metadata of every installed package: 0.1-0.3 s of every command that runs JAX, in a venv of ~160
    packages. A package's name is read here from its folder's name (``jax_rocm7_plugin-0.9.2.dist-info``),
    its metadata only where the folder does not tell; JAX sees the same ``jax*`` packages.
    """
    for dist in _all_distributions(**kwargs):
        name = getattr(dist, "_normalized_name", None) or (dist.metadata.get("Name") or "").lower()
        if name.startswith("jax"):
            yield dist


#: Not imported while JAX imports. JAX keeps its paths (the compilation cache's folder) as ``etils.epath``
#: paths where that module is installed, for remote file systems (GCS buckets), else as ``pathlib`` paths;
#: importing it loads ``unittest.mock`` and ``asyncio`` (~0.03-0.05 s of every command that runs JAX).
#: drivecal's cache is a local folder, which ``pathlib`` reads and writes the same way.
REMOTE_PATHS_MODULE = "etils.epath"

_all_distributions = importlib.metadata.distributions
importlib.metadata.distributions = _jax_distributions  # only while JAX imports (if not imported yet)
_blocked = REMOTE_PATHS_MODULE not in sys.modules
if _blocked:
    sys.modules[REMOTE_PATHS_MODULE] = None  # type: ignore[assignment]  # an import of it raises ImportError
try:
    import jax  # noqa: E402
finally:
    importlib.metadata.distributions = _all_distributions
    if _blocked and REMOTE_PATHS_MODULE in sys.modules and sys.modules[REMOTE_PATHS_MODULE] is None:
        del sys.modules[REMOTE_PATHS_MODULE]  # importable again, for whoever needs it later

jax.config.update("jax_enable_x64", True)


def _enable_compilation_cache() -> None:
    """Keep compiled kernels on disk so a second drivecal process does not recompile.

    On by default; ``DRIVECAL_JAX_CACHE=0`` turns it off. Kernels go to
    ``$XDG_CACHE_HOME/drivecal/jax`` (``~/.cache/drivecal/jax``), or to
    ``DRIVECAL_JAX_CACHE_DIR``, in a sub-folder per kind of processor.
    """
    if not cache_enabled():
        return
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    root = os.environ.get("DRIVECAL_JAX_CACHE_DIR") or str(Path(base) / "drivecal" / "jax")
    # One folder per kind of processor: XLA:CPU compiles for the host's
    # instruction set, and a kernel loaded on a machine without it (a home
    # folder shared between machines) crashes the process.
    jax.config.update("jax_compilation_cache_dir", str(Path(root) / f"{_host_kind()}-{_CACHE_LAYOUT}"))
    # drivecal's kernels compile in well under JAX's default 1 s threshold.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # No size limit: a limit turns on JAX's cross-process file lock around every
    # read and write, on which parallel processes queue. A kernel read while
    # another process still writes it is a truncated zlib stream, which JAX
    # rejects and recompiles (tried: cut at 30-99 %), so the lock buys nothing.
    _keep_loadable_kernels_only()
    _remember_cache_hits()


#: The cache folder's layout: 2 since kernels of too many object files are no longer written
#: (earlier folders may hold such kernels, which crash the process that loads them).
_CACHE_LAYOUT = 2
#: Kernels of more object files than this are not written to the cache. jaxlib 0.9.2's XLA:CPU writes
#: a kernel of many objects that crashes (SIGSEGV, no Python error) the next process that loads it: seen
#: at 425 and 426 objects (the saturating flux model's fit), never at 416 or fewer (a dozen kernels of
#: 280-416 objects loaded fine). Not writing them costs their compilation in every process.
MAX_CACHED_OBJECTS = 400


def _keep_loadable_kernels_only() -> None:
    """Write a compiled kernel to the cache only when it has at most :data:`MAX_CACHED_OBJECTS` object files."""
    try:  # JAX's own module (jax is pinned: 0.9.2); without it, the cache is left as JAX keeps it
        from jax._src import compilation_cache

        write = compilation_cache.put_executable_and_time
    except (ImportError, AttributeError):
        return
    if getattr(write, "_drivecal_checked", False):
        return

    def checked(cache_key, module_name, executable, backend, compile_time):
        try:
            serialized = executable.serialize()
        except Exception:  # serialisation is JAX's to report, in its own write
            serialized = None
        if getattr(KERNELS, "keeping", False):  # model._lowered_cache keeps it: no second copy on disk
            KERNELS.latest = None if serialized is None else (executable, serialized)
            return None
        if serialized is not None and serialized.count(b"\x7fELF") > MAX_CACHED_OBJECTS:
            return None
        return write(cache_key, module_name, executable, backend, compile_time)

    checked._drivecal_checked = True
    compilation_cache.put_executable_and_time = checked


#: The kernels of this thread, as ``model._lowered_cache`` keeps them beside a program. ``latest``: (the
#: latest kernel the compilation cache supplied, or compiled while ``keeping``; its serialised bytes), or None.
#: A cache hit's bytes are those the cache holds: jaxlib 0.9.2 serialises an executable loaded from the cache
#: without its code. ``keeping`` (set by ``model._lowered_cache`` while it compiles a program it keeps):
#: the compilation cache does not write the kernel (the lowered cache keeps it, serialised once for both).
KERNELS = threading.local()


def _remember_cache_hits() -> None:
    """Note in :data:`KERNELS` each kernel the compilation cache supplies, with its serialised bytes."""
    try:  # JAX's own module, as in _keep_loadable_kernels_only
        from jax._src import compilation_cache

        read, extract = compilation_cache.get_executable_and_time, compilation_cache.extract_executable_and_time
    except (ImportError, AttributeError):
        return
    if getattr(read, "_drivecal_remembers", False):
        return

    def extracted(executable_and_time):
        serialized, compile_time = extract(executable_and_time)
        KERNELS.serialized = serialized
        return serialized, compile_time

    def remembered(*args, **kwargs):
        KERNELS.serialized = None
        executable, compile_time = read(*args, **kwargs)
        if executable is not None and KERNELS.serialized is not None:
            KERNELS.latest = (executable, KERNELS.serialized)
        KERNELS.serialized = None
        return executable, compile_time

    remembered._drivecal_remembers = True
    compilation_cache.extract_executable_and_time = extracted
    compilation_cache.get_executable_and_time = remembered


def _host_kind() -> str:
    """A short name for this host's processor: its architecture and a hash of its instruction-set flags."""
    import hashlib
    import platform

    text = platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key = line.split(":", 1)[0].strip()
                if key in ("flags", "Features", "model name", "isa"):
                    text += "\n" + line.strip()
                if key in ("flags", "Features") and line.strip():
                    break
    except OSError:
        pass
    return f"{platform.machine() or 'cpu'}-{hashlib.sha256(text.encode()).hexdigest()[:12]}"


_enable_compilation_cache()
