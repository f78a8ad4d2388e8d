"""The numbers behind the fleet report's figures: what is drawn where, with no drawing.

A production engineer reads a fleet page for three things: where the population
sits against the nominal and the limits, whether it drifts along the line, and
which motors stand out. So each parameter gets (:func:`parameter_view`):

* the motors in line order: the serial in natural order (``SN2`` before
  ``SN10``) or a test-time column of the table;
* a **robust axis range**: the population's median ± (outlier threshold + 1)
  robust SDs (1.4826·MAD), no wider than the values themselves, then widened to
  the nominal and the tolerance limits unless they lie more than
  :data:`WIDEN_MAX` population widths away (they are then named at the edge).
  Values beyond the range are drawn at its edge and listed with their values:
  a few faulty motors no longer squash the healthy population to a sliver;
* a **rolling median and band** over :func:`rolling_window` motors (the band:
  ± :data:`BAND_K` robust SDs from the rolling interquartile range), and the
  **drift**: the rolling median's largest distance from the fleet median, as a
  fraction of the band's half-width. A drift-free line's rolling median wanders
  by about ``sqrt(pi/2) / (BAND_K sqrt(window))`` of it (one SD; :func:`drift_noise`),
  so the page calls a drift visible from :data:`DRIFT_FRACTION` or 5 such SDs,
  whichever is more (:func:`drift_threshold`: under 1 % of drift-free lines of
  30 to 3 000 motors are called drifting). Only full windows count (the line's
  first and last half-windows are drawn, not judged);
* engineering units (mΩ, mH, mWb, ...) chosen from the parameter's magnitude
  (:func:`engineering_unit`), and the nominal for the % axis.

The false-alarm rate of each of the batch's checks on healthy motors is here
too (:func:`false_alarm_rates`), computed from the thresholds the checks use.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import numpy as np
import pandas as pd

from .._parameters import UNITS
from .._stats import WHITENESS_ALPHA, WHITENESS_LAGS, robust_centre_scale
from .._status import Status

#: Half-width of the rolling band, in robust SDs (from the rolling interquartile range).
BAND_K = 2.0
#: The drift the page calls visible: the rolling median this fraction of the band's half-width from the fleet median,
#: and at least :data:`DRIFT_NOISE_SD` times the wander of a drift-free line's rolling median (short lines).
DRIFT_FRACTION = 0.5
DRIFT_NOISE_SD = 5.0
#: The axis covers the population's median ± (outlier threshold + this) robust SDs.
VIEW_MARGIN_SD = 1.0
#: Nominal and limits farther than this many population widths beyond the population are named, not drawn.
WIDEN_MAX = 3.0
#: The level of the batch's intervals (``<name>_ci_low`` .. ``<name>_ci_high``) the specification is judged with.
INTERVAL_LEVEL = 0.95
#: Table columns taken for a test time when present (``--trend-by`` offers them).
TIME_COLUMNS = ("test_time", "tested_at", "timestamp", "time", "date", "datetime")
#: Statuses whose estimates are usable (drawn and summarised).
USABLE = (Status.CALIBRATED.label, Status.PARTIAL.label)
#: Robust z-score beyond which a parameter marks a motor as an outlier (``drivecal batch --outlier-z``).
DEFAULT_OUTLIER_Z = 5.0

#: The standard normal's IQR, to turn an interquartile range into a robust SD.
_IQR_TO_SD = 1.0 / 1.3489795003921634

#: Each parameter's SI unit as the page writes it, and whether SI prefixes apply to it.
_SYMBOLS: dict[str, tuple[str, bool]] = {
    "R": ("Ω", True), "Ld": ("H", True), "Lq": ("H", True), "lambda_m": ("Wb", True),
    "J": ("kg·m²", False), "B": ("N·m·s", False), "T_coulomb": ("N·m", True), "T_load": ("N·m", True),
    "v_dead": ("V", True), "i_dead": ("A", True), "offset_d": ("A", True), "offset_q": ("A", True),
    "offset_a": ("A", True), "offset_b": ("A", True), "alpha_R": ("1/K", False), "delay": ("samples", False),
    "encoder_offset": ("rad", True),
}
_PREFIXES = {-9: "n", -6: "µ", -3: "m", 0: "", 3: "k"}


def outlier_z_of(table: pd.DataFrame) -> float:
    """The outlier threshold a results table was checked at: its ``outlier_z`` column, or
    :data:`DEFAULT_OUTLIER_Z` for a table written before the column was recorded."""
    recorded = table["outlier_z"].dropna() if "outlier_z" in table else ()
    return float(recorded.iloc[0]) if len(recorded) else DEFAULT_OUTLIER_Z


def natural_key(serial: Any) -> tuple:
    """Sort key of a serial in natural order: digit runs compare as numbers (``SN2`` < ``SN10``), text without case."""
    parts = re.split(r"(\d+)", str(serial))
    return tuple(int(p) if i % 2 else p.casefold() for i, p in enumerate(parts))


def natural_order(serials: Any) -> np.ndarray:
    """Indices that put ``serials`` in natural order (ties: as given)."""
    keys = [natural_key(s) for s in serials]
    return np.asarray(sorted(range(len(keys)), key=keys.__getitem__), dtype=int)


def time_columns(table: pd.DataFrame) -> list[str]:
    """The table's columns that can order its motors in time: datetimes, or a :data:`TIME_COLUMNS` name."""
    return [c for c in table.columns
            if pd.api.types.is_datetime64_any_dtype(table[c]) or str(c).lower() in TIME_COLUMNS]


