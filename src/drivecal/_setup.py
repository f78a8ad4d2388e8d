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
    ``DRIVECAL_JAX_CACHE_DIR``.
    """
    if not cache_enabled():
        return
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    path = os.environ.get("DRIVECAL_JAX_CACHE_DIR") or str(Path(base) / "drivecal" / "jax")
    jax.config.update("jax_compilation_cache_dir", path)
    # drivecal's kernels compile in well under JAX's default 1 s threshold.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


_enable_compilation_cache()
