"""The bench effects chosen by the data (selection/_select.py), on benches drivecal did not make.

The realistic bench is the independent switching-level plant (drivecal.bench.
pwm_bench: carrier-comparison SVPWM, currents sampled at the carrier peak,
computation delay, dead time per edge); the one-cause benches run on the
Jaxonomy engine. Every fit here is the default: ``select_effects(...,
effects="auto")`` from the nominal motor with a nominal delay of 0, as
``drivecal fit`` runs it with no flags.

Tolerances are the statistics': 3 standard errors for R, Ld, Lq, lambda_m
(a 0.3 % event per parameter for a correct interval), and the reported delay's
95 % interval must hold the truth (fixed noise seeds: the test is deterministic).
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import pwm_bench
from drivecal.fitting import fit_currents
from drivecal.identify import assess_identifiability
from drivecal.report import build_result
from drivecal.selection import parse_effects, select_effects

NOISE = 0.02  # A
MOTOR = dc.DEFAULT_MOTOR
#: The issue's realistic inverter: 10 kHz carrier and sampling, 48 V, 1 us dead time (0.48 V per phase).
PLAN_10K = dc.Plan(dc.default_plan().segments, sample_rate=10_000.0)
T_DEAD = 1e-6


def _select(bench, effects="auto"):
    experiment = bench.experiment(measured_speed=True)
    return select_effects(experiment, bench.currents, MOTOR, names=dc.ESTIMATED, effects=effects,
                          source=bench.source)


def _z(cal, truth=MOTOR):
    return {n: (cal.estimate[cal.names.index(n)] - float(getattr(truth, n))) / cal.se[cal.names.index(n)]
            for n in dc.ESTIMATED}


def _choice(selection, effect):
    return next(c for c in selection.choices if c.effect == effect)


def _verdict(selection, bench):
    doc = build_result(selection.calibration, bench, experiment=selection.experiment, noise_sigma=NOISE,
                       effects=selection.to_dict())
    return doc["verdict"]


def test_parse_effects():
    assert parse_effects("auto") == "auto" and parse_effects("none") == "none"
    assert parse_effects("offsets, dead-time") == ("dead_time", "offsets")
    with pytest.raises(dc.DrivecalError, match="unknown effect.*ripple"):
        parse_effects("delay,ripple")


@pytest.mark.slow
@pytest.mark.parametrize("delay", [0, 0.5, 1, 1.5, 2])
def test_default_fit_finds_the_delay_of_a_switching_inverter(delay):
    bench = pwm_bench(dc.default_plan(), MOTOR, delay_samples=delay, noise=NOISE, seed=11, substeps=16)
    selection = _select(bench)
    assert _verdict(selection, bench)["status"] == "calibrated"
    for name, z in _z(selection.calibration).items():
        assert abs(z) < 3.0, (delay, name, z)
    choice = _choice(selection, "delay")
    # A delay of 0 is not added (nothing to find): reported with its one-step estimate and interval.
    assert choice.included == (delay > 0), choice
    value, se = choice.estimate["delay"]
    assert abs(value - delay) < 1.96 * se, (delay, value, se)
    assert selection.included in ((), ("delay",))


@pytest.fixture(scope="module")
def dead_time_clean():
    """The issue's realistic bench: 10 kHz, 48 V, 1 us dead time, one sample of delay; no noise."""
    return pwm_bench(PLAN_10K, MOTOR, delay_samples=1, t_dead=T_DEAD, substeps=16)


@pytest.mark.slow
def test_default_fit_models_the_dead_time_by_itself(dead_time_clean):
    bench = dead_time_clean.add_noise(NOISE, 5)
    selection = _select(bench)
    assert set(selection.included) == {"delay", "dead_time"}
    for name, z in _z(selection.calibration).items():
        assert abs(z) < 3.0, (name, z)
    v_dead, se = _choice(selection, "dead_time").estimate["v_dead"]
    assert abs(v_dead - 48.0 * T_DEAD * 10_000.0) < 0.05 * 0.48  # the dead time's volt-seconds, within 5 %
    # No offsets are invented: their estimate from the final fit is within 3 SE of zero.
    for name, (value, se) in _choice(selection, "offsets").estimate.items():
        assert abs(value) < 3.0 * se, (name, value, se)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "measured 2026-11-24: coverage R 0.935, Ld 0.905, Lq 0.940, lambda_m 0.885 (mean z -0.80), delay 0.83. "
    "Measured 2026-11-25 on the noise-free bench (bias of the fit over the SE of 64 noisy fits): the selection's "
    "model gives Ld -0.77 SE, lambda_m +0.91 SE; the switching plant's exact per-period dq voltage integrals "
    "(Park at the instantaneous angle) given as inputs, with no dead-time model, still give lambda_m -0.52 SE and "
    "Lq -0.57 SE (0.1 SE without dead time). So two parts: the tanh average law's shape, and the dead time inside "
    "the PWM period (the pulse of a phase near zero current is not shifted by t_dead/2 as the others are; the "
    "mean-ripple correction this predicts through R and w_e*L is 0.4 mV RMS and moved nothing). "
    "Measured 2026-11-27 (noise-free bench, bias over the SE of noisy fits): the average law's shape is not it "
    "(tanh lambda_m -0.73, clipped ramp -0.74, x/sqrt(1+x^2) alike; i_dead fitted 53-66 mA); SVPWM and sine, 16 "
    "and 64 plant substeps give the same; the bias grows with the dead time (0.5 us -0.57, 2 us -1.51, delay "
    "-0.08 / -0.99 / -2.06 SE at 0.5 / 1 / 2 us); the same 0.48 V as a device drop (sign of the instantaneous "
    "current all period, no dead intervals) gives lambda_m +0.23, delay -0.52. So it is the dead intervals at the "
    "switching edges (where each phase's error falls in the period, and the sign the ripple gives it there). "
    "Found 2026-11-27 (second stop): the residual sits in the spin-up's first 10 ms, where phase a starts at zero "
    "current and stays clamped near +45 mA (its PWM ripple) for ~100 samples: model minus plant i_d down to -26 mA. "
    "The ripple law (each phase's error decided at its two edges, mean current +- ripple: branch i17-ripple2) with "
    "a 10 mA smooth sign gives noise-free biases R +0.01, Ld -0.04, Lq +0.05, lambda_m -0.19, delay -0.12 SE "
    "(with 50 mA: Ld -0.73, lambda_m +0.35; the tanh law with 4 mA: lambda_m -4.5). With i_dead fitted it falls "
    "toward 0 and 22 % of 32 seeds do not converge; held at 10 mA, this test's 224 seeds all converge (7-17 "
    "steps, 8 min) with coverage R 0.933, Ld 0.969, Lq 0.946, lambda_m 0.942 (mean z -0.25). "
    "Issue 17 stays open until that branch lands"))
