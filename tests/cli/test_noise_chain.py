"""One noise level through plan -> design -> simulate -> fit (issue 22 item 2).

`plan --noise` records the noise in the plan file (current_noise); `design` and `simulate` use it unless
`--noise` overrides it, and say which; `fit` with no stated noise checks sigma_hat against the noise
estimated from the samples (or says that the check is off, and why) instead of skipping it silently.

Tolerances:
* a sample SD of n white samples scatters by 1/sqrt(2n) of itself: 5 of those;
* the robust second-difference level of one series of n samples by ~1.42/sqrt(n) of itself (measured
  over 20 000 series; ``diagnose.NOISE_MIN_SAMPLES``): the estimate is a median over segments and axes,
  so 4 SDs of the shortest series' bound it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from drivecal.cli import main
from drivecal.data import load_bench
from drivecal.plan import load_plan

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
MOTOR = EXAMPLES / "motor.toml"
NOISE = 0.06  # A, what the plan is designed for: three times design's and simulate's old fixed 20 mA
ESTIMATE_SD = 1.42  # relative SD of the robust level of one series of n samples, times sqrt(n)


def _json(args, capsys, code=0) -> dict:
    assert main([str(a) for a in args] + ["--json"]) == code
    return json.loads(capsys.readouterr().out)


def _estimate_tolerance(bench) -> float:
    return 4.0 * ESTIMATE_SD / math.sqrt(min(s.num_samples for s in bench.segments))


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    """The plan for the demo motor at 60 mA, its bench at the plan's noise, and the same bench noise-free."""
    d = tmp_path_factory.mktemp("noise_chain")
    plan = d / "plan.toml"
    assert main(["plan", "--motor", str(MOTOR), "--vdc", "48", "--imax", "30", "--noise", str(NOISE),
                 "--out", str(plan)]) == 0
    assert main(["simulate", str(plan), "--motor", str(MOTOR), "--seed", "5", "--out", str(d / "bench.csv")]) == 0
    assert main(["simulate", str(plan), "--motor", str(MOTOR), "--noise", "1e-12", "--out", str(d / "clean.csv")]) == 0
    return plan, d / "bench.csv", d / "clean.csv"


def test_plan_records_the_noise_it_was_designed_for(chain):
    plan, _, _ = chain
    assert load_plan(plan).current_noise == NOISE
    assert f"current_noise = {NOISE!r}" in plan.read_text()


def test_design_uses_the_plans_noise_unless_told(chain, capsys):
    plan, _, _ = chain
    own = _json(["design", plan, "--motor", MOTOR], capsys)
    assert own["noise_sigma"] == NOISE and own["noise_source"] == "the plan's current_noise"
    told = _json(["design", plan, "--motor", MOTOR, "--noise", "0.02"], capsys)
    assert told["noise_sigma"] == 0.02 and told["noise_source"] == "from --noise"
    # The predicted intervals scale with the noise: three times wider at the plan's 60 mA than at 20 mA.
    for name, half in own["identifiability"]["predicted_ci95"].items():
        assert half == pytest.approx(3.0 * told["identifiability"]["predicted_ci95"][name], rel=1e-9)
    assert main(["design", str(plan), "--motor", str(MOTOR)]) == 0
    assert "sensor noise 60 mA (the plan's current_noise)" in capsys.readouterr().out
    # A plan that records none: the default, said as such.
    assert _json(["design", EXAMPLES / "default_plan.toml"], capsys)["noise_source"] == \
        "default; no current_noise in the plan"


def test_simulate_adds_the_plans_noise_unless_told(chain, capsys, tmp_path):
    plan, bench_path, clean_path = chain
    clean = load_bench(clean_path).currents
    added = load_bench(bench_path).currents - clean
    assert np.std(added) == pytest.approx(NOISE, rel=5.0 / math.sqrt(2 * added.size))
    assert main(["simulate", str(plan), "--motor", str(MOTOR), "--noise", "0.02", "--out", str(tmp_path / "t.csv")]) == 0
    assert "noise 20 mA (from --noise; seed 1)" in capsys.readouterr().out
    told = load_bench(tmp_path / "t.csv").currents - clean
    assert np.std(told) == pytest.approx(0.02, rel=5.0 / math.sqrt(2 * told.size))
    assert main(["simulate", str(plan), "--motor", str(MOTOR), "--out", str(tmp_path / "p.csv")]) == 0
    assert "noise 60 mA (the plan's current_noise; seed 1)" in capsys.readouterr().out


