"""Plans from the bench's real limits (issue 22): a real inverter's sample rate, the dead-time margin, the clamp
torque and the spin-up's speed, shown per segment and checked; ten real motors planned, run and fitted."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import jax
import numpy as np
import pytest

import drivecal as dc
from drivecal import design
from drivecal.cli import main
from helpers import corpus

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "motors.csv"
needs_corpus = pytest.mark.skipif(not CORPUS.is_file(), reason=f"real-motor corpus {CORPUS} not present")

#: A 400 V servo whose locked steps (2 V at half its 20 A) are under 10 x its 4 V dead-time voltage.
SERVO = dc.MotorParams(R=0.2, Ld=2e-3, Lq=2e-3, lambda_m=0.1, pole_pairs=4, J=3e-4, B=1e-5)
SERVO_LIMITS = dict(v_dc=400.0, current_limit=20.0, max_speed=300.0)


@pytest.fixture(scope="module")
def demo_design() -> dc.DesignReport:
    return dc.auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=30.0)


@pytest.fixture(scope="module")
def servo_design() -> dc.DesignReport:
    return dc.auto_design(SERVO, **SERVO_LIMITS)


def test_the_default_sample_rate_is_a_real_inverters_and_the_plan_keeps_its_shape_at_another(demo_design):
    plan = demo_design.plan
    assert plan.sample_rate == design.DEFAULT_SAMPLE_RATE == 10_000.0
    assert demo_design.limits.sample_rate_source.startswith("default")
    other = dc.auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=30.0, sample_rate=16_000.0)
    assert other.plan.sample_rate == 16_000.0 and other.limits.sample_rate_source == "the bench's"
    # the same segments and ramp; durations from time constants (the sample count's rounding to a power of two
    # stretches all of them alike); the steps as high as the dead time's margin asks at each rate (its voltage
    # grows with the PWM rate: 0.48 V at 10 kHz, 0.77 V at 16 kHz)
    assert [(s.name, s.locked) for s in other.plan.segments] == [(s.name, s.locked) for s in plan.segments]
    for report in (demo_design, other):
        for seg in report.plan.segments[:2]:
            level = max(float(seg.v_d), float(seg.v_q))
            assert level == pytest.approx(max(0.5 * 30.0 * 0.45, 10 * report.limits.v_dead))
    ratios = [b.duration / a.duration for a, b in zip(plan.segments, other.plan.segments)]
    assert max(ratios) / min(ratios) < 1.01
    (key, ramp), = other.waveforms.items()
    assert key == ("free spin-up", "v_q") and ramp["kind"] == "ramp"
    assert ramp["level"] == pytest.approx(demo_design.waveforms[key]["level"], rel=1e-9)
    assert ramp["rise"] == pytest.approx(demo_design.waveforms[key]["rise"], rel=1e-3)
    # a motor whose electrical time constant (0.56 ms) is too short for 10 samples at 10 or 16 kHz gets 20 kHz
    fast = dc.auto_design(dc.DEFAULT_MOTOR.replace(Ld=2.5e-4, Lq=4e-4), v_dc=48.0, current_limit=30.0)
    assert fast.plan.sample_rate == 20_000.0 and "time constant" in fast.limits.sample_rate_source


def test_steps_above_the_dead_time_margin_need_no_v_dead(demo_design):
    limits = demo_design.limits
    assert limits.v_dead == pytest.approx(48.0 * 1e-6 * 10_000.0) and not limits.v_dead_fitted
    assert limits.dead_time_ratio(demo_design.plan) >= design.DEAD_TIME_MARGIN
    assert "v_dead" not in demo_design.identifiability.names
    assert [s.name for s in demo_design.plan.segments] == ["locked d-step", "locked q-step", "free spin-up"]


def test_steps_under_the_dead_time_margin_fit_v_dead_with_a_second_d_step_current(servo_design):
    report, limits = servo_design, servo_design.limits
    assert limits.v_dead == pytest.approx(4.0) and limits.v_dead_fitted
    assert limits.dead_time_ratio(report.plan) < design.DEAD_TIME_MARGIN
    assert report.ok and "v_dead" in report.identifiability.names and "v_dead" in report.identifiability.fit_names
    names = [s.name for s in report.plan.segments]
    assert names == ["locked d-step", "locked d-step, half current", "locked q-step", "free spin-up"]
    assert any("v_dead must be fitted" in n for n in report.notes)
    # the steps add the dead time's drop: on the motor with that dead time they reach their currents
    d_full, d_half = report.segments[:2]
    assert d_half.peak_current == pytest.approx(0.5 * d_full.peak_current, rel=0.02)
    assert d_full.peak_current <= design.CURRENT_MARGIN * SERVO_LIMITS["current_limit"] * (1 + 1e-6)
    assert float(report.motor.v_dead) == pytest.approx(4.0)
    # an inverter that compensates its dead time: no v_dead, the three standard segments
    ideal = dc.auto_design(SERVO, dead_time=0.0, **SERVO_LIMITS)
    assert not ideal.limits.v_dead_fitted and len(ideal.plan.segments) == 3


def test_clamp_torque_is_predicted_per_locked_segment_and_held_under_the_clamps_limit(demo_design):
    kt = 1.5 * 4 * 0.0533  # N*m per A of i_q
    q_step = demo_design.segments[1]
    assert q_step.peak_torque == pytest.approx(kt * 15.0, rel=1e-3) and demo_design.segments[0].peak_torque < 1e-9
    held = dc.auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=30.0, max_torque=2.0)
    assert held.plan.max_torque == 2.0 and held.ok
    for seg, pred in zip(held.plan.segments, held.segments):
        if seg.locked:
            assert pred.peak_torque <= design.TORQUE_MARGIN * 2.0 * (1 + 1e-6)
    assert not design.margin_problems(held, dc.DEFAULT_MOTOR)
    # design judges a plan file's max_torque: the demo plan's q-step breaks a 2 N*m clamp
    over = dc.assess_design(dataclasses.replace(demo_design.plan, max_torque=2.0), dc.DEFAULT_MOTOR)
    assert any("clamp" in p and "max_torque" in p for p in over.problems)


def test_the_spin_up_ramps_to_a_good_share_of_the_speed_limit_within_it(demo_design, servo_design):
    for report in (demo_design, servo_design):
        spin = report.segments[-1]
        w_limit = report.limits.speed_limit
        assert 0.5 * w_limit <= spin.peak_speed <= design.SPEED_FRACTION * w_limit
        spec = report.waveforms[("free spin-up", "v_q")]
        assert spec["kind"] == "ramp" and spec["rise"] > 0
        assert spin.peak_current <= design.CURRENT_MARGIN * report.plan.current_limit
        assert not design.margin_problems(report, report.motor)


def test_a_rotor_too_heavy_for_the_longest_ramp_spins_slower_and_the_plan_says_so(demo_design):
    """100 x the demo rotor's inertia: reaching 60 % of the speed limit at half a locked step's current would
    take ~7 s (70 000 samples); the ramp keeps to MAX_RAMP_SAMPLES, spins slower, and lambda_m stays identified."""
    heavy = dc.auto_design(dc.DEFAULT_MOTOR.replace(J=100 * float(dc.DEFAULT_MOTOR.J)), v_dc=48.0, current_limit=30.0)
    assert heavy.ok and "lambda_m" in heavy.identifiability.fit_names
    spec = heavy.waveforms[("free spin-up", "v_q")]
    assert spec["kind"] == "ramp" and spec["rise"] * heavy.plan.sample_rate <= design.MAX_RAMP_SAMPLES
    assert heavy.plan.num_samples <= 2 * design.MAX_RAMP_SAMPLES
    spin = heavy.segments[-1]
    assert spin.peak_speed < 0.5 * heavy.limits.speed_limit
    assert any(n.startswith("the spin-up ramps to") for n in heavy.notes)
    assert not any(n.startswith("the spin-up ramps to") for n in demo_design.notes)
    assert spin.peak_current <= design.CURRENT_MARGIN * 30.0 and not design.margin_problems(heavy, heavy.motor)


def test_cli_plan_shows_the_limits_per_segment_and_says_when_v_dead_must_be_fitted(tmp_path, capsys):
    motor = tmp_path / "servo.toml"
    motor.write_text('R = "0.2 ohm"\nLd = "2 mH"\nLq = "2 mH"\nlambda_m = "0.1 Wb"\npole_pairs = 4\n'
                     'J = "3e-4 kg*m^2"\nB = "1e-5 N*m*s"\n')
    out = tmp_path / "servo_plan.toml"
    assert main(["plan", "--motor", str(motor), "--vdc", "400", "--imax", "20", "--max-speed", "300",
                 "--max-torque", "5 N*m", "--out", str(out)]) == 0
    text = " ".join(capsys.readouterr().out.split())  # rich wraps long lines at spaces
    for fragment in ("sample rate 10 kHz (default", "v_dead must be fitted", "clamp [N·m]", "speed [rpm]",
                     "[rad/s]", "ramp to", "limit", "clamp torque 5 N·m"):
        assert fragment in text, fragment
    plan = dc.load_plan(out)
    assert plan.max_torque == 5.0 and plan.sample_rate == 10_000.0
    assert main(["plan", "--motor", str(motor), "--vdc", "400", "--imax", "20", "--max-speed", "300",
                 "--dead-time", "0", "--json", "--out", str(tmp_path / "ideal.toml")]) == 0
    doc = json.loads(capsys.readouterr().out)
    limits = doc["assessment"]["limits"]
    assert limits["v_dead"] == 0 and not limits["v_dead_fitted"] and limits["sample_rate"] == 10_000.0
    assert doc["segments"][-1]["v_q"]["kind"] == "ramp"  # the ramp as its table, not 4000 numbers
    assert all("peak_torque" in s for s in doc["assessment"]["segments"])


def test_a_clamp_too_weak_for_the_dead_times_uncertainty_is_refused_in_one_sentence():
    """The q-step adds the expected dead-time drop; a dead-time voltage 10 % off would move its current by 2.3 A,
    more than a 2 N*m clamp's margin leaves (2.7 A)."""
    with pytest.raises(dc.DrivecalError) as info:
        dc.auto_design(SERVO, max_torque=2.0, **SERVO_LIMITS)
    message = str(info.value)
    assert "clamp" in message and "--max-torque" in message and message.count(". ") == 0


