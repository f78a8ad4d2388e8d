"""Plan and motor TOML files: schema, units, and one-sentence errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import drivecal as dc

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_example_default_plan_is_the_default_plan():
    loaded = dc.load_plan(EXAMPLES / "default_plan.toml")
    reference = dc.default_plan()
    assert loaded.sample_rate == reference.sample_rate and loaded.v_dc == reference.v_dc
    for a, b in zip(loaded.segments, reference.segments):
        assert (a.name, a.locked) == (b.name, b.locked)
        assert np.array_equal(a.voltages(loaded.sample_rate), b.voltages(reference.sample_rate))


@pytest.mark.parametrize("name", ["chirp_plan", "multisine_plan", "prbs_plan", "seed_poor_plan"])
def test_example_plans_load_and_are_feasible(name):
    plan = dc.load_plan(EXAMPLES / f"{name}.toml")
    assert plan.check_feasible() is plan


def test_example_motor_is_the_default_motor():
    mf = dc.load_motor(EXAMPLES / "motor.toml")
    assert mf.motor.as_dict() == pytest.approx(dc.DEFAULT_MOTOR.as_dict(), rel=1e-15)
    assert mf.estimate is None and mf.names == dc.ESTIMATED


def test_units_are_converted_to_si():
    plan = dc.plan_from_dict({"sample_rate": "10 kHz", "v_dc": 300, "segment": [
        {"name": "a", "duration": "2.5 ms", "locked": True, "v_d": "1500 mV"}]})
    assert plan.sample_rate == 10_000.0 and plan.segments[0].duration == pytest.approx(2.5e-3)
    assert plan.segments[0].voltages(plan.sample_rate)[0, 0] == pytest.approx(1.5)
    mf = dc.motor_from_dict({"R": "450 mohm", "Ld": "3200 uH", "lambda_m": "53.3 mWb", "estimate": ["R", "Ld"]})
    assert (mf.motor.R, mf.motor.Ld, mf.motor.lambda_m) == pytest.approx((0.45, 3.2e-3, 0.0533))
    assert mf.names == ("R", "Ld")


@pytest.mark.parametrize(
    "data, expected",
    [
        ({"segment": [{"name": "a", "duration": 0.01, "locked": True, "v_d": 1.0, "vd": 2.0}]},
         r"unknown key 'segment\[0\]\.vd'"),
        ({"sample_rate": "20 kV", "segment": [{"name": "a", "duration": 0.01, "locked": True}]},
         r"'sample_rate': '20 kV' has unit 'kV' but a frequency in Hz is expected"),
        ({"segment": [{"name": "a", "duration": "10 V", "locked": True}]},
         r"'segment\[0\]\.duration': '10 V' has unit 'V' but a time in s"),
        ({"segment": [{"name": "a", "duration": 0.01, "locked": True,
                       "v_d": {"kind": "chirp", "amplitude": "3 A", "f_start": 10, "f_stop": 100}}]},
         r"'segment\[0\]\.v_d\.amplitude': '3 A' has unit 'A' but a voltage"),
        ({"segment": [{"name": "a", "locked": True}]}, r"'segment\[0\]\.duration' is missing"),
        ({"segment": [{"name": "a", "duration": 0.01, "locked": True, "v_d": 30.0}]},
         r"segment 'a': \|v_dq\| reaches 30.00 V .* outside the voltage circle"),
    ],
)
def test_bad_plan_is_one_sentence_naming_the_key(data, expected):
    with pytest.raises(dc.DrivecalError, match=expected) as info:
        dc.plan_from_dict(data, source="p.toml")
    message = str(info.value)
    assert message.startswith("p.toml") and "\n" not in message


def test_bad_motor_file_names_the_key():
    with pytest.raises(dc.DrivecalError, match=r"m.toml: unknown key 'Rs' in the motor file"):
        dc.motor_from_dict({"Rs": 0.4}, source="m.toml")
    with pytest.raises(dc.DrivecalError, match=r"m.toml: 'Ld': '3.2 mOhm' has unit 'mOhm' but a inductance"):
        dc.motor_from_dict({"Ld": "3.2 mOhm"}, source="m.toml")
    with pytest.raises(dc.DrivecalError, match=r"'R' must be a positive number"):
        dc.motor_from_dict({"R": -1.0}, source="m.toml")


def test_motor_files_are_read_by_data_and_units_shared_with_plans(tmp_path):
    """Motor files belong to drivecal.data; plan and motor files parse units alike (drivecal.plan keeps read_toml)."""
    import drivecal.data
    import drivecal.plan

    assert dc.MotorFile is drivecal.data.MotorFile
    assert dc.load_motor is drivecal.data.load_motor and dc.motor_from_dict is drivecal.data.motor_from_dict
    assert drivecal.data.MotorSpec.model_fields["R"].default == dc.DEFAULT_MOTOR.R
    assert drivecal.plan.parse_quantity("3.2 mH", "inductance") == pytest.approx(3.2e-3)
    path = tmp_path / "motor.toml"
    path.write_text('Ld = "3.2 mH"\n')
    assert drivecal.plan.read_toml(path) == {"Ld": "3.2 mH"}
    assert dc.load_motor(path).motor.Ld == pytest.approx(3.2e-3)
    for bad, expected in [("Ld = ", "not valid TOML"), (None, "no such file")]:
        if bad is not None:
            path.write_text(bad)
        with pytest.raises(dc.DrivecalError, match=expected):
            dc.load_motor(path if bad is not None else tmp_path / "none.toml")