def test_coverage_on_the_dead_time_bench(dead_time_clean):
    """Monte Carlo over 224 noise seeds, one batched fit of the model the selection picks on this bench.

    Coverage of the 95 % intervals of R, Ld, Lq, lambda_m must lie in [0.90, 0.99]: with ~200 seeds the
    binomial standard error at 0.95 is 0.015, so a correct interval falls outside that band with
    probability < 1e-3 and an interval 30 % too narrow (coverage ~0.85) inside it with < 1e-3.
    """
    seeds = 224  # >= 200, a whole number of the solver's tiles of 32 fits (memory stays that of one tile)
    names = dc.ESTIMATED + ("delay", "v_dead", "i_dead")
    rng = np.random.default_rng(2026)
    currents = dead_time_clean.currents[None] + NOISE * rng.standard_normal((seeds,) + dead_time_clean.currents.shape)
    experiment = dead_time_clean.experiment(measured_speed=True)
    start = MOTOR.replace(delay=1.0, v_dead=0.45, i_dead=0.05)  # where the selection's one-step estimates start it
    ident = assess_identifiability(experiment, start, names=names)  # as the selection judges it
    cal = fit_currents(experiment, currents, MOTOR, names=names, initial=start, identifiability=ident)
    assert np.all(cal.converged)
    for name in dc.ESTIMATED:
        i = names.index(name)
        truth = float(getattr(MOTOR, name))
        covered = np.mean((cal.ci95[:, i, 0] <= truth) & (truth <= cal.ci95[:, i, 1]))
        assert 0.90 <= covered <= 0.99, (name, covered)


@pytest.fixture(scope="module")
def engine_effects(truth):
    """One bench per single cause, on the engine, encoder recorded."""
    plan = dc.default_plan()
    return {
        "delay": dc.engine_bench(plan, truth, delay_samples=1, record_speed=True).add_noise(NOISE, 21),
        "dead_time": dc.engine_bench(plan, truth.replace(v_dead=0.4), record_speed=True).add_noise(NOISE, 22),
        "offsets": dc.engine_bench(plan, truth.replace(offset_d=0.05, offset_q=-0.03),
                                   record_speed=True).add_noise(NOISE, 23),
    }


@pytest.mark.slow
@pytest.mark.parametrize("cause", ["delay", "dead_time", "offsets"])
def test_one_cause_one_effect(engine_effects, cause):
    """A bench with one effect: exactly that effect is fitted, and nothing is left to advise."""
    bench = engine_effects[cause]
    selection = _select(bench)
    assert selection.included == (cause,)
    verdict = _verdict(selection, bench)
    assert verdict["status"] == "calibrated", verdict
    # Without the selection the same bench names that cause first.
    plain = _select(bench, effects="none")
    doc = build_result(plain.calibration, bench, experiment=plain.experiment, noise_sigma=NOISE)
    suspected = [e["effect"] for e in doc["residuals"]["unmodelled_effects"] if e["suspected"]]
    assert suspected[:1] == [cause], suspected
    assert doc["verdict"]["headline"] == f"model mismatch suspected: most likely {cause.replace('_', ' ')} " \
                                         "(see the first detail for the fix)"


@pytest.mark.slow
def test_too_much_delay_is_told_less(engine_effects):
    bench = engine_effects["delay"]  # one sample of delay, fitted assuming two
    experiment = bench.experiment(measured_speed=True, delay_samples=2)
    cal = fit_currents(experiment, bench.currents, MOTOR.replace(delay=2.0), names=dc.ESTIMATED)
    doc = build_result(cal, bench, experiment=experiment, noise_sigma=NOISE)
    first = doc["residuals"]["unmodelled_effects"][0]
    assert first["effect"] == "delay" and first["suspected"] and first["direction"] < 0
    assert "less PWM/computation delay" in first["message"] and "lower" in first["message"]
    assert doc["verdict"]["details"][0] == first["message"]
