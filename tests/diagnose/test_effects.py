"""Bench effects: dead time, sensor offsets, PWM delay and winding temperature.

The truth runs on the Jaxonomy engine (dead time as a feedback block around
the PMSM block, the delay in the applied samples, R at each segment's
temperature); drivecal's forward model must agree with it, a fit that ignores
the effects must be visibly wrong, and a fit that models them must recover
the motor within its intervals.
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.model import model_experiment, predict_currents

NOISE = 0.02  # A
EFFECTS = dict(v_dead=0.4, offset_d=0.05, offset_q=-0.03)
DELAY = 1
WITH_EFFECTS = dc.ESTIMATED + ("v_dead", "offset_d", "offset_q")


@pytest.fixture(scope="module")
def effects_truth(truth):
    return truth.replace(**EFFECTS)


@pytest.fixture(scope="module")
def effects_clean(effects_truth):
    """Default plan on the engine with dead time, offsets and one sample of delay; encoder recorded."""
    return dc.engine_bench(dc.default_plan(), effects_truth, delay_samples=DELAY, record_speed=True)


@pytest.fixture(scope="module")
def effects_bench(effects_clean):
    return effects_clean.add_noise(NOISE, 1)


@pytest.fixture(scope="module")
def plain_fit(effects_bench, guess):
    return dc.fit(effects_bench, guess, measured_speed=False)


@pytest.fixture(scope="module")
def effects_fit(effects_bench, guess):
    return dc.fit(effects_bench, guess, names=WITH_EFFECTS, delay_samples=DELAY, measured_speed=False)


def _z(cal, truth):
    return {n: (cal.estimate[i] - float(getattr(truth, n))) / cal.se[i] for i, n in enumerate(cal.names)}


def test_forward_model_matches_engine_with_effects(effects_clean, effects_truth):
    experiment = model_experiment(effects_clean.experiment(measured_speed=False, delay_samples=DELAY), effects_truth,
                                  WITH_EFFECTS)
    error = np.abs(np.asarray(predict_currents(effects_truth, experiment)) - effects_clean.currents)
    # The smooth sign (10 mA) and the ripple's dead zone turn within one sample period where a phase current
    # crosses zero: the dead-time model's four RK4 sub-steps err by 2.7e-6 A there against the engine's
    # adaptive solver (one step per sample: 6e-5 A). The bound is 5e-4 of the 20 mA noise: no fit sees it.
    assert error.max() < 1e-5


def test_forward_model_matches_engine_offsets_delay_temperature(truth):
    motor = truth.replace(offset_d=0.05, offset_q=-0.03, alpha_R=3.93e-3)
    plan = dc.Plan(tuple(dc.Segment(f"{s.name} hot", s.duration, s.locked, s.v_d, s.v_q, temperature=80.0)
                         for s in dc.default_plan().segments))
    clean = dc.engine_bench(plan, motor, delay_samples=2)
    error = np.abs(np.asarray(predict_currents(motor, clean.experiment(delay_samples=2))) - clean.currents)
    assert error.max() < 1e-6


@pytest.mark.slow
def test_plain_fit_is_biased_beyond_its_intervals(plain_fit, effects_truth):
    r = plain_fit.names.index("R")
    low, high = plain_fit.ci95[r]
    assert not low <= float(effects_truth.R) <= high
    assert abs(_z(plain_fit, effects_truth)["R"]) > 10


@pytest.mark.slow
def test_fit_with_bench_effects_recovers_the_motor(effects_fit, effects_truth):
    assert bool(effects_fit.converged)
    assert effects_fit.fit_names == WITH_EFFECTS
    for name, z in _z(effects_fit, effects_truth).items():
        assert abs(z) < 3.0, (name, z)


@pytest.mark.slow
def test_diagnostics_flag_the_plain_fit_and_clear_the_full_one(plain_fit, effects_fit, effects_bench):
    plain = dc.build_result(plain_fit, effects_bench, experiment=effects_bench.experiment(measured_speed=False),
                            noise_sigma=NOISE)
    assert plain["verdict"]["status"] == "mismatch"
    suspected = {e["effect"] for e in plain["residuals"]["unmodelled_effects"] if e["suspected"]}
    assert "dead_time" in suspected
    assert any("dead time" in d and "v_dead" in d for d in plain["verdict"]["details"])
    assert any(s["i_d"]["rms"] > 1.5 * NOISE or s["i_q"]["rms"] > 1.5 * NOISE
               for s in plain["residuals"]["per_segment"])

    full = dc.build_result(effects_fit, effects_bench,
                           experiment=effects_bench.experiment(measured_speed=False, delay_samples=DELAY),
                           noise_sigma=NOISE)
    assert full["verdict"]["status"] == "calibrated", full["verdict"]
    # What is left to test: the delay, and (the bench records the encoder's angle) an encoder offset; neither shows.
    assert {e["effect"] for e in full["residuals"]["unmodelled_effects"]} == {"delay", "encoder_offset"}
    assert not any(e["suspected"] for e in full["residuals"]["unmodelled_effects"])
    assert full["parameters"]["v_dead"]["unit"] == "V" and full["delay_samples"] == DELAY


@pytest.mark.slow
def test_phase_offsets_from_a_phase_file(truth, guess, tmp_path):
    """Offsets of the phase-a/b sensors rotate with the rotor in dq; a phase file with its angle identifies them."""
    motor = truth.replace(offset_a=0.04, offset_b=-0.06)
    clean = dc.engine_bench(dc.default_plan(), motor, record_speed=True)
    theta_e = np.concatenate([s.theta_e for s in clean.segments])
    path = tmp_path / "phase.csv"
    clean.add_noise(NOISE, 3).to_phase_frame(theta_e).to_csv(path, index=False, float_format="%.17g")
    bench = dc.load_bench(path)
    names = dc.ESTIMATED + ("offset_a", "offset_b")
    cal = dc.fit(bench, guess, names=names, measured_speed=False)
    for name, z in _z(cal, motor).items():
        assert abs(z) < 3.0, (name, z)

    dq_only = clean.with_currents(clean.currents)
    no_angle = dc.BenchData(tuple(s.__class__(s.name, s.locked, s.t, s.voltages, s.currents) for s in dq_only.segments),
                            dq_only.sample_rate)
    with pytest.raises(dc.DrivecalError, match="offset_a.*phase"):
        dc.check_requested(names, no_angle.experiment(), "bench.csv")


def _two_temperature_plan(t_low: float, t_high: float) -> dc.Plan:
    base = dc.default_plan().segments
    segments = [dc.Segment(f"{s.name} #{k} @{t:g}C", s.duration, s.locked, s.v_d, s.v_q, temperature=t)
                for k, t in enumerate((t_low, t_high)) for s in base]
    return dc.Plan(tuple(segments))


@pytest.mark.slow
def test_r0_and_alpha_from_two_temperatures(truth, guess):
    plan = _two_temperature_plan(25.0, 85.0)
    bench = dc.engine_bench(plan, truth).add_noise(NOISE, 4)
    names = dc.ESTIMATED + ("alpha_R",)
    prior = guess.replace(alpha_R=3.0e-3)
    cal = dc.fit(bench, prior, names=names)
    assert cal.fit_names == names
    for name, z in _z(cal, truth).items():
        assert abs(z) < 3.0, (name, z)


def test_design_reports_alpha_ill_conditioned_when_temperatures_are_close(truth):
    names = dc.ESTIMATED + ("alpha_R",)
    close = dc.assess_design(_two_temperature_plan(25.0, 26.0), truth, names=names)
    apart = dc.assess_design(_two_temperature_plan(25.0, 85.0), truth, names=names)
    alpha = names.index("alpha_R")
    assert "alpha_R" in close.identifiability.weak_params and not close.identifiability.identifiable
    assert "temperature spread of 1 K" in close.identifiability.reasons["alpha_R"]
    assert close.identifiability.variance_inflation[alpha] > 100  # correlation with R inflates its variance 100x
    assert close.identifiability.condition_number > 3 * apart.identifiability.condition_number
    assert apart.ok and "alpha_R" not in apart.identifiability.weak_params
    assert apart.identifiability.variance_inflation[alpha] < 10
    # Further from T_ref the extrapolation to R(T_ref) is worse still: the condition number says so too.
    far = dc.assess_design(_two_temperature_plan(60.0, 61.0), truth, names=names)
    assert "alpha_R" in far.identifiability.weak_params and far.identifiability.condition_number > 100

    one = dc.assess_design(_two_temperature_plan(60.0, 60.0), truth, names=names)
    assert "alpha_R" not in one.identifiability.fit_names
    assert "one winding temperature" in one.identifiability.reasons["alpha_R"]


def test_motor_file_bench_effects():
    mf = dc.motor_from_dict({"v_dead": "0.4 V", "offset_d": "-20 mA", "delay_samples": 1, "T_ref": "25 degC",
                             "estimate": ["R", "Ld", "Lq", "lambda_m", "v_dead", "offset_d"]})
    assert float(mf.motor.v_dead) == 0.4 and float(mf.motor.offset_d) == pytest.approx(-0.02)
    assert mf.delay_samples == 1 and float(mf.motor.T_ref) == 25.0
    assert mf.names == dc.ESTIMATED + ("v_dead", "offset_d")
    with pytest.raises(dc.DrivecalError, match="delay_samples"):
        dc.motor_from_dict({"delay_samples": -1}, "m.toml")
    with pytest.raises(dc.DrivecalError, match="v_dead"):
        dc.motor_from_dict({"v_dead": "0.4 A"}, "m.toml")


def test_the_delay_advice_says_which_way(truth, guess, clean_default, default_bench):
    """Two-sided: a fit that assumes too much delay is told 'lower', one that assumes too little 'raise'."""
    delayed = dc.engine_bench(dc.default_plan(), truth, delay_samples=1).add_noise(NOISE, 5)
    cases = [(default_bench, 1, "less", "lower 'delay_samples'"),  # no delay on the bench, one assumed
             (delayed, 0, "more", "raise 'delay_samples'")]  # one sample on the bench, none assumed
    for bench, assumed, word, fix in cases:
        cal = dc.fit(bench, guess, delay_samples=assumed, measured_speed=False)
        doc = dc.build_result(cal, bench, experiment=bench.experiment(measured_speed=False, delay_samples=assumed),
                              noise_sigma=NOISE)
        (delay,) = [e for e in doc["residuals"]["unmodelled_effects"] if e["effect"] == "delay"]
        assert delay["suspected"], delay
        assert f"{word} PWM/computation delay than the {assumed} sample(s) assumed" in delay["message"]
        assert fix in delay["message"]
        assert doc["verdict"]["status"] == "mismatch"
