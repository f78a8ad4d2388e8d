"""Issue 18: motor files that hold a saturating magnetic law (drivecal's per-unit keys or Hinkkanen's SI table).

The law a file states is the one the plan predicts with, the synthetic bench simulates and the fit starts
from; a motor without a magnet (``lambda_m = 0``) holds it at zero. Bad laws are one sentence naming the key.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import drivecal as dc
from drivecal.cli import main
from drivecal.physics import MAGNETIC, from_hinkkanen, from_lelli
from helpers.blocks import LELLI_PM_SYRM, LELLI_PM_SYRM_MACHINE

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
#: Hinkkanen et al. 2017's 6.7-kW SyRM (doi 10.1109/TIA.2016.2644624), as in examples/syrm_motor.toml.
HINKKANEN_SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)


def test_example_syrm_motor_file_is_hinkkanens_published_law():
    motor_file = dc.load_motor(EXAMPLES / "syrm_motor.toml")
    truth = from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=20.0, **HINKKANEN_SYRM)
    loaded, expected = motor_file.motor.all_values(), truth.all_values()
    assert loaded.keys() == expected.keys()
    for name, value in expected.items():
        assert loaded[name] == pytest.approx(value, rel=1e-14, abs=0.0), name
    assert motor_file.defaulted == ()  # Ld, Lq come from the law
    assert motor_file.names == ("R", "Ld", "Lq")  # no magnet: lambda_m held at zero, not fitted


def test_example_pm_syrm_motor_file_is_lellis_published_law():
    """examples/pm_syrm_motor.toml: the 5.5-kW PM-SyRM of Lelli et al. (ICEM 2024) with its iron bridge."""
    motor_file = dc.load_motor(EXAMPLES / "pm_syrm_motor.toml")
    law = {k: float(v) for k, v in LELLI_PM_SYRM.items()}
    truth = from_lelli(dc.MotorParams(**LELLI_PM_SYRM_MACHINE), i_ref=10.0, **law)
    loaded, expected = motor_file.motor.all_values(), truth.all_values()
    for name, value in expected.items():
        assert loaded[name] == pytest.approx(value, rel=1e-14, abs=0.0), name
    assert loaded["sat_b"] > 0 and loaded["sat_at_zero"] == 1.0 and loaded["psi_n"] == 0.804
    assert motor_file.defaulted == ()  # Ld, Lq and lambda_m come from the law
    assert dc.motor_from_dict({"estimate": ["R", "sat_b"]}, "m.toml").names == ("R", "sat_b")


def test_per_unit_law_keys_and_saturation_to_estimate():
    motor_file = dc.motor_from_dict({"R": 0.45, "Ld": "3.2 mH", "Lq": "5.8 mH", "lambda_m": 0.0533, "pole_pairs": 4,
                                     "sat_d": 0.3, "sat_q": 0.8, "sat_dq": 0.3, "exp_d": 3, "exp_dq_q": 0,
                                     "i_ref": "30 A", "estimate": ["R", "Ld", "Lq", "lambda_m", "sat_q"]}, "m.toml")
    expected = dc.DEFAULT_MOTOR.replace(sat_d=0.3, sat_q=0.8, sat_dq=0.3, exp_d=3.0, exp_dq_q=0.0, i_ref=30.0)
    assert motor_file.motor.all_values() == expected.all_values()
    assert motor_file.names == ("R", "Ld", "Lq", "lambda_m", "sat_q")
    assert set(MAGNETIC) <= set(dc.motor_from_dict({"estimate": list(MAGNETIC)}, "m.toml").names)


@pytest.mark.parametrize("data, expected", [
    ({"Ld": 0.05, "hinkkanen": HINKKANEN_SYRM}, "m.toml: 'Ld' and the [hinkkanen] table both give the magnetic law"),
    ({"sat_q": 0.5, "hinkkanen": HINKKANEN_SYRM}, "m.toml: 'sat_q' and the [hinkkanen] table both give"),
    ({"hinkkanen": {"a_d0": 17.4}}, "m.toml: 'hinkkanen.a_q0' is missing; add it to the motor file."),
    ({"hinkkanen": {**HINKKANEN_SYRM, "W": 2}}, "m.toml: unknown key 'hinkkanen.W' in the motor file; the known keys "
                                                "are a_d0, a_dd, S, a_q0, a_qq, T, a_dq, U, V (in [hinkkanen])."),
    ({"hinkkanen": {**HINKKANEN_SYRM, "a_q0": 0}}, "m.toml: 'hinkkanen.a_q0': Input should be greater than 0."),
    ({"hinkkanen": 3}, "m.toml: 'hinkkanen': Input should be a valid dictionary"),
    ({"lambda_m": 0.5, "lelli": LELLI_PM_SYRM}, "m.toml: 'lambda_m' and the [lelli] table both give the magnetic law"),
    ({"hinkkanen": HINKKANEN_SYRM, "lelli": LELLI_PM_SYRM}, "m.toml: the [hinkkanen] and [lelli] tables both give"),
    ({"lelli": {**LELLI_PM_SYRM, "psi_n": 0}}, "m.toml: 'lelli.psi_n': Input should be greater than 0."),
    ({"lelli": {**LELLI_PM_SYRM, "X": 1}}, "m.toml: unknown key 'lelli.X' in the motor file; the known keys are "
                                          "a_d0, a_dd, S, a_q0, a_qq, T, a_dq, U, V, a_b, a_bp, k_q, psi_n, W (in [lelli])."),
    ({"sat_at_zero": 0.5}, "m.toml: 'sat_at_zero': Input should be 0 or 1"),
    ({"sat_d": -0.1}, "m.toml: 'sat_d': Input should be greater than or equal to 0."),
    ({"exp_q": 11}, "m.toml: 'exp_q': Input should be less than or equal to 10."),
    ({"i_ref": "3 V"}, "m.toml: 'i_ref': '3 V' has unit 'V' but a current in A is expected"),
    ({"i_ref": 0}, "m.toml: 'i_ref' must be a positive number, got 0.0."),
    ({"lambda_m": -0.1}, "m.toml: 'lambda_m' is the magnet's flux linkage and must be >= 0"),
    ({"lambda_m": 0, "estimate": ["R", "lambda_m"]}, "m.toml: 'estimate' names lambda_m but 'lambda_m' is 0"),
])
def test_a_bad_law_is_one_sentence_naming_the_key(data, expected):
    with pytest.raises(dc.DrivecalError) as info:
        dc.motor_from_dict({"R": 0.45, **data}, "m.toml")
    message = str(info.value)
    assert message.startswith(expected) and "\n" not in message, message


def test_the_cli_refuses_a_bad_law_with_exit_status_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('R = 0.5\nLd = "50 mH"\n\n[hinkkanen]\na_d0 = 17.4\na_q0 = 52.1\n')
    with pytest.raises(SystemExit) as exc:
        main(["plan", "--motor", str(bad), "--vdc", "540", "--imax", "40", "--out", str(tmp_path / "p.toml")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{bad}: 'Ld' and the [hinkkanen] table both give the magnetic law" in err


def test_a_motor_file_without_the_law_is_the_linear_motor_of_before():
    linear = dc.load_motor(EXAMPLES / "motor.toml")
    assert linear.motor.all_values() == dc.DEFAULT_MOTOR.all_values()
    assert not any(dataclasses.asdict(linear.motor)[n] for n in MAGNETIC)


def test_a_held_law_makes_the_selection_saturating():
    """A fit that holds a motor file's law (no term fitted) reports the saturating model, and shows its maps."""
    from types import SimpleNamespace

    from drivecal.selection import EffectSelection

    def selection(motor):
        return EffectSelection(calibration=SimpleNamespace(motor=motor), experiment=None, mode="none", choices=())

    held = dc.load_motor(EXAMPLES / "syrm_motor.toml").motor
    assert selection(held).magnetic_model == "saturating"
    assert selection(dc.DEFAULT_MOTOR).magnetic_model == "linear"
    assert selection(held).to_dict()["magnetic_model"] == "saturating"
