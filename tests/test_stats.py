"""The statistics helpers of drivecal._stats written once: robust z-scores and power-of-two batch sizes."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from drivecal._stats import (MAD_TO_SD, chi2_isf, chi2_sf, fast_median, next_power_of_two, robust_centre_scale,
                             robust_z, t_ppf)


def test_robust_z_is_median_over_mad_as_the_fleet_check_computed_it():
    """Bit for bit the fleet check's former pandas arithmetic (NaN left out of the centre and the scale)."""
    values = pd.Series(np.random.default_rng(1).normal(0.0125, 3e-4, 101))
    values[[3, 50]] = np.nan
    values[7] = 0.02
    centre = float(values.median())
    scale = 1.4826 * float((values - centre).abs().median())
    z, c, s = robust_z(values.to_numpy())
    assert (c, s) == (centre, scale) and MAD_TO_SD == 1.4826
    expected = ((values - centre) / scale).to_numpy()
    np.testing.assert_array_equal(z, expected)
    assert np.isnan(z[[3, 50]]).all() and z[7] > 20


def test_robust_centre_scale_is_the_reports_nanmedian_arithmetic():
    values = np.random.default_rng(2).standard_normal(40)
    values[5] = np.nan
    centre = float(np.nanmedian(values))
    assert robust_centre_scale(values) == (centre, float(np.nanmedian(np.abs(values - centre))) * 1.4826)
    assert all(math.isnan(v) for v in robust_centre_scale([np.nan, np.nan]))


def test_robust_z_of_identical_values_still_singles_out_the_odd_one():
    """MAD 0 (most values alike): the scale falls back to a tiny fraction of the centre."""
    z, centre, scale = robust_z([2.0, 2.0, 2.0, 2.0, 2.5])
    assert centre == 2.0 and scale == 2e-12
    assert list(z[:4]) == [0.0] * 4 and z[4] == pytest.approx(0.5 / 2e-12)
    assert robust_z([0.0, 0.0, 0.0])[2] == 1e-300


def test_next_power_of_two_equals_the_formulas_it_replaces():
    # fleet._batch._bucket (before the chunk cap); design._autoplan._bucket and bench._step's span (at least 2).
    for n in range(0, 5000):
        assert next_power_of_two(n) == 1 << max(0, math.ceil(math.log2(max(n, 1)))), n
        if n >= 1:
            assert next_power_of_two(n, minimum=2) == 1 << max(n - 1, 1).bit_length(), n


# The two below also stand in tests/test_data.py and tests/test_report.py, which reach into drivecal._stats
# (the architecture test refuses it there): they belong here, and leave those files.


@pytest.mark.parametrize("n", [4, 5, 1000, 1001])
def test_partition_median_is_numpy_median(n):
    x = np.random.default_rng(n).normal(size=n)
    assert fast_median(x) == np.median(x)
    columns = np.random.default_rng(n + 1).normal(size=(n, 3))
    np.testing.assert_array_equal(fast_median(columns), np.median(columns, axis=0))


def test_distributions_are_scipy_stats_bit_for_bit():
    """drivecal computes t.ppf and chi2.sf with scipy.special (scipy.stats costs a second to import)."""
    from scipy import stats

    df = np.concatenate([np.arange(1, 2000), [2797, 12_345, 10**6]])
    for q in (0.975, 0.5, 0.025):
        np.testing.assert_array_equal(t_ppf(q, df), stats.t.ppf(q, df))
        assert t_ppf(q, 2797) == stats.t.ppf(q, 2797) and type(t_ppf(q, 7)) is type(stats.t.ppf(q, 7))
    x = np.concatenate([np.random.default_rng(0).exponential(30.0, 3000), [0.0, -1.0, np.nan, np.inf]])
    for k in (1, 2, 10):
        np.testing.assert_array_equal(chi2_sf(x, k), stats.chi2.sf(x, k))
        np.testing.assert_array_equal(chi2_sf(x.reshape(-1, 2), k), stats.chi2.sf(x.reshape(-1, 2), k))
        assert all(chi2_sf(v, k) == stats.chi2.sf(v, k) for v in x[:50])


def test_chi2_isf_is_scipy_stats_bit_for_bit():
    from scipy import stats

    for k in (1, 2, 10, 20):
        for p in (1e-12, 1e-3, 0.05, 0.5, 0.999):
            assert chi2_isf(p, k) == stats.chi2.isf(p, k)


# A fresh interpreter: drivecal's distributions first, then SciPy's own packages, as a user's script might.
_FIRST_THEN_SCIPY = """
import sys
from drivecal._stats import chi2_isf, chi2_sf, t_ppf
values = (t_ppf(0.975, 7), chi2_sf(3.0, 2), chi2_isf(0.05, 10))
print("f2py" if "numpy.f2py" in sys.modules else "no f2py", "scipy.special" in sys.modules)
from scipy import special, stats
print(values == (stats.t.ppf(0.975, 7), stats.chi2.sf(3.0, 2), stats.chi2.isf(0.05, 10)),
      special.stdtrit is special._ufuncs.stdtrit, special.gamma(5.0))
"""


def test_the_distributions_load_scipys_compiled_functions_alone_and_scipy_still_imports_whole():
    """The first call loads ``scipy.special``'s compiled functions without its array-API layer (which imports
    numpy.f2py: ~0.13 s a process) and leaves no package behind; SciPy's packages then import as usual."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _FIRST_THEN_SCIPY], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == ["no f2py False", "True True 24.0"]
