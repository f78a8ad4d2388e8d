"""The numbers behind the fleet report's figures (drivecal.fleet._report_stats): natural order, units, robust
ranges, the rolling band and the drift."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from drivecal.fleet._report_stats import (BAND_K, DRIFT_FRACTION, drift_noise, drift_of, drift_threshold,
                                          engineering_unit,
                                          line_positions, natural_order, parameter_view, robust_view, rolling_band,
                                          rolling_window)
from helpers.fleet_table import DRIFTING, planted_table


def test_serials_sort_in_natural_order():
    serials = ["SN10", "SN2", "sn1", "SN100", "SN2a", "B7", "SN02-3", "SN2-10", "SN2-9"]
    ordered = [serials[i] for i in natural_order(serials)]
    assert ordered == ["B7", "sn1", "SN2", "SN02-3", "SN2-9", "SN2-10", "SN2a", "SN10", "SN100"]


@pytest.mark.parametrize("name, reference, unit, factor", [
    ("R", 0.45, "mΩ", 1e3), ("R", 2.2, "Ω", 1.0), ("Ld", 3.2e-3, "mH", 1e3), ("Lq", 450e-6, "µH", 1e6),
    ("lambda_m", 0.0533, "mWb", 1e3), ("J", 1.2e-3, "kg·m²", 1.0), ("R", 0.0, "Ω", 1.0), ("R", math.nan, "Ω", 1.0)])
def test_engineering_units(name, reference, unit, factor):
    assert engineering_unit(name, reference) == (unit, factor)


def test_the_rolling_window_grows_with_the_line():
    assert [rolling_window(n) for n in (3, 50, 200, 600, 3000, 100000)] == [3, 11, 13, 41, 151, 151]
    assert all(rolling_window(n) % 2 for n in range(11, 5000, 37))


def test_the_axis_holds_the_population_and_near_limits_and_names_far_ones():
    rng = np.random.default_rng(0)
    values = np.concatenate([1.0 + 0.01 * rng.standard_normal(500), [1.5, 0.5]])
    (lo, hi), off = robust_view(values, 1.0, 0.01, 5.0, {"nominal": 1.0, "upper limit": 1.05, "lower limit": 0.2})
    assert lo < 0.94 and 1.05 < hi < 1.07  # ±6 robust SD, widened to the upper limit
    assert off == {"lower limit": 0.2}  # 80 SD away: named at the edge, not drawn
    (lo, hi), off = robust_view(np.full(5, 2.0), 2.0, 0.0, 5.0, {})
    assert lo < 2.0 < hi and off == {}  # identical values: still a range


def test_the_rolling_band_and_the_drift_of_a_planted_drift():
    rng = np.random.default_rng(1)
    flat = rng.standard_normal(1000)
    band = rolling_band(flat, 67)
    half = float(np.nanmedian(band["high"] - band["median"]))
    assert half == pytest.approx(BAND_K, rel=0.1)  # ± BAND_K robust SD of unit-SD noise
    assert drift_of(band, float(np.median(flat)), 67) < 4 * drift_noise(67) < DRIFT_FRACTION
    drifting = flat + np.linspace(-2.0, 2.0, 1000)
    assert drift_of(rolling_band(drifting, 67), float(np.median(drifting)), 67) == pytest.approx(0.93, abs=0.1)
    assert math.isnan(drift_of(pd.DataFrame({"median": [1.0], "low": [1.0], "high": [1.0]}), 1.0))


def test_the_drift_shows_along_the_natural_serial_order_not_along_the_rows():
    """Rows as a table may hold them (here shuffled): against the row index the drift hides."""
    table = planted_table(600, seed=3, shuffle=True)
    natural, label = line_positions(table)
    assert label == "motor, in serial order"
    view = parameter_view(table, DRIFTING, natural, 5.0)
    assert list(view.serial[:3]) == ["SN1", "SN2", "SN3"] and list(view.serial[8:11]) == ["SN9", "SN10", "SN11"]
    by_row = parameter_view(table, DRIFTING, np.arange(len(table), dtype=float), 5.0)
    assert by_row.drift < DRIFT_FRACTION < view.drift


def test_a_short_line_without_drift_is_rarely_called_drifting():
    """The call 'visible' takes the rolling median's wander into account: 400 lines of 100 drift-free motors."""
    assert drift_threshold(41) == DRIFT_FRACTION and drift_threshold(11) > DRIFT_FRACTION
    rng = np.random.default_rng(5)
    window = rolling_window(100)
    called = 0
    for _ in range(400):
        x = rng.standard_normal(100)
        called += drift_of(rolling_band(x, window), float(np.median(x)), window) >= drift_threshold(window)
    assert called <= 4  # at most 1 % of drift-free lines
    x = rng.standard_normal(100) + np.linspace(-4.0, 4.0, 100)  # ±2 band half-widths
    assert drift_of(rolling_band(x, window), float(np.median(x)), window) >= drift_threshold(window)