@pytest.mark.parametrize("args, fragment", [
    (["--max-torque", "-3"], "--max-torque"),
    (["--max-torque", "3 V"], "--max-torque"),
    (["--dead-time", "-1"], "--dead-time"),
])
def test_cli_plan_bad_limits_exit_2_with_one_line(args, fragment, tmp_path, capsys):
    out = tmp_path / "p.toml"
    with pytest.raises(SystemExit) as info:
        main(["plan", "--vdc", "48", "--imax", "30", *args, "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err and not out.exists()


# --- ten real motors ------------------------------------------------------------------------------

TEN = corpus.TEN
#: The rotor clamp holds the motor's rated torque (the q-step's 0.75 of the rated current is then held under
#: 80 % of it, less where the dead time's uncertainty needs room).
CLAMP_SHARE = 1.0


def _clamp_limit(entry: corpus.CorpusMotor) -> float:
    m = entry.motor
    return CLAMP_SHARE * 1.5 * float(m.pole_pairs) * float(m.lambda_m) * entry.i_rated


@pytest.fixture(scope="module")
def ten_plans() -> dict:
    """Per motor: (the corpus entry, the datasheet motor, its auto-plan report) with the motor's real limits."""
    motors = {m.name: m for m in corpus.load_corpus(CORPUS)}
    out = {}
    for name in TEN:
        entry = motors[name]
        prior = corpus.datasheet(entry.motor, np.random.default_rng(int(name[1:])))
        report = dc.auto_design(prior, v_dc=entry.v_dc, current_limit=entry.current_limit, max_speed=entry.w_rated,
                                noise_sigma=entry.noise_sigma, max_torque=_clamp_limit(entry))
        out[name] = (entry, prior, report)
    return out


@needs_corpus
@pytest.mark.slow
@pytest.mark.long
def test_ten_corpus_motors_get_plans_an_engineer_would_accept(ten_plans):
    """Sample rate of a real inverter, steps over the dead-time margin or v_dead fitted, clamp torque, speed and
    current within their limits and margins, the spin-up at 50 to 80 % of the speed limit."""
    for name, (entry, prior, report) in ten_plans.items():
        plan, limits = report.plan, report.limits
        assert report.ok, name
        assert 8_000.0 <= plan.sample_rate <= 40_000.0, name
        ratio = limits.dead_time_ratio(plan)
        assert ratio >= design.DEAD_TIME_MARGIN or (limits.v_dead_fitted and "v_dead" in report.identifiability.fit_names
                                                    and any("v_dead must be fitted" in n for n in report.notes)), name
        assert not design.margin_problems(report, report.motor), (name, design.margin_problems(report, report.motor))
        torque = max(p.peak_torque for s, p in zip(plan.segments, report.segments) if s.locked)
        print(f"{name}: {plan.sample_rate / 1e3:g} kHz, {plan.num_samples} samples, dead-time voltage "
              f"{limits.v_dead:.3g} V, smallest locked step {ratio:.3g} x it"
              f"{' (v_dead fitted)' if limits.v_dead_fitted else ''}, clamp torque {torque:.3g} of "
              f"{_clamp_limit(entry):.3g} N*m")
        w_limit = min(entry.w_rated, plan.voltage_limit / (float(prior.pole_pairs) * float(prior.lambda_m)))
        assert limits.speed_limit == pytest.approx(w_limit)
        for seg, pred in zip(plan.segments, report.segments):
            assert pred.peak_current <= design.CURRENT_MARGIN * entry.current_limit * (1 + 1e-6), (name, seg.name)
            if seg.locked:
                assert pred.peak_torque <= design.TORQUE_MARGIN * _clamp_limit(entry) * (1 + 1e-6), (name, seg.name)
            else:
                assert 0.5 * w_limit <= pred.peak_speed <= design.SPEED_FRACTION * w_limit, (name, pred.peak_speed)


@needs_corpus
@pytest.mark.slow
@pytest.mark.long
def test_ten_corpus_motors_simulate_and_fit_within_4_se(ten_plans):
    """Each plan run on the Jaxonomy engine with the true motor (its dead time 10 % off the expected one where
    the plan fits v_dead), noise at the plan's current_noise, fitted from the datasheet: every parameter within
    4 SE, and the true motor's currents, speed and clamp torque within the bench's limits."""
    failed = []
    for name, (entry, prior, report) in ten_plans.items():
        jax.clear_caches()  # each motor's plan compiles its own programs: drop the last motor's (11.7 GB kept else)
        plan, limits = report.plan, report.limits
        rng = np.random.default_rng((22, int(name[1:])))
        truth, start = entry.motor, prior
        if limits.v_dead_fitted:
            truth = truth.replace(v_dead=limits.v_dead * rng.uniform(0.9, 1.1), i_dead=limits.i_dead)
            start = prior.replace(v_dead=limits.v_dead, i_dead=limits.i_dead)
        clean = dc.engine_bench(plan, truth, record_speed=True)
        kt, kr = 1.5 * float(truth.pole_pairs) * float(truth.lambda_m), 1.5 * float(truth.pole_pairs) * (
            float(truth.Ld) - float(truth.Lq))
        for seg in clean.segments:
            i_d, i_q = seg.currents[:, 0], seg.currents[:, 1]
            assert np.max(np.hypot(i_d, i_q)) <= entry.current_limit, (name, seg.name)
            if seg.locked:
                assert np.max(np.abs(kt * i_q + kr * i_d * i_q)) <= _clamp_limit(entry), (name, seg.name)
            else:
                assert np.max(np.abs(seg.w_m)) <= entry.w_rated, (name, seg.name)
        bench = clean.add_noise(plan.current_noise, int(name[1:]))
        cal = dc.fit(bench, start, names=report.identifiability.names)
        z = (np.asarray(cal.estimate) - np.asarray([float(getattr(truth, n)) for n in cal.names])) / np.asarray(cal.se)
        print(f"{name}: converged {bool(cal.converged)}, largest |z| {np.max(np.abs(z)):.2f} "
              f"({cal.names[int(np.argmax(np.abs(z)))]})")
        if not (bool(cal.converged) and np.all(np.abs(z) <= corpus.PASS_SE)):
            failed.append((name, dict(zip(cal.names, np.round(z, 2)))))
    assert not failed, failed
