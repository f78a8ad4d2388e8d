"""What a person reads: engineering units with the digits the interval supports (drivecal._units.format_quantity)."""

from __future__ import annotations

import math

import pytest

from drivecal._units import format_quantity


@pytest.mark.parametrize("value, unit, se, text", [
    (0.0032003, "H", 5.7e-7, "3.20030 ± 0.00057 mH"),  # digits down to the SE's second significant digit
    (0.0032, "H", None, "3.2 mH"),
    (0.45, "ohm", 4.3e-5, "450.000 ± 0.043 mΩ"),
    (0.0043, "ohm", None, "4.3 mΩ"),  # the traction motor's milliohms
    (5.8, "ohm", 0.031, "5.800 ± 0.031 Ω"),  # the servo's ohms
    (0.000451, "H", None, "451 µH"),
    (0.0533, "Wb", 6.1e-6, "53.3000 ± 0.0061 mWb"),
    (627.0, "V", None, "627 V"),
    (0.0, "A", None, "0 A"),
    (0.0, "A", 0.002, "0.0 ± 2.0 mA"),  # a zero estimate takes its SE's prefix
    (4.0, "-", None, "4"),
    (1.0, "samples", 0.01, "1.000 ± 0.010 samples"),  # units without a prefix form stay as written
    (0.0012, "kg*m^2", None, "0.0012 kg·m²"),
])
def test_format_quantity(value, unit, se, text):
    assert format_quantity(value, unit, se) == text


def test_format_quantity_without_a_usable_se():
    assert format_quantity(0.45, "ohm", math.nan) == "450 mΩ"
    assert format_quantity(0.45, "ohm", 0.0) == "450 mΩ"
    assert format_quantity(math.nan, "ohm") == "nan ohm"
