"""The two distribution functions drivecal needs, straight from ``scipy.special``.

``scipy.stats`` computes ``t.ppf`` and ``chi2.sf`` with these same special
functions, but importing it loads most of SciPy (about a second per
process). The results are bit for bit those of ``scipy.stats``
(tests/test_report.py checks it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import special


def t_ppf(q: Any, df: Any) -> Any:
    """Student-t quantile, ``scipy.stats.t.ppf(q, df)`` for ``0 < q < 1`` (NaN where ``df <= 0``)."""
    q, df = np.asarray(q, dtype=float), np.asarray(df, dtype=float)
    out = np.where(df > 0, special.stdtrit(df, q), np.nan)
    return out[()] if out.ndim == 0 else out


def chi2_sf(x: Any, df: Any) -> Any:
    """Chi-squared survival function, ``scipy.stats.chi2.sf(x, df)``: 1 for ``x <= 0``, NaN where ``df <= 0``."""
    x, df = np.asarray(x, dtype=float), np.asarray(df, dtype=float)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0, 1.0, special.chdtrc(df, np.maximum(x, 0.0)))
    out = np.where(df > 0, out, np.nan)
    return out[()] if out.ndim == 0 else out


def fast_median(x: np.ndarray, axis: int = 0) -> Any:
    """``np.median`` along ``axis`` by partition (~5x faster on a few thousand samples)."""
    n = x.shape[axis]
    part = np.partition(x, [(n - 1) // 2, n // 2], axis=axis)
    return 0.5 * (np.take(part, (n - 1) // 2, axis=axis) + np.take(part, n // 2, axis=axis))
