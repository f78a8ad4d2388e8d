"""Shared, session-scoped fixtures: engine benches and the default fits are built once."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

# Each pytest-xdist worker keeps its compiled kernels in a folder of its own (set before drivecal
# starts JAX): the two workers then never load a kernel the other is writing. drivecal itself
# guards that with JAX's file lock (drivecal/_setup.py); the suite does not rely on it alone.
if os.environ.get("PYTEST_XDIST_WORKER") and "DRIVECAL_JAX_CACHE_DIR" not in os.environ:
    _base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    os.environ["DRIVECAL_JAX_CACHE_DIR"] = str(Path(_base) / "drivecal" / f"jax-tests-{os.environ['PYTEST_XDIST_WORKER']}")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import drivecal as dc  # noqa: E402

NOISE = 0.02  # A, the default sensor noise


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