def engineering_unit(name: str, reference: float) -> tuple[str, float]:
    """``(unit, factor)`` to show ``name`` with: e.g. ``("mΩ", 1e3)`` for R = 0.45 Ω (SI value x factor)."""
    symbol, prefixed = _SYMBOLS.get(name, (UNITS.get(name, ""), False))  # a parameter added later: its SI unit
    if not prefixed or not (math.isfinite(reference) and reference != 0):
        return symbol, 1.0
    exponent = int(min(max(3 * math.floor(math.log10(abs(reference)) / 3), -9), 3))
    return _PREFIXES[exponent] + symbol, 10.0 ** -exponent


def rolling_window(count: int) -> int:
    """Motors per rolling window: about a fifteenth of the line, odd, 11 to 151 (all of them below 11)."""
    if count < 11:
        return max(count, 1)
    return int(min(max(round(count / 15), 11), 151)) | 1


def drift_noise(window: int) -> float:
    """One SD of a drift-free line's rolling median, as a fraction of the band's half-width."""
    return math.sqrt(math.pi / 2) / (BAND_K * math.sqrt(max(window, 1)))


def drift_threshold(window: int) -> float:
    """The drift called visible at this window: :data:`DRIFT_FRACTION`, or :data:`DRIFT_NOISE_SD` times
    :func:`drift_noise` where that is more (a short line's rolling median wanders more)."""
    return max(DRIFT_FRACTION, DRIFT_NOISE_SD * drift_noise(window))


