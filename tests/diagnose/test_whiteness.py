"""The whiteness rule, written once: the verdict's and the fleet's reading of the Ljung-Box p-values."""

from __future__ import annotations

import numpy as np
import pytest

from drivecal.diagnose import WHITENESS_ALPHA, ljung_box, null_sf, whiteness_rule


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
    """Q = N(N+2) sum_k r_k^2 / (N-k), r_k the lag-k autocorrelation, computed plainly; p from the simulated null
    (chi^2(lags) where the lags are not the tabulated ones)."""
    from scipy import stats

    x = np.random.default_rng(4).standard_normal(257)
    d = x - x.mean()
    n, lags = x.size, 10
    r = np.array([np.correlate(d[:-k], d[k:])[0] for k in range(1, lags + 1)]) / (d @ d)
    q = n * (n + 2) * sum(r[k - 1] ** 2 / (n - k) for k in range(1, lags + 1))
    q_lb, p_lb = ljung_box(x, lags)
    assert q_lb == pytest.approx(q, rel=1e-12)
    assert p_lb == pytest.approx(float(null_sf(q, n, lags)), rel=1e-12)
    q8, p8 = ljung_box(x, 8)  # not tabulated: chi^2(8)
    assert p8 == pytest.approx(float(stats.chi2.sf(q8, 8)), rel=1e-12)


def _white_p_values(rng, count, n):
    """Ljung-Box p-values of ``count`` white Gaussian series of ``n`` samples (in chunks: memory stays small)."""
    chunk = max(1, 4_000_000 // n)
    return np.concatenate([ljung_box(rng.standard_normal((min(chunk, count - k), n)))[1]
                           for k in range(0, count, chunk)])


@pytest.mark.slow
@pytest.mark.parametrize("n, count, levels", [(200, 1_200_000, (1e-2, 1e-3, WHITENESS_ALPHA / 6)),
                                              (1000, 300_000, (1e-2, 1e-3))])
def test_each_test_rejects_white_noise_at_its_nominal_rate(n, count, levels):
    """Per test, at the levels the Bonferroni rule uses: within 30 % of nominal, with >= 200 alarms expected (the
    binomial SD is then <= 7 % of it). The chi^2 approximation gave 2.4x at 1e-3 and 4x at 1.7e-4 for n = 200.
    Seeded apart from the table's simulation; the 1000-sample series meet 1.7e-4 in the default-plan test."""
    p = _white_p_values(np.random.default_rng(7), count, n)
    for level in levels:
        expected = level * count
        assert abs((p < level).sum() - expected) < 0.3 * expected, (n, level, (p < level).sum(), expected)


@pytest.mark.slow
def test_the_default_plans_false_alarm_rate_is_nominal():
    """200 000 white-noise 'motors' laid out as the default plan (two 200-sample and one 1000-sample segment,
    i_d and i_q each): the whiteness rule alarms on WHITENESS_ALPHA of them, within 30 % (200 expected: the
    binomial SD is 7 %). With the chi^2 p-values it alarmed on about 2.5 times as many."""
    rng = np.random.default_rng(11)
    motors = 200_000
    p = np.column_stack([_white_p_values(rng, motors, n) for n in (200, 200, 200, 200, 1000, 1000)])
    _, white = whiteness_rule(p)
    alarms, expected = int((~white).sum()), WHITENESS_ALPHA * motors
    assert abs(alarms - expected) < 0.3 * expected, (alarms, expected)


def test_the_null_is_continuous_and_falls_with_q():
    q = np.linspace(0.0, 80.0, 801)
    for n in (16, 20, 200, 333, 1000, 2048, 5000):
        p = null_sf(q, n)
        assert np.all(np.diff(p) <= 0) and p[0] == 1.0 and 0.0 < p[-1] < 1e-6
        assert np.max(np.abs(np.diff(np.log(p[100:])))) < 0.6  # no jumps at the table's edges
    assert np.isnan(null_sf(np.nan, 200))
