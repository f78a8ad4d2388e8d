"""A single fit's Levenberg-Marquardt stepped from the host (``fitting._host_lm``) takes the compiled solve's steps.

The compiled solve is what a batch runs (optimistix's loop with drivecal's descent, vmapped): the same data
twice in a batch of two is solved there, and alone by the host loop. Both must take the same steps and end the
same way; the estimates may differ only by the order of floating-point sums (numpy's against XLA's), far
below any statistical meaning: 1e-9 standard errors (measured: at most 4e-12 on fits of 2 to 31 steps).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import optimistix as optx
import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.fitting import FitOptions, _host_lm, fit_currents  # this file tests the host loop
from drivecal.model import model_experiment
from drivecal.results import solver_code


def test_endings_and_trust_region_are_optimistixs():
    """The RESULTS indices and ClassicalTrustRegion constants the host loop uses are optimistix's own."""
    codes = (optx.RESULTS.successful, optx.RESULTS.singular, optx.RESULTS.nonlinear_max_steps_reached,
             optx.RESULTS.nonfinite)
    assert (_host_lm.SUCCESSFUL, _host_lm.SINGULAR, _host_lm.MAX_STEPS_REACHED, _host_lm.NONFINITE) == tuple(
        int(solver_code(c)) for c in codes)
    region = optx.ClassicalTrustRegion()
    assert (_host_lm.LOW_CUTOFF, _host_lm.HIGH_CUTOFF, _host_lm.LOW_CONSTANT, _host_lm.HIGH_CONSTANT) == (
        region.low_cutoff, region.high_cutoff, region.low_constant, region.high_constant)


CASES = {
    "from the data": dict(),
    "from the datasheet guess, 30-50 % off": dict(start="guess"),
    "stopped at its step limit": dict(start="guess", options=FitOptions(max_steps=2)),
    "R and lambda_m only": dict(names=("R", "lambda_m")),
}


@pytest.mark.parametrize("case", CASES)
def test_host_steps_are_the_compiled_solves(case, default_bench, guess):
    spec = CASES[case]
    names = spec.get("names", dc.ESTIMATED)
    options = dataclasses.replace(spec.get("options", FitOptions()), first_pass_steps=None)
    initial = guess if spec.get("start") == "guess" else None
    experiment = model_experiment(default_bench.experiment(), guess, names)
    currents = np.asarray(default_bench.currents)

    alone = fit_currents(experiment, currents, guess, names=names, options=options, initial=initial)
    batch = fit_currents(experiment, np.stack([currents, currents]), guess, names=names, options=options,
                         initial=initial)
    compiled = batch[0]

    assert int(alone.iterations) == int(compiled.iterations)
    assert int(alone.result_code) == int(compiled.result_code)
    assert bool(alone.converged) == bool(compiled.converged)
    if case == "stopped at its step limit":
        assert int(alone.result_code) == _host_lm.MAX_STEPS_REACHED and not bool(alone.converged)
    se = np.asarray(compiled.se)
    assert np.all(np.abs(np.asarray(alone.estimate) - np.asarray(compiled.estimate)) <= 1e-9 * se)
    np.testing.assert_allclose(alone.se, compiled.se, rtol=1e-9)
    np.testing.assert_allclose(alone.sigma_hat, compiled.sigma_hat, rtol=1e-12)
    np.testing.assert_allclose(alone.initial, compiled.initial, rtol=1e-12)
    # The residuals of the last accepted point, model minus measured (A): sigma_hat is 20 mA here.
    np.testing.assert_allclose(alone.residuals, compiled.residuals, rtol=0, atol=1e-9 * NOISE)
    # The path the convergence figure draws: the start, each accepted point, the final Gauss-Newton step.
    assert alone.history.shape[0] >= 2 and np.array_equal(alone.history[-1], alone.estimate[
        [alone.names.index(n) for n in alone.fit_names]])
