"""Whether residuals are white: the Ljung-Box test and the rule that reads its p-values.

One fit's residuals are tested segment by segment and current axis by axis
with ``WHITENESS_LAGS`` lags; they are white unless some test rejects at
family-wise level ``WHITENESS_ALPHA`` (Bonferroni: each p-value against
``WHITENESS_ALPHA`` divided by the number of tests). A correct model leaves
sensor noise, which is white; an unmodelled effect (a wrong R, saturation,
dead time) leaves a smooth, autocorrelated trace. The verdict of one fit
(``residual_checks``) and the fleet's batched check (``fleet.residual_diagnostics``)
both apply :func:`whiteness_rule`.

The p-value is the statistic's simulated null, not the textbook chi^2(lags):
at the lengths drivecal tests the chi^2 approximation rejects white noise far
too often in the upper tail where the Bonferroni levels lie (at n = 200 and 10
lags, 2.4 times at p = 1e-3 and 4 times at p = 1.7e-4). :func:`null_sf` reads
the quantiles of Q simulated for white Gaussian series of 16 to 2048 samples
(``_ljung_box_table``, written by ``tools/ljung_box_null.py``), interpolated in
log p between tabulated tail probabilities and in log n between lengths, and a
chi^2 scaled to the nearest tabulated quantile beyond them; longer series take
the 2048-sample row (within a few percent of their own null, and on the safe
side). The false-alarm rate is then the nominal one (tested on white noise).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._stats import WHITENESS_ALPHA, WHITENESS_LAGS, chi2_isf, chi2_sf
from . import _ljung_box_table as _table


def ljung_box(x: np.ndarray, lags: int = WHITENESS_LAGS) -> tuple[Any, Any]:
    """Ljung-Box statistic ``Q = N(N+2) sum_k r_k^2/(N-k)`` and its p-value under white noise (:func:`null_sf`).

    Args:
        x: residual series along the last axis, shape (..., N), N > lags + 1;
            leading axes (motors of a fleet, segments) are tested independently.
        lags: number of autocorrelation lags summed.

    Returns:
        ``(Q, p)``: floats for one series, arrays of shape (...) otherwise
        (NaN where a series is too short or constant).
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    lags = min(lags, n - 2)
    if lags < 1:
        nan = np.full(x.shape[:-1], np.nan)
        return (float("nan"), float("nan")) if x.ndim == 1 else (nan, nan)
    d = x - x.mean(axis=-1, keepdims=True)
    # einsum sums the lagged products without a temporary array per lag (a fleet tests ~1000 series a chunk).
    denom = np.einsum("...i,...i->...", d, d)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.stack([np.einsum("...i,...i->...", d[..., :-k], d[..., k:]) for k in range(1, lags + 1)], axis=-1)
        r = r / denom[..., None]
        q = n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1)), axis=-1)
    q = np.where(denom > 0, q, np.nan)
    p = null_sf(q, n, lags)
    return (float(q), float(p)) if x.ndim == 1 else (q, p)


def _row_log_sf(q: np.ndarray, row: int) -> np.ndarray:
    """log P(Q >= q) at the tabulated length ``LENGTHS[row]``: log-linear between the tabulated quantiles, a
    chi^2(LAGS) scaled to the first or last quantile outside them."""
    quantiles = np.asarray(_table.QUANTILES[row], dtype=float)
    log_tails = np.log(np.asarray(_table.TAILS, dtype=float))
    inside = np.interp(q, quantiles, log_tails)
    with np.errstate(divide="ignore"):
        below = np.log(chi2_sf(q * (chi2_isf(_table.TAILS[0], _table.LAGS) / quantiles[0]), _table.LAGS))
        above = np.log(chi2_sf(q * (chi2_isf(_table.TAILS[-1], _table.LAGS) / quantiles[-1]), _table.LAGS))
    return np.where(q < quantiles[0], below, np.where(q > quantiles[-1], above, inside))


def null_sf(q: Any, n: int, lags: int = WHITENESS_LAGS) -> Any:
    """P(Q >= q) for a white Gaussian series of ``n`` samples: the p-value of a Ljung-Box statistic ``q``.

    The simulated null (``_ljung_box_table``) where it is tabulated (``lags`` =
    10, n >= 16; longer series than the table take its last row), chi^2(lags)
    otherwise. ``q`` any shape (NaN stays NaN); returns the same shape.
    """
    q = np.asarray(q, dtype=float)
    lengths = np.asarray(_table.LENGTHS, dtype=float)
    if lags != _table.LAGS or n < lengths[0]:
        p = chi2_sf(q, lags)
        return p
    n = min(float(n), lengths[-1])
    hi = int(np.searchsorted(lengths, n))
    lo = max(hi - 1, 0) if lengths[hi] != n else hi
    log_p = _row_log_sf(q, hi)
    if lo != hi:
        w = (np.log(n) - np.log(lengths[lo])) / (np.log(lengths[hi]) - np.log(lengths[lo]))
        log_p = (1.0 - w) * _row_log_sf(q, lo) + w * log_p
    p = np.minimum(np.exp(log_p), 1.0)
    return float(p) if p.ndim == 0 else p


def whiteness_rule(p_values: Any) -> tuple[Any, Any]:
    """The whiteness rule over one fit's Ljung-Box p-values (last axis; leading axes: one fit each).

    NaN p-values (a series too short or constant to test) are not tests. The
    threshold is ``WHITENESS_ALPHA`` over the number of tests (at least one);
    the residuals are white when no test's p-value is below it.

    Returns:
        ``(threshold, white)``: a float and a bool for one fit (1-D or empty
        input), arrays of the leading shape otherwise.
    """
    p = np.asarray(p_values, dtype=float)
    tested = np.isfinite(p)
    threshold = WHITENESS_ALPHA / np.maximum(tested.sum(axis=-1), 1)
    white = ~np.any(tested & (p < np.expand_dims(threshold, -1)), axis=-1)
    return (float(threshold), bool(white)) if p.ndim <= 1 else (threshold, white)