def rolling_band(values: np.ndarray, window: int) -> pd.DataFrame:
    """Rolling median, and the band ± :data:`BAND_K` robust SDs (rolling IQR), centred; columns median, low, high."""
    s = pd.Series(np.asarray(values, dtype=float))
    roll = s.rolling(window, center=True, min_periods=max(1, (window + 1) // 2))
    median, q1, q3 = roll.median(), roll.quantile(0.25), roll.quantile(0.75)
    half = BAND_K * (q3 - q1) * _IQR_TO_SD
    return pd.DataFrame({"median": median, "low": median - half, "high": median + half})


def drift_of(band: pd.DataFrame, centre: float, window: int = 1) -> float:
    """The rolling median's largest distance from ``centre``, in half-widths of the band, over the full windows
    (the first and last ``window // 2`` rows left out when anything is left; NaN without a band)."""
    edge = window // 2
    band = band.iloc[edge:len(band) - edge] if len(band) > 2 * edge else band
    half = float(np.nanmedian((band["high"] - band["median"]).to_numpy())) if len(band) else math.nan
    if not (math.isfinite(half) and half > 0):
        return math.nan
    return float(np.nanmax(np.abs(band["median"].to_numpy() - centre))) / half


def robust_view(values: np.ndarray, centre: float, scale: float, threshold: float,
                marks: dict[str, float]) -> tuple[tuple[float, float], dict[str, float]]:
    """The axis range of a parameter and the marks left off it (see the module's docstring).

    Args:
        values: the drawn values (finite, SI).
        centre, scale: their median and robust SD.
        threshold: the batch's outlier threshold (robust SDs).
        marks: ``{label: value}`` of lines to draw (nominal, limits).

    Returns:
        ``((low, high), off_scale)``: the range (padded 5 %), and the marks outside it.
    """
    v = np.asarray(values, dtype=float)
    lo, hi = (float(v.min()), float(v.max())) if v.size else (centre, centre)
    if scale > 0 and math.isfinite(scale):
        half = (threshold + VIEW_MARGIN_SD) * scale
        lo, hi = max(lo, centre - half), min(hi, centre + half)
    if not hi > lo:
        half = max(abs(centre) * 1e-3, 1e-12) if math.isfinite(centre) else 1.0
        lo, hi = (centre - half, centre + half) if math.isfinite(centre) else (-1.0, 1.0)
    width, off = hi - lo, {}
    for label, mark in marks.items():
        if not math.isfinite(mark):
            continue
        if lo - WIDEN_MAX * width <= mark <= hi + WIDEN_MAX * width:
            lo, hi = min(lo, mark), max(hi, mark)
        else:
            off[label] = mark
    pad = 0.05 * (hi - lo)
    return (lo - pad, hi + pad), off


@dataclasses.dataclass(frozen=True)
class ParameterView:
    """One parameter as the page draws it (values SI; ``unit``/``factor`` for display).

    Attributes:
        name, unit, factor: the parameter, its display unit and SI-to-unit factor.
        nominal: the motor file's value (None: none given); tolerance: (low, high) limits, either None.
        x: trend positions of the drawn motors, in line order (rank in natural serial order, or test time).
        serial, values, flagged: their serials, values and whether the batch flagged them in this parameter.
        centre, scale: the fleet median and robust SD of ``values``.
        view: the axis range; off_scale: nominal or limits outside it, by label.
        window: motors per rolling window; band: rolling median, low, high (rows as ``x``).
        drift: the rolling median's largest distance from ``centre`` in band half-widths.
    """

    name: str
    unit: str
    factor: float
    nominal: float | None
    tolerance: tuple[float | None, float | None]
    x: np.ndarray
    serial: np.ndarray
    values: np.ndarray
    flagged: np.ndarray
    centre: float
    scale: float
    view: tuple[float, float]
    off_scale: dict[str, float]
    window: int
    band: pd.DataFrame
    drift: float

    @property
    def above(self) -> np.ndarray:
        """Mask of values beyond the top of the axis (drawn at its edge)."""
        return self.values > self.view[1]

    @property
    def below(self) -> np.ndarray:
        """Mask of values beyond the bottom of the axis."""
        return self.values < self.view[0]

    @property
    def label(self) -> str:
        return f"{self.name} [{self.unit}]" if self.unit else self.name

    def percent(self, value: float) -> float:
        """``value`` (SI) as % of the nominal (NaN without one)."""
        return 100.0 * value / self.nominal if self.nominal else math.nan

    def marks(self) -> dict[str, float]:
        """The lines to draw: nominal and limits, by label (SI)."""
        out = {} if self.nominal is None else {"nominal": float(self.nominal)}
        for label, limit in zip(("lower limit", "upper limit"), self.tolerance):
            if limit is not None:
                out[label] = float(limit)
        return out


def line_positions(table: pd.DataFrame, trend_by: str = "serial") -> tuple[np.ndarray, str]:
    """Each row's position along the line and the axis label: the rank of its serial in natural order, or the
    ``trend_by`` column's values (datetimes or numbers; NaT/NaN rows are left off the trends)."""
    if trend_by == "serial":
        rank = np.empty(len(table), dtype=float)
        rank[natural_order(table["serial"].astype(str).to_numpy())] = np.arange(len(table))
        return rank, "motor, in serial order"
    column = table[trend_by]
    if pd.api.types.is_numeric_dtype(column) and not pd.api.types.is_bool_dtype(column):
        return column.to_numpy(dtype=float), trend_by
    return pd.to_datetime(column, errors="coerce", utc=True).dt.tz_localize(None).to_numpy(), trend_by


def parameter_view(table: pd.DataFrame, name: str, x: np.ndarray, threshold: float,
                   nominal: float | None = None, tolerance: tuple[float | None, float | None] | None = None
                   ) -> ParameterView | None:
    """The view of ``name`` over the usable, identified motors with a position ``x`` (None when there are none)."""
    status = table["status"].astype(str)
    ok = status.isin(USABLE).to_numpy() & np.isfinite(pd.to_numeric(table[name], errors="coerce").to_numpy(float))
    if f"{name}_identifiable" in table:
        ok &= table[f"{name}_identifiable"].fillna(False).astype(bool).to_numpy()
    ok &= ~pd.isna(x)
    if not ok.any():
        return None
    idx = np.flatnonzero(ok)
    order = idx[np.argsort(np.asarray(x)[idx], kind="stable")]
    values = table[name].to_numpy(dtype=float)[order]
    flagged = (table["outlier_params"].astype(str).str.contains(rf"\b{re.escape(name)}\b", regex=True).to_numpy()
               if "outlier_params" in table else np.zeros(len(table), bool))[order]
    centre, scale = robust_centre_scale(values)
    tol = tuple(tolerance) if tolerance is not None else (None, None)
    unit, factor = engineering_unit(name, nominal if nominal else centre)
    draft = ParameterView(name, unit, factor, nominal, tol, np.asarray(x)[order], table["serial"].astype(str)
                          .to_numpy()[order], values, flagged, centre, scale, (centre, centre), {}, 1,
                          pd.DataFrame(), math.nan)
    view, off = robust_view(values, centre, scale, threshold, draft.marks())
    window = rolling_window(len(values))
    band = rolling_band(values, window) if len(values) >= 3 else pd.DataFrame(columns=["median", "low", "high"])
    return dataclasses.replace(draft, view=view, off_scale=off, window=window, band=band,
                               drift=drift_of(band, centre, window))


def false_alarm_rates(threshold: float, outlier_parameters: int, toleranced: int) -> dict[str, dict[str, Any]]:
    """The rate at which each check of the batch flags a healthy motor, from the thresholds it runs at.

    Returns ``{check: {"rate": per-motor rate (an upper bound where said), "basis": how it follows}}`` for
    ``outlier`` (robust |z| > ``threshold`` in any of ``outlier_parameters``, a Gaussian population),
    ``mismatch`` (the residual whiteness test: family-wise ``WHITENESS_ALPHA``) and, with ``toleranced``
    parameters, ``spec`` (a motor on a limit judged with its :data:`INTERVAL_LEVEL` interval).
    """
    per_parameter = math.erfc(threshold / math.sqrt(2.0))
    k = max(int(outlier_parameters), 1)
    out = {
        "outlier": {"rate": -math.expm1(k * math.log1p(-per_parameter)),
                    "basis": (f"|robust z| > {threshold:g} in any of {k} parameters: {per_parameter:.2g} per "
                              f"parameter for a Gaussian spread (a heavier-tailed population raises it)")},
        "mismatch": {"rate": WHITENESS_ALPHA,
                     "basis": (f"Ljung-Box whiteness of the residuals ({WHITENESS_LAGS} lags, each segment and axis) "
                               f"at family-wise level {WHITENESS_ALPHA:g} (Bonferroni: at most this); such a motor "
                               "is 'not calibrated' against the specification")},
    }
    if toleranced:
        tail = (1.0 - INTERVAL_LEVEL) / 2.0
        every = -math.expm1(toleranced * math.log1p(-tail))
        out["spec"] = {"rate": tail,
                       "basis": (f"a motor exactly on a limit is failed (or an out-of-limit one passed) when its "
                                 f"{INTERVAL_LEVEL:.0%} interval misses on that side: at most {tail:.1%} per "
                                 f"toleranced parameter ({every:.1%} with all {toleranced} on their limits), far "
                                 "less for a motor inside; a straddling interval is 'inconclusive', never a false "
                                 "fail")}
    return out
