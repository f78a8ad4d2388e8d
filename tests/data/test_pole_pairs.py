"""The motor file's pole pairs checked against the bench's own rotation (issue 20, item 5)."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc

from helpers.cli import assert_one_sentence, run_cli


@pytest.fixture(scope="module")
def turning():
    """The default plan on the engine with an encoder: w_m and theta_e recorded, no noise."""
    return dc.engine_bench(dc.default_plan(), dc.DEFAULT_MOTOR, record_speed=True)


def test_a_wrong_pole_pair_count_is_refused_with_the_measured_ratio(turning):
    frame = turning.to_frame()
    assert dc.bench_from_frame(frame, "bench.csv", pole_pairs=4.0).num_samples == turning.num_samples
    for wrong in (3.0, 5.0, 8.0):
        with pytest.raises(dc.DataError, match=r"^bench\.csv: in the free segments the electrical angle theta_e turns "
                                               r"4 times as fast as the rotor \(w_m\), but the motor file says "
                                               rf"pole_pairs = {wrong:g}; set pole_pairs = 4 in the motor file"):
            dc.bench_from_frame(frame, "bench.csv", pole_pairs=wrong)


def test_phase_voltages_show_the_pole_pairs_without_an_electrical_angle(turning):
    """A phase file with the mechanical angle and speed: the voltages' rotation is the electrical angle's.

    Over a spin-up long enough for a dozen electrical revolutions (0.2 s at 12 V); the default plan's
    (one revolution) is too short to judge from the phase voltages alone.
    """
    plan = dc.Plan(dc.default_plan().segments[:2] + (dc.Segment("long spin-up", 0.2, locked=False, v_q=12.0),))
    long_run = dc.engine_bench(plan, dc.DEFAULT_MOTOR, record_speed=True)
    theta_e = np.concatenate([s.theta_e for s in long_run.segments])
    noisy = long_run.add_noise(0.02, 3)
    phases = noisy.to_phase_frame(theta_e).drop(columns=["theta_e"]).assign(theta_m=theta_e / 4.0)
    converted = dc.bench_from_frame(phases, "abc.csv", pole_pairs=4.0)
    np.testing.assert_allclose(converted.currents, noisy.currents, atol=1e-9)
    short = turning.to_phase_frame(np.concatenate([s.theta_e for s in turning.segments]))
    dc.bench_from_frame(short.drop(columns=["theta_e"]).assign(theta_m=short["theta_e"] / 4.0), "abc.csv",
                        pole_pairs=3.0)  # too little rotation to judge: accepted
    with pytest.raises(dc.DataError, match=r"phase voltages turn 4\.?\d* times as fast as the rotor \(theta_m\), but the "
                                           r"motor file says pole_pairs = 2; set pole_pairs = 4"):
        dc.bench_from_frame(phases, "abc.csv", pole_pairs=2.0)
    # Speed in rpm where rad/s is meant: the ratio is off by 60 / (2 pi).
    rpm = phases.drop(columns=["theta_m"]).assign(theta_e=theta_e, w_m=phases["w_m"] * 60 / (2 * np.pi))
    with pytest.raises(dc.DataError, match=r"check that w_m is mechanical and in rad/s"):
        dc.bench_from_frame(rpm, "abc.csv", pole_pairs=4.0)


def test_the_fit_command_refuses_a_wrong_pole_pair_count(turning, tmp_path, capsys):
    bench = turning.add_noise(0.02, 1).save(tmp_path / "bench.csv")
    motor = tmp_path / "motor.toml"
    motor.write_text("R = 0.45\nLd = 3.2e-3\nLq = 5.8e-3\nlambda_m = 0.0533\npole_pairs = 3\n")
    out = tmp_path / "out"
    code, err = run_cli(["fit", bench, "--motor", motor, "--out", out], capsys)
    assert_one_sentence(code, err, str(bench), "pole_pairs = 3; set pole_pairs = 4 in the motor file")
    assert not out.exists()