def test_fit_without_noise_on_a_correct_bench_checks_the_estimate_and_stays_calibrated(chain, capsys):
    plan, bench_path, _ = chain
    bench = load_bench(bench_path)
    free = _json(["fit", bench_path, "--motor", MOTOR], capsys)
    stated = _json(["fit", bench_path, "--motor", MOTOR, "--noise", str(NOISE)], capsys)
    assert free["verdict"]["status"] == stated["verdict"]["status"] == "calibrated"
    # The noise judges the fit, it does not enter it: the same estimates and intervals.
    for name, p in stated["parameters"].items():
        assert free["parameters"][name]["estimate"] == p["estimate"] and free["parameters"][name]["ci95"] == p["ci95"]
    res = free["residuals"]
    assert res["sigma_estimated"] and res["noise_check_off"] is None and res["noise_consistent"]
    assert res["sigma_stated"] == pytest.approx(NOISE, rel=_estimate_tolerance(bench))
    assert "second-difference" in res["sigma_source"]
    assert any(d.startswith("noise check against the sensor noise estimated from the samples")
               for d in free["verdict"]["details"])
    assert not stated["residuals"]["sigma_estimated"] and stated["residuals"]["sigma_source"] == "--noise"
    # Predicted (design, at the plan's noise) and realised (fit) intervals agree where the fit models the
    # speed as the design does (from J and B, not the measured w_m as an input): sigma_hat scatters by
    # 1/sqrt(2M) around the noise, the Jacobian at the estimate is that at the nominal motor to ~0.1 %.
    design = _json(["design", plan, "--motor", MOTOR], capsys)["identifiability"]["predicted_ci95"]
    like_design = _json(["fit", bench_path, "--motor", MOTOR, "--speed", "ignore"], capsys)
    assert like_design["verdict"]["status"] == "calibrated" and like_design["residuals"]["sigma_estimated"]
    m = 2 * bench.num_samples
    for name, half in design.items():
        low, high = like_design["parameters"][name]["ci95"]
        assert 0.5 * (high - low) == pytest.approx(half, rel=5.0 / math.sqrt(m) + 0.01), name


def test_fit_without_noise_says_mismatch_when_sigma_hat_is_far_above_the_noise_in_the_samples(chain, capsys,
                                                                                                  tmp_path):
    """Sensor glitches the model does not have (2 % of the samples off by +-20 sigma): the residuals stay
    white and carry no bench effect's signature, so without a noise check the fit said "calibrated"; sigma_hat
    is ~3 sigma while the robust estimate sees the sensor's sigma."""
    _, bench_path, clean_path = chain
    clean = load_bench(clean_path)
    rng = np.random.default_rng(11)
    glitch = (rng.random(clean.currents.shape) < 0.02) * rng.choice([-20.0, 20.0], clean.currents.shape) * NOISE
    path = clean.with_currents(clean.currents + rng.normal(0.0, NOISE, clean.currents.shape) + glitch).save(
        tmp_path / "glitches.csv")
    doc = _json(["fit", path, "--motor", MOTOR], capsys, code=4)
    res = doc["residuals"]
    assert doc["verdict"]["status"] == "mismatch" and doc["verdict"]["headline"] == "model mismatch suspected"
    assert res["white"] and not any(e["suspected"] for e in res["unmodelled_effects"])  # only the noise check
    assert res["sigma_estimated"] and not res["noise_consistent"]
    assert res["sigma_stated"] == pytest.approx(NOISE, rel=_estimate_tolerance(clean) + 0.1)  # + the glitches' share
    assert any("times the sensor noise estimated from the samples" in d and "no noise was stated" in d
               for d in doc["verdict"]["details"])


def test_fit_without_noise_on_a_wrong_model_checks_against_the_estimate(capsys):
    """The inverter bench (dead time, offsets, a delay; 20 mA) with its effects left out: sigma_hat 137 mA."""
    bench = load_bench(EXAMPLES / "inverter_bench.csv")
    doc = _json(["fit", EXAMPLES / "inverter_bench.csv", "--motor", MOTOR, "--effects", "none"], capsys, code=4)
    res = doc["residuals"]
    assert res["sigma_estimated"] and not res["noise_consistent"]
    assert res["sigma_stated"] == pytest.approx(0.02, rel=_estimate_tolerance(bench))
    assert res["sigma_ratio"] > 1.5 * 3  # far beyond the limit, not at its edge


def test_fit_says_the_noise_check_is_off_and_why(chain, capsys, tmp_path):
    """Currents read through a coarse converter (100 mA steps, no noise to speak of): most second differences
    are exactly zero, so there is no noise to estimate; the verdict says the check is off, and why."""
    _, _, clean_path = chain
    clean = load_bench(clean_path)
    path = clean.with_currents(np.round(clean.currents / 0.1) * 0.1).save(tmp_path / "quantised.csv")
    main(["fit", str(path), "--motor", str(MOTOR), "--effects", "none", "--json"])  # the status is not judged here
    doc = json.loads(capsys.readouterr().out)
    res = doc["residuals"]
    assert res["sigma_stated"] is None and res["sigma_source"] is None and not res["sigma_estimated"]
    assert res["noise_check_off"].startswith("the currents show no measurable noise")
    assert any(d.startswith("noise check off: the currents show no measurable noise")
               for d in doc["verdict"]["details"])
