"""Auto-plan: feasible, identifiable plans scaled to the motor; the CLI; the real-motor corpus end to end."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal import design as autoplan
from helpers import corpus
from drivecal.cli import main

CORPUS = Path(__file__).resolve().parents[2] / ".." / "shared" / "data" / "motors.csv"
needs_corpus = pytest.mark.skipif(not CORPUS.is_file(), reason=f"real-motor corpus {CORPUS} not present")


@pytest.fixture(scope="module")
def default_design() -> dc.DesignReport:
    return dc.auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=30.0)


def test_default_motor_plan_is_feasible_identifiable_and_within_limits(default_design):
    report, plan = default_design, default_design.plan
    assert report.ok and report.identifiability.rank == 4
    assert [s.name for s in plan.segments] == ["locked d-step", "locked q-step", "free spin-up"]
    assert [s.locked for s in plan.segments] == [True, True, False]
    # independent re-check with the public assessment
    assert dc.assess_design(plan, dc.DEFAULT_MOTOR).ok
    motor = dc.DEFAULT_MOTOR
    # locked steps: steady current = STEP_CURRENT_FRACTION of the limit (v = i R), reached
    for seg, pred in zip(plan.segments[:2], report.segments[:2]):
        v = float(seg.v_d) + float(seg.v_q)
        assert v == pytest.approx(autoplan.STEP_CURRENT_FRACTION * 30.0 * float(motor.R))
        assert pred.peak_current == pytest.approx(v / float(motor.R), rel=1e-3)
    # every segment at least LOCKED_TIME_CONSTANTS electrical time constants long
    assert plan.segments[0].duration >= autoplan.LOCKED_TIME_CONSTANTS * float(motor.Ld / motor.R)
    assert plan.segments[1].duration >= autoplan.LOCKED_TIME_CONSTANTS * float(motor.Lq / motor.R)
    # sample rate: >= SAMPLES_PER_TIME_CONSTANT samples in the fastest time constant
    assert plan.sample_rate * float(min(motor.Ld, motor.Lq) / motor.R) >= autoplan.SAMPLES_PER_TIME_CONSTANT
    spin = report.segments[2]
    assert spin.peak_electrical_step <= autoplan.PLAN_MAX_ELECTRICAL_STEP
    assert all(p.peak_current <= autoplan.CURRENT_MARGIN * 30.0 for p in report.segments)
    no_load = plan.voltage_limit / (float(motor.pole_pairs) * float(motor.lambda_m))
    assert 0 < spin.peak_speed <= autoplan.SPEED_FRACTION * no_load
    assert plan.num_samples & (plan.num_samples - 1) == 0  # a power of two: fits share compiled code


def test_plan_scales_with_the_motor(default_design):
    base = default_design.plan
    # 3x the resistance: 3x the step voltage for the same current, a third of the time constants
    stiff = dc.auto_plan(dc.DEFAULT_MOTOR.replace(R=3 * 0.45), v_dc=48.0, current_limit=30.0)
    assert float(stiff.segments[0].v_d) == pytest.approx(3 * float(base.segments[0].v_d))
    # the sample rate is the inverter's (10 kHz by default), not the motor's: the steps get shorter instead
    assert stiff.sample_rate == base.sample_rate == autoplan.DEFAULT_SAMPLE_RATE
    assert stiff.segments[0].duration < 0.7 * base.segments[0].duration
    # 10x the inductances: ten times slower electrically, locked steps at least 10x as long
    slow = dc.auto_plan(dc.DEFAULT_MOTOR.replace(Ld=3.2e-2, Lq=5.8e-2), v_dc=48.0, current_limit=30.0)
    assert slow.segments[1].duration >= autoplan.LOCKED_TIME_CONSTANTS * 5.8e-2 / 0.45
    assert slow.segments[1].duration > 5 * base.segments[1].duration
    # a current limit near the steps' reach of the voltage circle: step voltage capped inside the circle
    capped = dc.auto_plan(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=1000.0)
    assert float(capped.segments[0].v_d) == pytest.approx(autoplan.VOLTAGE_FRACTION * 48.0 / math.sqrt(3.0))


def test_budget_and_max_speed_are_respected(default_design):
    full = sum(s.duration for s in default_design.plan.segments)
    report = dc.auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=30.0, budget=0.5 * full, max_speed=20.0)
    plan = report.plan
    assert report.ok
    assert sum(s.duration for s in plan.segments) <= 0.5 * full + 1e-12
    assert plan.max_speed == 20.0
    assert 0 < report.segments[2].peak_speed <= autoplan.SPEED_FRACTION * 20.0 * 1.05


@pytest.mark.parametrize("kwargs, fragment", [
    ({"budget": 1e-3}, "budget 0.001 s is too short"),
    ({"sample_rate": 100.0}, "sample_rate 100 Hz"),
    ({"current_limit": -1.0}, "current_limit must be a positive number"),
    ({"v_dc": float("nan")}, "v_dc must be a positive number"),
])
def test_impossible_requests_raise_one_clear_sentence(kwargs, fragment):
    args = {"v_dc": 48.0, "current_limit": 30.0, **kwargs}
    with pytest.raises(dc.DrivecalError) as info:
        dc.auto_plan(dc.DEFAULT_MOTOR, **args)
    message = str(info.value)
    assert fragment in message and message.count(". ") == 0 and message.endswith(".")


def test_step_engine_bench_equals_engine_bench():
    """The shared-kernel engine run (time in sample periods) reproduces drivecal.engine_bench, ramps included."""
    motor = dc.DEFAULT_MOTOR.replace(Ld=2.5e-5, Lq=4e-5, R=0.05, T_load=0.01)  # fast: a high sample rate
    plan = dc.auto_plan(motor, v_dc=48.0, current_limit=60.0)
    assert plan.sample_rate >= 10_000
    fast = dc.step_engine_bench(plan, motor, record_speed=True)
    ref = dc.engine_bench(plan, motor, record_speed=True)
    scale = np.abs(ref.currents).max()
    assert np.abs(fast.currents - ref.currents).max() <= 1e-8 * scale  # the engine's tolerance, 1e-12 per step
    for a, b in zip(fast.segments, ref.segments):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_allclose(a.w_m, b.w_m, rtol=0, atol=1e-8 * max(1.0, np.abs(b.w_m).max()))
    assert plan.segments[-1].v_q.ndim == 1  # the spin-up's ramp runs on the shared kernel too
    waveform = dc.Plan((dc.Segment("chirp", 0.01, True, v_d=np.sin(np.linspace(0, 9, 200))),), sample_rate=20_000)
    with pytest.raises(dc.PlanError, match="constant voltages or a ramp"):
        dc.step_engine_bench(waveform, motor)
    with pytest.raises(dc.PlanError, match="no dead time"):
        dc.step_engine_bench(plan, motor.replace(v_dead=0.5))


# --- command line ------------------------------------------------------------------------------


def test_plan_help(capsys):
    assert main(["plan", "--help"]) == 0
    out = capsys.readouterr().out
    assert "Usage: drivecal plan" in out and "--imax" in out and "--budget" in out and "[rad/s]" in out


def test_plan_writes_a_plan_that_design_accepts(tmp_path, capsys):
    out = tmp_path / "auto.toml"
    assert main(["plan", "--vdc", "48", "--imax", "30", "--max-speed", "100", "--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["assessment"]["feasible"] and doc["assessment"]["identifiable"]
    assert doc["assessment"]["noise_sigma"] == pytest.approx(autoplan.NOISE_FRACTION * 30)
    assert all(v["ci95_half_width"] > 0 for v in doc["assessment"]["predicted"].values())
    plan = dc.load_plan(out)
    assert plan.max_speed == 100.0 and plan.num_samples == doc["num_samples"]
    assert main(["design", str(out)]) == 0
    assert "identifiable" in capsys.readouterr().out
    # the table form
    assert main(["plan", "--vdc", "48", "--imax", "30", "--out", str(tmp_path / "b.toml")]) == 0
    text = capsys.readouterr().out
    assert "free spin-up" in text and "predicted 95 % intervals" in text


@pytest.mark.parametrize("args, fragment", [
    (["--vdc", "48", "--imax", "-1"], "--imax"),
    (["--vdc", "48"], "--imax"),
    (["--vdc", "48", "--imax", "30", "--budget", "1e-5"], "budget"),
    (["--vdc", "48", "--imax", "30", "--motor", "missing.toml"], "missing.toml"),
])
def test_plan_bad_input_exits_2_with_one_line(args, fragment, tmp_path, capsys):
    out = tmp_path / "p.toml"
    with pytest.raises(SystemExit) as info:
        main(["plan", *args, "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("drivecal: error:") and fragment in err
    assert not out.exists()  # nothing half-written


def test_plan_out_in_a_missing_directory_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        main(["plan", "--vdc", "48", "--imax", "30", "--out", str(tmp_path / "nowhere" / "p.toml")])
    assert info.value.code == 2 and "--out" in capsys.readouterr().err


# --- the real-motor corpus ------------------------------------------------------------------------


@needs_corpus
def test_corpus_sample_holds_the_extremes():
    motors = corpus.load_corpus(CORPUS)
    sample = corpus.corpus_sample(motors, 50)
    names = {m.name for m in sample}
    assert len(sample) == len(names) >= 50
    for key in (lambda m: m.motor.R, lambda m: m.motor.Ld, lambda m: m.motor.lambda_m, lambda m: m.v_dc,
                lambda m: min(m.motor.Ld, m.motor.Lq) / m.motor.R):
        values = [float(key(m)) for m in motors]
        assert motors[int(np.argmin(values))].name in names and motors[int(np.argmax(values))].name in names


@needs_corpus
@pytest.mark.slow
@pytest.mark.long
def test_corpus_sample_end_to_end_within_4_se():
    """The corpus's extremes (smallest and largest R, Ld, Lq, lambda_m, pole pairs, V_dc, rated current and speed,
    time constants and saliency: 18 motors, less the ten that test_bench_limits.py runs end to end under their real
    limits): auto-plan -> Jaxonomy engine -> fit; every estimate within 4 SE of the truth.

    4 SE: at ~50 estimates a 3 SE rule would fail by chance with probability 0.13; 4 SE fails with 0.003.
    The share within 1.96 SE must also look like 95 %: the count outside may exceed its binomial
    (n estimates, p = 0.05) 99.5 % quantile only with probability 0.005.
    Not more motors: at a real inverter's sample rate every motor's plan has its own segment layout, hence its
    own compiled fit (~20-35 s each on 2 cores); benchmarks/validate_corpus.py runs the whole corpus.
    """
    sample = [m for m in corpus.corpus_sample(corpus.load_corpus(CORPUS), 0) if m.name not in corpus.TEN]
    assert len(sample) >= 10
    results = corpus.validate(sample, seed=0)
    failed = [r.name + (f" ({r.error})" if r.error else f" z={np.round(r.z, 2)}") for r in results if not r.passed]
    assert not failed, failed
    z = np.concatenate([np.ravel(r.z) for r in results])
    outside, n = int(np.sum(np.abs(z) > 1.96)), z.size
    # The smallest k with P(Binomial(n, 0.05) >= k) <= 0.005: more outside than that is no chance.
    tail = [sum(math.comb(n, j) * 0.05**j * 0.95 ** (n - j) for j in range(k, n + 1)) for k in range(n + 1)]
    allowed = next(k for k in range(n + 1) if tail[k] <= 0.005) - 1
    assert outside <= allowed, (outside, n, allowed)
