"""The Python API prints values a person can read (issue 22, item 6): MotorParams and Calibration, and
``fit`` takes a loaded motor file as the CLI does."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

import drivecal as dc

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_motor_params_repr_and_str():
    m = dc.DEFAULT_MOTOR.replace(v_dead=0.4)
    assert repr(m) == ("MotorParams(R=0.45, Ld=0.0032, Lq=0.0058, lambda_m=0.0533, pole_pairs=4.0, J=0.0012, "
                       "B=8e-05, v_dead=0.4)")
    lines = str(m).splitlines()
    assert lines[0] == "MotorParams:"
    assert "    R          = 450 mΩ" in lines and "    Ld         = 3.2 mH" in lines
    assert "    v_dead     = 400 mV" in lines
    assert str(dc.DEFAULT_MOTOR.replace(R=np.ones(3))) == "MotorParams batch of shape (3,)"


def test_calibration_repr(default_fit):
    text = repr(default_fit)
    assert text.startswith("Calibration(R = ") and "mΩ" in text and "mH" in text and "mWb" in text
    assert "; converged; " in text and "array(" not in text


def test_fit_takes_a_motor_file(default_bench):
    motor_file = dc.load_motor(EXAMPLES / "motor.toml")
    cal = dc.fit(default_bench, motor_file)
    same = dc.fit(default_bench, motor_file.motor, names=motor_file.estimate or dc.ESTIMATED,
                  delay_samples=motor_file.delay_samples)
    assert cal.names == same.names
    np.testing.assert_allclose(cal.estimate, same.estimate, rtol=1e-12)


def test_calibration_str_reads_in_engineering_units(default_fit):
    """print(cal): each parameter in its own prefix, the estimate and interval to the SE's second significant
    digit, sigma_hat in mA."""
    text = str(default_fit)
    assert re.search(r"^    sigma_hat\s+= \d+\.\d+ mA$", text, re.M), text
    for name, unit in (("R", "mΩ"), ("Ld", "mH"), ("Lq", "mH"), ("lambda_m", "mWb")):
        line = re.search(rf"^    {name} +{unit} +(\S+) +(\S+) +\[(\S+), (\S+)\]", text, re.M)
        assert line, (name, text)
        estimate, se, low, high = line.groups()
        assert len(se.replace(".", "").lstrip("0")) == 2, se  # two significant digits
        assert len(estimate.split(".")[1]) == len(se.split(".")[1]) == len(low.split(".")[1]) == len(high.split(".")[1])
