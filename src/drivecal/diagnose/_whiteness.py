"""Whether residuals are white: the Ljung-Box test and the rule that reads its p-values.

One fit's residuals are tested segment by segment and current axis by axis
with ``WHITENESS_LAGS`` lags; they are white unless some test rejects at
family-wise level ``WHITENESS_ALPHA`` (Bonferroni: each p-value against
``WHITENESS_ALPHA`` divided by the number of tests). A correct model leaves
sensor noise, which is white; an unmodelled effect (a wrong R, saturation,
dead time) leaves a smooth, autocorrelated trace. The verdict of one fit
(``residual_checks``) and the fleet's batched check (``fleet.residual_diagnostics``)
both apply :func:`whiteness_rule`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._stats import chi2_sf

#: Lags of the Ljung-Box whiteness test.
WHITENESS_LAGS = 10
#: Family-wise false-alarm rate of the whiteness tests of one fit.
WHITENESS_ALPHA = 1e-3


def ljung_box(x: np.ndarray, lags: int = WHITENESS_LAGS) -> tuple[Any, Any]:
    """Ljung-Box statistic ``Q = N(N+2) sum_k r_k^2/(N-k)`` and its chi^2(lags) p-value.

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
    p = chi2_sf(q, lags)
    return (float(q), float(p)) if x.ndim == 1 else (q, p)


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
