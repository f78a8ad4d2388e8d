"""Shared, session-scoped fixtures: engine benches and the default fits are built once."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# The suite runs without drivecal's on-disk compilation cache (unless DRIVECAL_JAX_CACHE is set): in
# jaxlib 0.9.2 XLA:CPU's executable serialisation is not reliable enough for a suite that compiles
# thousands of kernels (a test worker aborted inside executable.serialize(), another crashed inside
# deserialize_executable, each about once in a few full runs), and one crashed pytest-xdist worker
# breaks the whole run. Set before drivecal starts JAX; the cache's own tests give it a temporary folder.
os.environ.setdefault("DRIVECAL_JAX_CACHE", "0")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import drivecal as dc  # noqa: E402
# JAX set up as a command sets it up (float64, XLA's small-loop threshold in XLA_FLAGS: drivecal/_setup.py)
# before any fixture starts it: jaxonomy, imported below, starts JAX's backend at its import, and XLA reads
# its flags then.
import drivecal.physics  # noqa: E402, F401

NOISE = 0.02  # A, the default sensor noise

#: Memory mappings a test worker may hold before its compiled kernels are dropped (Linux allows
#: vm.max_map_count = 65530 a process by default).
MAX_MAPPINGS = 30_000


def _mappings() -> int:
    try:
        with open("/proc/self/maps", "rb") as f:
            return sum(1 for _ in f)
    except OSError:  # not Linux
        return 0


def pytest_collection_modifyitems(config, items):
    """Files with the most ``slow`` tests first, each file's tests in their order.

    pytest-xdist's ``--dist loadfile`` hands whole files to the two workers in collection order. In
    alphabetical order the longest files (the selections, the manual's pages: 5 to 25 min each) came
    last, where one worker can be left running one alone while the other has finished (seen: the backward
    step's 5 min at the end of a full run). Longest first, the short files fill both workers' ends.
    """
    slow: dict[str, int] = {}
    for item in items:
        slow[item.fspath.strpath] = slow.get(item.fspath.strpath, 0) + (item.get_closest_marker("slow") is not None)
    items[:] = sorted(items, key=lambda item: -slow[item.fspath.strpath])  # stable: a file's order kept


@pytest.fixture(autouse=True)
def _drop_compiled_kernels_before_the_map_limit():
    """Free every compiled kernel once a worker holds MAX_MAPPINGS memory mappings.

    Each XLA:CPU executable maps ~21 regions of memory, and jit caches keep them all: a test worker
    that compiles more than ~3 000 kernels reaches Linux's vm.max_map_count, where LLVM's next mmap
    fails and XLA crashes inside a compile or a cache read (seen as a segmentation fault or an abort
    three quarters into a full run, and a crashed xdist worker ends the run). ``jax.clear_caches()``
    unmaps them; later tests compile again what they need.
    """
    yield
    if _mappings() > MAX_MAPPINGS:
        import gc

        import jax

        jax.clear_caches()
        gc.collect()


@pytest.fixture(scope="session")
def truth() -> dc.MotorParams:
    return dc.DEFAULT_MOTOR


@pytest.fixture(scope="session")
def guess(truth) -> dc.MotorParams:
    """Datasheet guess 30-50 % off: the prior and the starting point."""
    return dc.datasheet_guess(truth)


@pytest.fixture(scope="session")
def clean_default(truth) -> dc.BenchData:
    """Noise-free default plan on the Jaxonomy engine."""
    return dc.engine_bench(dc.default_plan(), truth)


@pytest.fixture(scope="session")
def clean_poor(truth) -> dc.BenchData:
    """Noise-free locked q-step on the Jaxonomy engine."""
    return dc.engine_bench(dc.locked_q_step_plan(), truth)


@pytest.fixture(scope="session")
def default_bench(clean_default) -> dc.BenchData:
    """The default scenario's data: sigma 20 mA, seed 1."""
    return clean_default.add_noise(NOISE, 1)


@pytest.fixture(scope="session")
def poor_bench(clean_poor) -> dc.BenchData:
    return clean_poor.add_noise(NOISE, 2)


@pytest.fixture(scope="session")
def default_fit(default_bench, guess) -> dc.Calibration:
    """The default scenario: sigma 20 mA, seed 1, the guess as prior, the search started from the data."""
    return dc.fit(default_bench, guess)


@pytest.fixture(scope="session")
def poor_fit(poor_bench, guess) -> dc.Calibration:
    return dc.fit(poor_bench, guess)


@pytest.fixture(scope="session")
def demo_run(tmp_path_factory):
    """One real `drivecal demo --json --out DIR` in a fresh process: (CompletedProcess, DIR)."""
    out = tmp_path_factory.mktemp("demo") / "out"
    exe = Path(sys.executable).with_name("drivecal")
    proc = subprocess.run([str(exe), "demo", "--json", "--out", str(out)], capture_output=True, text=True,
                          timeout=600)
    return proc, out


def true_vector(truth: dc.MotorParams) -> np.ndarray:
    return np.asarray(truth.vector(dc.ESTIMATED))


@pytest.fixture(autouse=True, scope="session")
def _quiet_jaxonomy():
    from jaxonomy import logging as jx_logging

    jx_logging.set_log_level(jx_logging.WARNING)
