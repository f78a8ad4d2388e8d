"""The fit on the synthetic bench: accuracy, honest intervals, convergence, poor designs."""

from __future__ import annotations

import json

import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE, true_vector


def test_default_scenario_recovers_the_truth(default_fit, truth):
    cal = default_fit
    true = true_vector(truth)
    assert cal.converged and cal.message == "converged"
    assert all(cal.identifiable)
    z = (cal.estimate - true) / cal.se
    assert np.all(np.abs(z) < 3.0), z
    assert np.all(np.abs(cal.estimate - true) / true < 5e-4)  # under 0.05 %
    assert np.all((cal.ci95[:, 0] < cal.estimate) & (cal.estimate < cal.ci95[:, 1]))
    assert abs(float(cal.sigma_hat) - NOISE) < 0.05 * NOISE  # sigma_hat is an estimate of the injected noise


def test_intervals_are_student_t(default_fit):
    from scipy import stats

    cal = default_fit
    assert cal.dof == 2800 - 4
    assert cal.t_factor == pytest.approx(stats.t.ppf(0.975, 2796))
    np.testing.assert_allclose(cal.ci95[:, 1] - cal.estimate, cal.t_factor * cal.se)
    np.testing.assert_allclose(np.sqrt(np.diag(cal.covariance)), cal.se)
    corr = cal.correlation
    np.testing.assert_allclose(np.diag(corr), 1.0)
    assert np.all(np.abs(corr) <= 1.0 + 1e-12)


def test_history_starts_at_the_start_and_ends_at_the_estimate(default_fit):
    hist = default_fit.history
    np.testing.assert_allclose(hist[0], default_fit.initial)
    np.testing.assert_allclose(hist[-1], default_fit.estimate, rtol=1e-10)
    assert hist.shape[0] >= 2


def test_history_from_the_guess(default_bench, guess, default_fit):
    """Started at the datasheet guess (30-50 % off) the search ends where the data start led."""
    cal = dc.fit(default_bench, guess, options=dc.FitOptions(start="prior"))
    np.testing.assert_allclose(cal.history[0], np.asarray(guess.vector()))
    np.testing.assert_allclose(cal.initial, np.asarray(guess.vector()))
    assert cal.iterations > default_fit.iterations
    assert np.all(np.abs(cal.estimate - default_fit.estimate) < 1e-3 * default_fit.se)


def test_residuals_are_the_model_at_the_estimate_minus_the_data(default_fit, default_bench):
    """What the fleet tests for whiteness: the solver's residuals, equal to a fresh prediction at the estimate."""
    from drivecal.model import predicted_currents

    res = default_fit.residuals
    assert res.shape == (default_bench.num_samples, 2)
    assert np.sum(res**2) == pytest.approx(float(default_fit.rss), rel=1e-12)
    diff = res - (predicted_currents(default_fit.motor, default_bench.experiment()) - default_bench.currents)
    # They differ by the final Gauss-Newton step (at most step_se SE): J times it has an rms over the
    # m residuals of at most step_se * sigma * sqrt(n / m).
    m, n = res.size, len(default_fit.fit_names)
    bound = dc.FitOptions().step_se * float(default_fit.sigma_hat) * np.sqrt(n / m)
    assert np.sqrt(np.mean(diff**2)) <= bound


def test_result_json_contract(default_fit):
    d = json.loads(json.dumps(default_fit.to_dict()))
    for name in dc.ESTIMATED:
        p = d["parameters"][name]
        assert set(p) >= {"estimate", "se", "ci95", "unit", "identifiable"}
        assert p["identifiable"] is True and len(p["ci95"]) == 2
    assert d["names"] == list(dc.ESTIMATED)
    assert np.asarray(d["covariance"]).shape == (4, 4) and np.asarray(d["correlation"]).shape == (4, 4)
    assert d["converged"] is True and d["iterations"] > 0 and d["sigma_hat"] > 0
    ident = d["identifiability"]
    assert set(ident) >= {"rank", "condition_number", "identifiable", "weak_params", "dead_params", "singular_values"}
    assert d["fixed"] == {"pole_pairs": 4.0, "J": 1.2e-3, "B": 8e-5}


