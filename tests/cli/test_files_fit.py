"""From files to calibrations: round trips, phase data, measured speed, the seed's chirp exercise."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal.plan import waveforms as wf
from drivecal.cli import main

from conftest import NOISE, true_vector
from helpers.cli import assert_page_embeds_files

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="session")
def example_benches(truth, clean_default):
    """Noise-free engine runs of the example plans (the chirp and PRBS ones record w_m)."""
    out = {"default": clean_default}
    for name in ("chirp", "prbs"):
        out[name] = dc.engine_bench(dc.load_plan(EXAMPLES / f"{name}_plan.toml"), truth, record_speed=True)
    return out


def within_se(cal: dc.Calibration, truth: dc.MotorParams) -> np.ndarray:
    return np.abs(cal.estimate - true_vector(truth)) / cal.se


@pytest.mark.slow
@pytest.mark.parametrize("plan", ["default", "chirp", "prbs"])
def test_round_trip_through_each_format(plan, example_benches, truth, guess, tmp_path):
    bench = example_benches[plan].add_noise(NOISE, 11)
    for suffix in (".csv", ".parquet", ".mat"):
        loaded = dc.load_bench(bench.save(tmp_path / f"bench{suffix}"), nominal_R=float(guess.R))
        cal = dc.fit(loaded, guess)
        assert cal.converged and all(cal.identifiable)
        assert np.all(within_se(cal, truth) < 3.0), (plan, suffix, within_se(cal, truth))


def test_cli_simulate_then_fit(truth, tmp_path, capsys):
    bench = tmp_path / "bench.parquet"
    assert main(["simulate", str(EXAMPLES / "default_plan.toml"), "--motor", str(EXAMPLES / "motor.toml"),
                 "--seed", "4", "--out", str(bench)]) == 0
    capsys.readouterr()
    assert main(["fit", str(bench), "--json", "--out", str(tmp_path / "out")]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["converged"] and result["measured_speed"]
    for name in dc.ESTIMATED:
        p = result["parameters"][name]
        assert abs(p["estimate"] - float(getattr(truth, name))) < 3 * p["se"]
    saved = json.loads((tmp_path / "out" / "report.json").read_text())
    assert saved["parameters"] == result["parameters"]
    # Every PNG file is also a figure of the page: one drawing, the same bytes.
    assert_page_embeds_files(tmp_path / "out", ["convergence.png", "estimates.png", "identifiability.png"])


def test_phase_file_gives_the_same_calibration(example_benches, guess, tmp_path):
    bench = example_benches["chirp"].add_noise(NOISE, 12)
    # The rotor angle: a locked rotor parked at 0.3 rad, then the free rotor's integrated speed.
    theta_m = []
    for seg in bench.segments:
        if seg.locked:
            theta_m.append(np.full(seg.num_samples, 0.3))
        else:
            steps = 0.5 * (seg.w_m[1:] + seg.w_m[:-1]) / bench.sample_rate
            theta_m.append(0.3 + np.concatenate([[0.0], np.cumsum(steps)]))
    frame = bench.to_phase_frame(4.0 * np.concatenate(theta_m))
    frame = frame.drop(columns=["theta_e"]).assign(theta_m=np.concatenate(theta_m))
    path = tmp_path / "phases.csv"
    frame.to_csv(path, index=False, float_format="%.17g")
    from_phases = dc.fit(dc.load_bench(path, pole_pairs=4.0), guess)
    from_dq = dc.fit(bench, guess)
    np.testing.assert_allclose(from_phases.estimate, from_dq.estimate, rtol=1e-8)
    np.testing.assert_allclose(from_phases.se, from_dq.se, rtol=1e-6)


@pytest.fixture(scope="session")
def spinning_bench(truth):
    """Default plan with the measured speed, sigma 20 mA."""
    return dc.engine_bench(dc.default_plan(), truth, record_speed=True).add_noise(NOISE, 3)


def test_measured_speed_makes_wrong_inertia_and_friction_harmless(spinning_bench, truth, guess):
    wrong = guess.replace(J=truth.J * 1.3, B=truth.B * 0.7)
    measured = dc.fit(spinning_bench, wrong, measured_speed=True)
    assert measured.converged and np.all(within_se(measured, truth) < 3.0), within_se(measured, truth)
    simulated = dc.fit(spinning_bench, wrong, measured_speed=False)
    # Without the speed, a 30 % wrong J is absorbed into the electrical parameters: far outside the intervals.
    assert np.max(within_se(simulated, truth)) > 10.0, within_se(simulated, truth)
    lam = dc.ESTIMATED.index("lambda_m")
    assert within_se(simulated, truth)[lam] > 3.0


def test_segment_cut_mid_transient_starts_from_its_first_sample(clean_default, truth, guess):
    """A recording that starts 1.5 ms into the d-step: the first sample is the initial state."""
    first = clean_default.segments[0]
    cut = dataclasses.replace(first, t=first.t[30:] - first.t[30], voltages=first.voltages[30:],
                              currents=first.currents[30:])
    frame = dataclasses.replace(clean_default, segments=(cut,) + clean_default.segments[1:]).to_frame()
    bench = dc.bench_from_frame(frame, "cut.csv")
    assert not bench.segments[0].at_rest
    cal = dc.fit(bench, guess)
    np.testing.assert_allclose(cal.estimate, true_vector(truth), rtol=1e-6)
    assumed_rest = dataclasses.replace(bench, segments=(dataclasses.replace(bench.segments[0], at_rest=True),)
                                       + bench.segments[1:])
    wrong = dc.fit(assumed_rest, guess)
    assert np.max(np.abs(wrong.estimate / true_vector(truth) - 1.0)) > 0.01


def test_chirp_identifies_r_and_ld_better_than_a_step_of_equal_energy(truth):
    """The seed's exercise: a locked d-axis chirp vs the 8 V d-step, same injected energy (sum v^2 dt)."""
    fs, n = 20_000.0, 200
    step = np.full(n, 8.0)
    chirp = wf.chirp(n, fs, amplitude=1.0, f_start=20.0, f_stop=2_000.0, sweep="log")
    chirp *= np.sqrt(np.sum(step**2) / np.sum(chirp**2))

    def assess(v_d):
        plan = dc.Plan((dc.Segment("locked d", n / fs, True, v_d=v_d, v_q=0.0),), sample_rate=fs)
        return dc.assess_identifiability(dc.Experiment.from_plan(plan), truth, names=("R", "Ld"))

    by_step, by_chirp = assess(step), assess(chirp)
    assert by_step.identifiable and by_chirp.identifiable
    assert by_chirp.condition_number < 0.6 * by_step.condition_number  # 1.9 vs 4.5
    assert np.all(np.array(by_chirp.predicted_ci95) < np.array(by_step.predicted_ci95))
