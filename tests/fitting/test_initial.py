"""The equation-error start: exact on noise-free data, ~1 % on noisy data, the prior where blind."""

from __future__ import annotations

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE, true_vector
from drivecal.fitting import equation_error_start

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _start(bench: dc.BenchData, prior: dc.MotorParams, measured_speed: bool = True) -> np.ndarray:
    experiment = bench.experiment(measured_speed=measured_speed)
    return np.asarray(equation_error_start(experiment, jnp.asarray(bench.currents)[None], prior, dc.ESTIMATED))[0]


@pytest.fixture(scope="module")
def spinning_clean(truth):
    return dc.engine_bench(dc.default_plan(), truth, record_speed=True)


def test_noise_free_default_plan_gives_the_truth(clean_default, spinning_clean, truth, guess):
    """Locked segments: the regression is the RK4 step itself (exact); lambda_m: trapezoid, ~1e-6."""
    true = true_vector(truth)
    for bench, measured in ((clean_default, False), (spinning_clean, True), (spinning_clean, False)):
        rel = _start(bench, guess, measured) / true - 1.0
        assert np.all(np.abs(rel[:3]) < 1e-9), rel
        assert abs(rel[3]) < 1e-5, rel


def test_noise_free_chirp_plan_gives_the_truth(truth, guess):
    bench = dc.engine_bench(dc.load_plan(EXAMPLES / "chirp_plan.toml"), truth, record_speed=True)
    rel = _start(bench, guess) / true_vector(truth) - 1.0
    assert np.all(np.abs(rel) < 1e-5), rel


def test_noisy_starts_are_within_a_few_percent(clean_default, truth, guess):
    """64 noise seeds: the start scatters by ~1 % (the instrument costs variance, not bias)."""
    rng = np.random.default_rng(7)
    currents = clean_default.currents[None] + rng.normal(0.0, NOISE, (64,) + clean_default.currents.shape)
    starts = np.asarray(equation_error_start(clean_default.experiment(), jnp.asarray(currents), guess,
                                             dc.ESTIMATED))
    rel = starts / true_vector(truth) - 1.0
    assert np.all(np.abs(rel) < 0.05), np.abs(rel).max(axis=0)
    # unbiased: the mean over the seeds sits within 4 standard errors of the mean of zero
    assert np.all(np.abs(rel.mean(axis=0)) < 4.0 * rel.std(axis=0) / np.sqrt(64)), (rel.mean(0), rel.std(0))


def test_what_the_data_cannot_tell_starts_at_the_prior(poor_bench, guess):
    """Locked q-step only: no d-axis voltage, no spin-up; Ld and lambda_m start at the prior."""
    start = _start(poor_bench, guess)
    assert start[1] == guess.Ld and start[3] == guess.lambda_m
    assert abs(start[0] / dc.DEFAULT_MOTOR.R - 1.0) < 0.1 and abs(start[2] / dc.DEFAULT_MOTOR.Lq - 1.0) < 0.1


def test_the_fit_records_the_data_start(default_fit, default_bench, guess):
    np.testing.assert_allclose(default_fit.initial, _start(default_bench, guess))
    assert default_fit.iterations <= 6
