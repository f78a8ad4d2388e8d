"""The whiteness rule, written once: the verdict's and the fleet's reading of the Ljung-Box p-values."""

from __future__ import annotations

import numpy as np
import pytest

from drivecal.diagnose import WHITENESS_ALPHA, whiteness_rule


def _verdict_rule(p):  # as diagnose.residual_checks read its tests before the rule moved
    tests = [x for x in p if np.isfinite(x)]
    threshold = WHITENESS_ALPHA / max(len(tests), 1)
    return threshold, all(x >= threshold for x in tests)


def _fleet_rule(p):  # as fleet.residual_diagnostics read them before the rule moved
    tested = np.isfinite(p)
    threshold = WHITENESS_ALPHA / np.maximum(tested.sum(axis=1), 1)
    return threshold, ~(np.where(tested, p, np.inf).min(axis=1) < threshold)


def test_the_rule_is_the_verdicts_and_the_fleets():
    rng = np.random.default_rng(0)
    p = 10.0 ** rng.uniform(-6, 0, (400, 8))
    p[rng.random(p.shape) < 0.1] = np.nan
    p[0] = np.nan  # nothing tested: white, threshold alpha
    threshold, white = whiteness_rule(p)
    expected_threshold, expected_white = _fleet_rule(p)
    np.testing.assert_array_equal(threshold, expected_threshold)
    np.testing.assert_array_equal(white, expected_white)
    assert 0 < white.mean() < 1 and white[0] and threshold[0] == WHITENESS_ALPHA
    for row in p[:50]:
        one = whiteness_rule(list(row))
        assert one == _verdict_rule(list(row))
        assert isinstance(one[0], float) and isinstance(one[1], bool)


def test_bonferroni_threshold_and_empty_input():
    assert whiteness_rule([]) == (WHITENESS_ALPHA, True)
    assert whiteness_rule([0.5, 0.5, 0.5, WHITENESS_ALPHA / 4]) == (pytest.approx(WHITENESS_ALPHA / 4), True)
    assert whiteness_rule([0.5, 0.5, np.nan, WHITENESS_ALPHA / 4]) == (pytest.approx(WHITENESS_ALPHA / 3), False)


def test_ljung_box_equals_its_formula():
    """Q = N(N+2) sum_k r_k^2 / (N-k), r_k the lag-k autocorrelation, computed plainly; p from chi^2(lags)."""
    from scipy import stats

    from drivecal.diagnose import ljung_box

    x = np.random.default_rng(4).standard_normal(257)
    d = x - x.mean()
    n, lags = x.size, 10
    r = np.array([np.correlate(d[:-k], d[k:])[0] for k in range(1, lags + 1)]) / (d @ d)
    q = n * (n + 2) * sum(r[k - 1] ** 2 / (n - k) for k in range(1, lags + 1))
    q_lb, p_lb = ljung_box(x, lags)
    assert q_lb == pytest.approx(q, rel=1e-12)
    assert p_lb == pytest.approx(float(stats.chi2.sf(q, lags)), rel=1e-12)
