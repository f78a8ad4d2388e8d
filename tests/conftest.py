"""Shared, session-scoped fixtures: engine benches and the default fits are built once."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc

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
def default_fit(clean_default, guess) -> dc.Calibration:
    """The default scenario: sigma 20 mA, seed 1, start at the guess."""
    return dc.fit(clean_default.add_noise(NOISE, 1), guess)


@pytest.fixture(scope="session")
def poor_fit(clean_poor, guess) -> dc.Calibration:
    return dc.fit(clean_poor.add_noise(NOISE, 2), guess)


def true_vector(truth: dc.MotorParams) -> np.ndarray:
    return np.asarray(truth.vector(dc.ESTIMATED))


@pytest.fixture(autouse=True, scope="session")
def _quiet_jaxonomy():
    from jaxonomy import logging as jx_logging

    jx_logging.set_log_level(jx_logging.WARNING)