def test_printed_calibration_is_a_table(default_fit):
    text = str(default_fit)
    assert "converged" in text and "95% CI" in text
    for name in dc.ESTIMATED:
        assert name in text


def test_poor_design_names_dead_parameters_and_still_recovers_r_and_lq(poor_fit, guess, truth):
    cal = poor_fit
    ident = cal.identifiability
    assert ident.rank == 2 and set(ident.dead_params) == {"Ld", "lambda_m"}
    assert cal.identifiable == (True, False, True, False)
    assert cal.fit_names == ("R", "Lq")
    # dead parameters: held at the prior, not reported as calibrated
    assert cal.estimate[1] == guess.Ld and cal.estimate[3] == guess.lambda_m
    assert np.all(np.isnan(cal.se[[1, 3]]))
    d = cal.to_dict()
    assert d["parameters"]["Ld"]["identifiable"] is False and d["parameters"]["Ld"]["ci95"] is None
    assert d["fixed"]["Ld"] == guess.Ld and d["names"] == ["R", "Lq"]
    # the excited ones come back
    true = true_vector(truth)
    assert cal.converged
    for i in (0, 2):
        assert abs(cal.estimate[i] - true[i]) < 3 * cal.se[i]


def test_nothing_identifiable_is_refused(truth):
    plan = dc.Plan(segments=(dc.Segment("idle", 0.005, True),))
    bench = dc.engine_bench(plan, truth)
    with pytest.raises(dc.DrivecalError, match="identifies none"):
        dc.fit(bench, truth)


def test_bad_currents_are_refused(clean_default, guess):
    y = clean_default.currents.copy()
    y[5, 0] = np.nan
    with pytest.raises(dc.DrivecalError, match="NaN or Inf"):
        dc.fit_currents(clean_default.experiment(), y, guess)


@pytest.mark.slow
def test_monte_carlo_coverage_and_spread(clean_default, truth, guess):
    """>= 200 noise realisations fitted in one batched call: the intervals are honest."""
    n = 240
    rng = np.random.default_rng(2024)
    currents = clean_default.currents[None] + rng.normal(0.0, NOISE, size=(n,) + clean_default.currents.shape)
    batch = dc.fit_currents(clean_default.experiment(), currents, guess)
    assert batch.batch_shape == (n,)
    assert np.all(batch.converged)
    true = true_vector(truth)
    covered = (batch.ci95[..., 0] <= true) & (true <= batch.ci95[..., 1])
    coverage = covered.mean(axis=0)
    assert np.all((coverage >= 0.90) & (coverage <= 0.99)), coverage
    spread = batch.estimate.std(axis=0, ddof=1) / batch.se.mean(axis=0)
    assert np.all(np.abs(spread - 1.0) <= 0.20), spread
    # and no bias beyond what n fits can resolve
    bias_z = (batch.estimate.mean(axis=0) - true) / (batch.se.mean(axis=0) / np.sqrt(n))
    assert np.all(np.abs(bias_z) < 4.0), bias_z


@pytest.mark.slow
def test_random_starts_converge_to_the_same_estimate(clean_default, truth):
    """>= 100 starts within +-50 % of the truth, batched: one answer."""
    n = 120
    rng = np.random.default_rng(7)
    true = true_vector(truth)
    starts = true * rng.uniform(0.5, 1.5, size=(n, 4))
    bench = clean_default.add_noise(NOISE, 1)
    currents = np.broadcast_to(bench.currents, (n,) + bench.currents.shape)
    batch = dc.fit_currents(bench.experiment(), currents, truth, initial=starts)
    assert np.all(batch.converged)
    ref = batch.estimate[0]
    se = batch.se[0]
    assert np.max(np.abs(batch.estimate - ref) / se) < 1e-3
