"""D-optimal design: the improved default plan shrinks the predicted confidence volume at equal
time budget, stays feasible, and a Monte Carlo fit on the Jaxonomy engine realises the predicted shrinkage."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import special, stats

import drivecal as dc
from drivecal.cli import main
from drivecal.model import stack_experiments
from drivecal.design import (BUDGET_ROOM, CURRENT_MARGIN, VOLTAGE_FRACTION, load_plan_waveforms, margin_problems,
                             min_durations, predicted_covariance)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
NOISE = 0.02  # A
DRAWS = 200  # noise realisations per plan


@pytest.fixture(scope="module")
def optimal() -> dc.OptimalDesign:
    return dc.optimize_plan(dc.default_plan(), dc.DEFAULT_MOTOR, noise_sigma=NOISE)


def test_optimal_plan_shrinks_the_confidence_volume_within_the_plan_margins(optimal):
    before, after = optimal.plan_before, optimal.plan_after
    assert optimal.improved
    # The default plan's 10 ms locked steps are shorter than the 3 L/R (21 and 39 ms) `drivecal plan` keeps:
    # the budget is raised to BUDGET_ROOM times the margins' least total (it was the input's 70 ms before issue 22).
    need = float(min_durations(before, dc.DEFAULT_MOTOR).sum())
    assert before.num_samples == 1400 and optimal.message.startswith("budget raised from 0.07 s")
    assert abs(after.num_samples - BUDGET_ROOM * need * after.sample_rate) <= 1
    assert math.isclose(sum(s.duration for s in after.segments), optimal.budget, rel_tol=1e-12)
    # same structure: segment names, order, locked/free, excited axes
    for sb, sa in zip(before.segments, after.segments):
        assert (sa.name, sa.locked) == (sb.name, sb.locked)
        for axis in ("v_d", "v_q"):
            assert (np.any(getattr(sa, axis)) != 0) == (np.any(getattr(sb, axis)) != 0)
    # feasible: voltage circle on every sample, predicted peak current under the limit, identifiable
    after.check_feasible()
    volts = np.concatenate([s.voltages(after.sample_rate) for s in after.segments])
    assert np.max(np.hypot(volts[:, 0], volts[:, 1])) <= after.voltage_limit * (1 + 1e-12)
    report = dc.assess_design(after, dc.DEFAULT_MOTOR, noise_sigma=NOISE)
    assert report.ok and not report.problems
    assert all(s.peak_current <= after.current_limit for s in report.segments)
    # the reported numbers are the exact re-evaluation of the rounded plans
    cov_b = predicted_covariance(before, dc.DEFAULT_MOTOR, noise_sigma=NOISE)
    cov_a = predicted_covariance(after, dc.DEFAULT_MOTOR, noise_sigma=NOISE)
    assert optimal.logdet_before == pytest.approx(np.linalg.slogdet(cov_b)[1], abs=1e-9)
    assert optimal.logdet_after == pytest.approx(np.linalg.slogdet(cov_a)[1], abs=1e-9)
    np.testing.assert_allclose(optimal.ci95_after, report.identifiability.predicted_ci95, rtol=1e-12)
    # a much smaller confidence region: every interval narrower, the volume at least 5x smaller (10x before the
    # margins held the peaks to 80 % of the current limit)
    assert np.all(optimal.ci95_after < optimal.ci95_before)
    assert optimal.volume_ratio < 0.2
    assert optimal.det_ratio == pytest.approx(optimal.volume_ratio**2)


@pytest.mark.slow
def test_optimisation_keeps_waveform_kinds_and_the_budget(tmp_path):
    """A chirp plan stays a chirp plan (bands inside Nyquist) and follows --budget."""
    plan, specs = load_plan_waveforms(EXAMPLES / "chirp_plan.toml")
    result = dc.optimize_plan(plan, dc.DEFAULT_MOTOR, waveforms_spec=specs, budget=0.09, max_steps=15)
    assert result.improved and result.report_after.ok
    assert result.plan_after.num_samples == 1800 and not margin_problems(result.report_after, dc.DEFAULT_MOTOR)
    for seg in ("locked d-chirp", "locked q-chirp"):
        axis = "v_d" if "d-" in seg else "v_q"
        spec = result.waveforms_after[(seg, axis)]
        assert spec["kind"] == "chirp" and spec["sweep"] == "log"
        assert 0 < spec["f_start"] < plan.sample_rate / 2 and 0 < spec["f_stop"] < plan.sample_rate / 2
    out = dc.write_plan(tmp_path / "chirp_opt.toml", result.plan_after,
                               {k: v for k, v in result.waveforms_after.items() if isinstance(v, dict)})
    reloaded = dc.load_plan(out)
    np.testing.assert_allclose(np.concatenate([s.voltages(20e3) for s in reloaded.segments]),
                               np.concatenate([s.voltages(20e3) for s in result.plan_after.segments]), atol=1e-9)


def _logdet_sd(n: int, draws: int) -> float:
    """Standard deviation of log det of a sample covariance (n parameters, ``draws`` Gaussian samples).

    log det S - log det Sigma is a sum of n independent log chi-square terms (Bartlett), so
    Var = sum_i trigamma((draws - i) / 2).
    """
    return math.sqrt(sum(special.polygamma(1, (draws - i) / 2) for i in range(1, n + 1)))


@pytest.mark.slow
def test_monte_carlo_realises_the_predicted_shrinkage(optimal):
    truth = dc.DEFAULT_MOTOR
    plans = {"before": optimal.plan_before, "after": optimal.plan_after}
    clean = {k: dc.engine_bench(p, truth) for k, p in plans.items()}  # the Jaxonomy engine is the truth
    rng = np.random.default_rng(20240604)
    # one batched call of 200 fits per plan (since issue 22 the plans differ in length: the budget is raised
    # to the margins' least durations, 1400 -> 1804 samples)
    cals = {}
    for k, b in clean.items():
        currents = b.currents[None] + rng.normal(0.0, NOISE, (DRAWS,) + b.currents.shape)
        cals[k] = dc.fit_currents(stack_experiments([b.experiment()] * DRAWS), currents, truth)
        assert cals[k].converged.all(), k
    cal = cals["before"]
    est = {k: c.estimate for k, c in cals.items()}
    se = {k: c.se for k, c in cals.items()}
    n = len(cal.names)

    # per parameter: ratio of sample variances ~ (predicted ratio) * F(DRAWS-1, DRAWS-1);
    # two-sided 99.8 % band per parameter (Bonferroni: < 1 % for the four together)
    var_ratio = est["after"].var(axis=0, ddof=1) / est["before"].var(axis=0, ddof=1)
    predicted = np.diag(optimal.covariance_after) / np.diag(optimal.covariance_before)
    low, high = stats.f.ppf([0.001, 0.999], DRAWS - 1, DRAWS - 1)
    assert np.all(var_ratio / predicted > low) and np.all(var_ratio / predicted < high), (var_ratio, predicted)

    # the confidence volume: log det of the empirical covariances against the predicted log det ratio;
    # the Wishart bias cancels in the difference, its spread is sqrt(2) * _logdet_sd
    logdet = {k: np.linalg.slogdet(np.cov(v, rowvar=False))[1] for k, v in est.items()}
    realised = logdet["after"] - logdet["before"]
    predicted_logdet = optimal.logdet_after - optimal.logdet_before
    assert abs(realised - predicted_logdet) < 4.0 * math.sqrt(2.0) * _logdet_sd(n, DRAWS), (realised,
                                                                                             predicted_logdet)
    # the fits report the shrinkage too: mean reported SE ratio = predicted SE ratio, within 5 standard
    # errors of the ratio of means (delta method on the 200 reported SEs of each plan)
    mean = {k: v.mean(axis=0) for k, v in se.items()}
    sem = {k: v.std(axis=0, ddof=1) / math.sqrt(DRAWS) for k, v in se.items()}
    ratio = mean["after"] / mean["before"]
    ratio_sd = ratio * np.hypot(sem["after"] / mean["after"], sem["before"] / mean["before"])
    np.testing.assert_array_less(np.abs(ratio - optimal.se_after / optimal.se_before), 5 * ratio_sd + 1e-3)
    # and the intervals are honest on both plans: each covers the truth at about its nominal 95 %
    for k in plans:
        lo, hi = est[k] - cals[k].t_factor * se[k], est[k] + cals[k].t_factor * se[k]
        theta = np.asarray(truth.vector(cal.names))
        coverage = np.mean((lo <= theta) & (theta <= hi), axis=0)
        assert np.all(np.abs(coverage - 0.95) < 4 * math.sqrt(0.95 * 0.05 / DRAWS)), (k, coverage)


def test_cli_design_optimize_writes_a_plan_that_passes_design(tmp_path, capsys, optimal):
    out = tmp_path / "opt.toml"
    assert main(["design", str(EXAMPLES / "default_plan.toml"), "--optimize", "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["improved"] and doc["after"]["feasible"] and doc["after"]["identifiable"]
    assert doc["volume_ratio"] == pytest.approx(optimal.volume_ratio, rel=1e-6)
    assert set(doc["predicted"]) == {"R", "Ld", "Lq", "lambda_m"}
    assert all(p["ci95_half_width_after"] < p["ci95_half_width_before"] for p in doc["predicted"].values())
    assert main(["design", str(out)]) == 0  # the written plan loads and passes design
    assert "identifiable" in capsys.readouterr().out
    loaded = dc.load_plan(out)
    assert loaded.num_samples == optimal.plan_after.num_samples and [s.name for s in loaded.segments] == [
        s.name for s in optimal.plan_after.segments]
    # It records the noise it was judged at (the default: the input plan records none), for design and simulate.
    assert loaded.current_noise == 0.02 and doc["noise_source"] == "default; no current_noise in the plan"


def _peak_volts(plan: dc.Plan) -> float:
    volts = np.concatenate([s.voltages(plan.sample_rate) for s in plan.segments])
    return float(np.max(np.hypot(volts[:, 0], volts[:, 1])))


def test_optimised_default_and_multisine_plans_keep_the_margins_of_plan(optimal):
    """`design --optimize` keeps what `drivecal plan` promises: peaks under 80 % of the current limit, voltages
    inside 90 % of the circle, every segment 200 samples and a locked one 3 L/R long at least."""
    plan, specs = load_plan_waveforms(EXAMPLES / "multisine_plan.toml")
    multisine = dc.optimize_plan(plan, dc.DEFAULT_MOTOR, waveforms_spec=specs, noise_sigma=NOISE)
    tau = {"v_d": 3.2e-3 / 0.45, "v_q": 5.8e-3 / 0.45}
    for result in (optimal, multisine):
        # the inputs break the durations (10 and 20 ms locked steps), the results hold every margin
        assert any("under its least" in p for p in margin_problems(result.report_before, dc.DEFAULT_MOTOR))
        after, report = result.plan_after, result.report_after
        assert report.ok and margin_problems(report, dc.DEFAULT_MOTOR) == ()
        assert max(p.peak_current for p in report.segments) <= CURRENT_MARGIN * after.current_limit * (1 + 1e-6)
        assert _peak_volts(after) <= VOLTAGE_FRACTION * after.voltage_limit * (1 + 1e-9)
        for seg in after.segments:
            assert seg.num_samples(after.sample_rate) >= 200
            if seg.locked:
                longest = max(t for axis, t in tau.items() if np.any(getattr(seg, axis)))
                assert seg.duration >= 3.0 * longest - 1.0 / after.sample_rate
        # the waveforms are what their tables say: a multisine kept its tones (a collapsed one is a constant)
        for (name, axis), spec in result.waveforms_after.items():
            if isinstance(spec, dict) and spec["kind"] == "multisine":
                assert spec["amplitude"] > 0.02 * (spec["amplitude"] + abs(spec["offset"])) and "multisine" in name


@pytest.mark.parametrize("argv, message", [
    (["--optimize"], "--optimize needs --out"),
    (["--budget", "0.05"], "--budget and --out go with --optimize"),
    (["--optimize", "--budget", "-1", "--out", "x.toml"], "must be a positive"),
])
def test_cli_optimize_bad_options_exit_2(argv, message, capsys):
    with pytest.raises(SystemExit) as info:
        main(["design", str(EXAMPLES / "default_plan.toml"), *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_optimize_refuses_a_plan_with_a_structural_gap(tmp_path, capsys):
    out = tmp_path / "opt.toml"
    with pytest.raises(SystemExit) as info:
        main(["design", str(EXAMPLES / "seed_poor_plan.toml"), "--optimize", "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("drivecal: error: the plan cannot identify Ld, lambda_m") and err.count("\n") == 1
    assert not out.exists()
