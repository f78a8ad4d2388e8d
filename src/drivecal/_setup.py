"""Process set-up every numeric sub-package needs first: float64 and the compilation cache.

Imported by each sub-package's ``__init__`` before anything of JAX runs
(``from .. import _setup``), so ``import drivecal`` itself stays light (the
CLI's ``--help`` never imports JAX). Fisher matrices need float64, so drivecal
switches JAX to double precision for the whole process.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_enabled() -> bool:
    """Whether the on-disk compilation cache is on (``DRIVECAL_JAX_CACHE=0`` turns it off)."""
    return os.environ.get("DRIVECAL_JAX_CACHE", "1").strip().lower() not in ("0", "off", "false", "no")


if cache_enabled():
    # XLA:CPU logs a harmless machine-feature line at ERROR level on every
    # cache hit; keep C++ logging to fatal errors unless the user chose a level.
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

import jax  # noqa: E402

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
    jax.config.update("jax_compilation_cache_dir", str(Path(root) / _host_kind()))
    # drivecal's kernels compile in well under JAX's default 1 s threshold.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    # No size limit: a limit turns on JAX's cross-process file lock around every
    # read and write, on which parallel processes queue. A kernel read while
    # another process still writes it is a truncated zlib stream, which JAX
    # rejects and recompiles (tried: cut at 30-99 %), so the lock buys nothing.


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
