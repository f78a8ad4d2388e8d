"""What a person reads: engineering units with the digits the interval supports (drivecal._units.format_quantity)."""

from __future__ import annotations

import math

import pytest

from drivecal._units import display_unit, format_quantity, format_value


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


def test_the_traction_motors_milliohms_keep_the_digits_of_their_interval():
    """0.00429944 ohm ± 2.57e-08: milliohms, down to the SE's second significant digit (2.6e-5 mΩ)."""
    assert format_quantity(0.00429944, "ohm", 2.57e-08) == "4.299440 ± 0.000026 mΩ"
    assert format_quantity(0.000450932, "H", 3.1e-7) == "450.93 ± 0.31 µH"
    assert format_quantity(0.000450932, "H") == "450.9 µH"


@pytest.mark.parametrize("reference, unit, scale, shown", [
    (0.0032, "H", 1e-3, "mH"),
    (0.000451, "H", 1e-6, "µH"),
    (0.0043, "ohm", 1e-3, "mΩ"),
    (5.8, "ohm", 1.0, "Ω"),
    (0.0533, "Wb", 1e-3, "mWb"),
    (627.0, "V", 1.0, "V"),
    (20e3, "Hz", 1e3, "kHz"),
    (0.02, "A", 1e-3, "mA"),
    (0.0, "A", 1.0, "A"),  # no reference: no prefix
    (0.0012, "kg*m^2", 1.0, "kg·m²"),  # no prefix form
    (8e-5, "N*m*s", 1e-6, "µN·m·s"),  # the viscous friction
    (1.5, "samples", 1.0, "samples"),
    (4.0, "-", 1.0, ""),
])
def test_display_unit_picks_the_prefix_that_puts_the_reference_in_1_to_1000(reference, unit, scale, shown):
    assert display_unit(reference, unit) == (scale, shown)


def test_format_value_is_the_number_in_the_columns_unit():
    scale = display_unit(0.0032, "H")[0]  # a column in mH
    assert format_value(0.0032003, scale, 5.7e-7) == "3.20030"  # to the SE's second significant digit
    assert format_value(5.7e-7, scale, 5.7e-7) == "0.00057"  # the SE itself: two significant digits
    assert format_value(0.0058, scale) == "5.8"  # no SE: four significant digits at most
    assert format_value(0.0032, scale, 0.0021) == "3.2"  # an SE of 2.1 mH: one decimal
    assert format_value(0.0032, scale, 0.021) == "3"  # an SE of 21 mH: no decimals
    assert format_value(math.nan, scale) == "-"
