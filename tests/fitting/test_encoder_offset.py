"""An encoder whose zero is 20 degrees (electrical) off the d axis (issue 20, items 4 and 6).

Truth is the Jaxonomy engine: the drive commands the plan's voltages in its encoder's frame, so the motor
receives them turned by +20 degrees, and the drive's phase file holds the true phase currents and voltages
with the encoder's angle, ``theta_e + 20 deg``. drivecal loads it with a Park transform at that angle, so
every dq column is turned by -20 degrees. The run is the default plan: locked d and q steps and a free
spin-up. Without ``encoder_offset`` the fit is biased far beyond its intervals and the verdict names the
offset; with it estimated the offset, R, Ld, Lq and lambda_m lie within 3 standard errors (fixed seed).
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.model import model_experiment, predicted_currents
from drivecal.report import build_result

from helpers.cli import assert_one_sentence, run_cli

NOISE = 0.02  # A
OFFSET = np.radians(20.0)  # rad, electrical
TRUE = dc.DEFAULT_MOTOR.replace(encoder_offset=OFFSET)
NAMES = dc.ESTIMATED + ("encoder_offset",)


@pytest.fixture(scope="module")
def clean():
    """The default plan on the engine through an encoder 20 degrees off: the drive's frame, no noise."""
    return dc.engine_bench(dc.default_plan(), TRUE, record_speed=True)


@pytest.fixture(scope="module")
def phase_bench(clean):
    """The drive's phase file (noise seed 3), loaded as drivecal loads any phase file."""
    theta_enc = np.concatenate([s.theta_e for s in clean.segments])
    frame = clean.add_noise(NOISE, 3).to_phase_frame(theta_enc)
    return dc.bench_from_frame(frame, "phase.csv", pole_pairs=4.0)


def _z(cal: dc.Calibration, names=NAMES) -> dict[str, float]:
    return {n: (float(cal.estimate[cal.names.index(n)]) - float(getattr(TRUE, n))) / float(cal.se[cal.names.index(n)])
            for n in names if n in cal.names}


def test_the_model_follows_the_engine_through_the_encoder_offset(clean):
    # The angle column is the encoder's: each segment starts at rest at theta_e = 0, read as 20 degrees.
    assert all(abs(s.theta_e[0] - OFFSET) < 1e-12 for s in clean.segments)
    experiment = clean.experiment(measured_speed=False)
    modelled = model_experiment(experiment, TRUE, NAMES)
    assert modelled.encoder_offset
    assert np.max(np.abs(predicted_currents(TRUE, modelled) - clean.currents)) < 1e-8
    # The offset matters: the model without it misses the drive's currents by amperes.
    assert np.max(np.abs(predicted_currents(dc.DEFAULT_MOTOR, experiment) - clean.currents)) > 1.0


def test_the_plain_fit_is_biased_and_the_verdict_names_the_encoder_offset(phase_bench):
    guess = dc.datasheet_guess(dc.DEFAULT_MOTOR)
    cal = dc.fit(phase_bench, guess, measured_speed=False)
    z = _z(cal, dc.ESTIMATED)
    print("plain fit z:", {n: round(v, 2) for n, v in z.items()})
    assert max(abs(v) for v in z.values()) > 3.0, z
    result = build_result(cal, phase_bench, experiment=phase_bench.experiment(measured_speed=False),
                          noise_sigma=NOISE)
    judged = result["verdict"]
    assert judged["status"] != "calibrated"
    assert judged["status"] == "mismatch" and "most likely encoder offset" in judged["headline"], judged
    assert "add encoder_offset to 'estimate'" in judged["details"][0]
    test = next(e for e in result["residuals"]["unmodelled_effects"] if e["effect"] == "encoder_offset")
    assert test["suspected"] and test["one_step"]["encoder_offset"]["estimate"] > np.radians(10.0)


def test_the_offset_estimated_recovers_it_and_the_motor(phase_bench):
    guess = dc.datasheet_guess(dc.DEFAULT_MOTOR)
    cal = dc.fit(phase_bench, guess, names=NAMES, measured_speed=False)
    assert bool(cal.converged) and cal.fit_names == NAMES
    assert 0.9 * NOISE < float(cal.sigma_hat) < 1.1 * NOISE
    z = _z(cal)
    print("with encoder_offset, z:", {n: round(v, 2) for n, v in z.items()},
          f"offset {np.degrees(float(cal.estimate[-1])):.4f} deg, SE {np.degrees(float(cal.se[-1])):.2g} deg")
    for name, value in z.items():
        assert abs(value) < 3.0, (name, value)


def test_the_motor_file_gives_the_offset_in_degrees():
    motor = dc.motor_from_dict({"R": 0.45, "pole_pairs": 4, "encoder_offset": "-20 deg",
                                "estimate": ["R", "encoder_offset"]}, "motor.toml")
    assert motor.motor.encoder_offset == pytest.approx(-OFFSET) and motor.names == ("R", "encoder_offset")
    assert dc.motor_from_dict({"R": 0.45, "encoder_offset": "0.1 rad"}).motor.encoder_offset == 0.1
    with pytest.raises(dc.DrivecalError, match=r"'encoder_offset': '20 V' has unit 'V' but a rotor angle in rad"):
        dc.motor_from_dict({"R": 0.45, "encoder_offset": "20 V"}, "motor.toml")


def test_a_dq_file_is_refused_with_one_sentence(clean, tmp_path, capsys):
    """The drive's dq file: turned into dq with an angle the file does not hold; the offset is not corrected."""
    frame = clean.add_noise(NOISE, 3).to_frame().drop(columns=["theta_e"])
    bench = tmp_path / "dq.csv"
    frame.to_csv(bench, index=False, float_format="%.17g")
    motor = tmp_path / "motor.toml"
    motor.write_text('R = 0.45\nLd = 3.2e-3\nLq = 5.8e-3\nlambda_m = 0.0533\npole_pairs = 4\n'
                     'estimate = ["R", "Ld", "Lq", "lambda_m", "encoder_offset"]\n')
    out = tmp_path / "out"
    code, err = run_cli(["fit", bench, "--motor", motor, "--out", out], capsys)
    assert_one_sentence(code, err, str(bench), "encoder_offset is requested", "it is a dq file",
                        "does not correct an encoder offset")
    assert not out.exists()


def test_the_default_command_calibrates_the_phase_file_with_the_offset_in_estimate(clean, tmp_path, capsys):
    """`drivecal fit FILE --motor M` (no other flag) on the drive's phase file, encoder_offset in 'estimate'."""
    import json

    from drivecal.cli import main

    theta_enc = np.concatenate([s.theta_e for s in clean.segments])
    path = tmp_path / "phase.csv"
    clean.add_noise(NOISE, 3).to_phase_frame(theta_enc).to_csv(path, index=False, float_format="%.17g")
    motor = tmp_path / "motor.toml"
    motor.write_text('R = 0.45\nLd = 3.2e-3\nLq = 5.8e-3\nlambda_m = 0.0533\npole_pairs = 4\n'
                     'estimate = ["R", "Ld", "Lq", "lambda_m", "encoder_offset"]\n')
    main(["fit", str(path), "--motor", str(motor), "--json"])  # a calibrated fit returns (exit 0)
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"]["status"] == "calibrated", doc["verdict"]
    for name in NAMES:
        p = doc["parameters"][name]
        assert abs(p["estimate"] - float(getattr(TRUE, name))) < 3 * p["se"], (name, p)
