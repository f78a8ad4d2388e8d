"""drivecal's statistics, each written once: three distribution functions, a fast median, robust z-scores
and power-of-two batch sizes.

``t_ppf``, ``chi2_sf`` and ``chi2_isf`` come straight from ``scipy.special``'s compiled
functions: ``scipy.stats`` computes ``t.ppf``, ``chi2.sf`` and ``chi2.isf`` with these same
functions, but importing it loads most of SciPy (about a second per process). The results are bit
for bit those of ``scipy.stats`` (tests/test_stats.py checks it). The functions are loaded on
their first call (:func:`_special_functions`), so a command that needs only the rest of this
module (``drivecal inspect``) does not load them.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

#: ``scipy.special._ufuncs`` once loaded (:func:`_special_functions`), and the lock its first load holds.
_UFUNCS: Any = None
_UFUNCS_LOCK = threading.Lock()


def _special_functions() -> Any:
    """The module of ``scipy.special``'s compiled functions (``stdtrit``, ``chdtrc``, ``chdtri``), loaded once.

    ``import scipy.special`` runs the package's ``__init__``, which loads its array-API layer: that
    clones NumPy's namespace and so imports ``numpy.f2py`` (~0.13 s of the ~0.16 s it takes; the
    compiled functions themselves ~0.03 s, measured in a fresh process). drivecal needs the
    functions only: their module is imported without the package's ``__init__`` (``_apart``).
    """
    global _UFUNCS
    if _UFUNCS is None:  # every call after the first one takes no lock
        with _UFUNCS_LOCK:
            if _UFUNCS is None:
                _UFUNCS = _load_special_functions()
    return _UFUNCS


def _load_special_functions() -> Any:
    from ._apart import import_apart

    with import_apart("scipy.special", ("_ufuncs",)) as (ufuncs,):
        return ufuncs


def t_ppf(q: Any, df: Any) -> Any:
    """Student-t quantile, ``scipy.stats.t.ppf(q, df)`` for ``0 < q < 1`` (NaN where ``df <= 0``)."""
    special = _special_functions()
    q, df = np.asarray(q, dtype=float), np.asarray(df, dtype=float)
    out = np.where(df > 0, special.stdtrit(df, q), np.nan)
    return out[()] if out.ndim == 0 else out


def chi2_sf(x: Any, df: Any) -> Any:
    """Chi-squared survival function, ``scipy.stats.chi2.sf(x, df)``: 1 for ``x <= 0``, NaN where ``df <= 0``."""
    special = _special_functions()
    x, df = np.asarray(x, dtype=float), np.asarray(df, dtype=float)
    with np.errstate(invalid="ignore"):
        out = np.where(x <= 0, 1.0, special.chdtrc(df, np.maximum(x, 0.0)))
    out = np.where(df > 0, out, np.nan)
    return out[()] if out.ndim == 0 else out


def chi2_isf(p: float, df: float) -> float:
    """Chi-squared inverse survival function, ``scipy.stats.chi2.isf(p, df)`` for ``0 < p < 1`` and ``df > 0``."""
    return float(_special_functions().chdtri(df, p))


def fast_median(x: np.ndarray, axis: int = 0) -> Any:
    """``np.median`` along ``axis`` by partition (~5x faster on a few thousand samples)."""
    n = x.shape[axis]
    part = np.partition(x, [(n - 1) // 2, n // 2], axis=axis)
    return 0.5 * (np.take(part, (n - 1) // 2, axis=axis) + np.take(part, n // 2, axis=axis))


#: Lags of the Ljung-Box whiteness test (``diagnose.ljung_box``).
WHITENESS_LAGS = 10
#: Family-wise false-alarm rate of the whiteness tests of one fit (``diagnose.whiteness_rule``).
WHITENESS_ALPHA = 1e-3

#: Scale of the median absolute deviation to the standard deviation of a normal sample (1 / Phi^-1(3/4)).
MAD_TO_SD = 1.4826


def robust_centre_scale(values: Any) -> tuple[float, float]:
    """The median of ``values`` and their robust SD ``1.4826 * MAD`` (NaN left out; both NaN if none is left).

    A few outliers cannot hide themselves by inflating this spread, as they would a standard deviation.
    """
    x = np.asarray(values, dtype=float).ravel()
    x = x[~np.isnan(x)]
    if not x.size:
        return float("nan"), float("nan")
    centre = float(np.median(x))
    return centre, MAD_TO_SD * float(np.median(np.abs(x - centre)))


def robust_z(values: Any) -> tuple[np.ndarray, float, float]:
    """Robust z-scores ``(x - median) / (1.4826 * MAD)`` of ``values``, with the centre and scale used.

    NaN values stay NaN and are left out of the centre and scale. Where the MAD is 0 (most values
    alike) the scale is a tiny fraction of the centre instead, so a value off the common one still
    stands out, by far.
    """
    x = np.asarray(values, dtype=float)
    centre, scale = robust_centre_scale(x)
    scale = scale if scale > 0 else max(abs(centre) * 1e-12, 1e-300)
    return (x - centre) / scale, centre, scale


def next_power_of_two(n: int, minimum: int = 1) -> int:
    """The smallest power of two at or above ``n`` and ``minimum``: a batch size shared by many, so few compile."""
    return 1 << (max(int(n), int(minimum), 1) - 1).bit_length()


def noise_level(x: np.ndarray, axis: int = 0) -> Any:
    """Robust sensor-noise estimate (the samples' unit) from second differences (MAD), insensitive to slow signals.

    Samples lie along ``axis``: shape (N,) gives a float, more axes one level per series (the others).
    """
    if x.shape[axis] < 4:
        return 0.0 if x.ndim == 1 else np.zeros(np.delete(x.shape, axis))
    d2 = np.diff(x, 2, axis=axis)
    level = fast_median(np.abs(d2 - np.expand_dims(fast_median(d2, axis), axis)), axis) / 0.6745 / math.sqrt(6.0)
    return float(level) if x.ndim == 1 else level
