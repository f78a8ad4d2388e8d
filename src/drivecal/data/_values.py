"""The values of a bench table's columns: numbers where numbers belong, finite, and the clock in seconds.

What a reader or a caller hands over may hold anything a file format can: text,
booleans, complex numbers, lists, date-times. Here a column that should hold
numbers and does not is refused in one sentence naming the file, the column and
the fix (:func:`check_numbers`), and a time column ``t`` of a timestamp or
duration type is turned into seconds from its first sample (:func:`time_in_seconds`).
"""

from __future__ import annotations

import numbers
import re
from typing import Any

import numpy as np

from ..errors import DataError

#: Text that is a date or a time of day (a clock logged as text).
_DATE_TIME = re.compile(r"^(\d{4}-\d{1,2}-\d{1,2}|\d{1,2}:\d{2}:\d{2})")
#: Columns that may hold booleans (read as 0/1).
FLAG_COLUMNS = ("locked",)


def time_in_seconds(values: np.ndarray) -> np.ndarray:
    """A timestamp (``datetime64``) or duration (``timedelta64``) column as float64 seconds from its first
    sample that has a value (NaN where a sample has none); any other column unchanged.

    A bench logging ``t`` as a Parquet timestamp (e.g. exact 50 us steps) gives the same clock as one
    logging seconds: the checks and the fit only use time from each segment's start.
    """
    if values.dtype.kind not in "mM":
        return values
    valid = ~np.isnat(values)
    if not valid.any():
        return np.full(values.shape, np.nan)
    first = values[np.flatnonzero(valid)[0]]
    ns = (values - first).astype("timedelta64[ns]")
    out = ns.astype(np.int64).astype(float) / 1e9
    out[~valid] = np.nan
    return out


def _describe(value: Any) -> str | None:
    """What a non-number ``value`` is, as a few words with the value (None when it is a number or blank)."""
    import pandas as pd

    if value is None or isinstance(value, float) and np.isnan(value):
        return None
    if isinstance(value, (bool, np.bool_)):
        return f"booleans ({value})"
    if isinstance(value, (complex, np.complexfloating)):
        return f"complex numbers ({value})"
    if isinstance(value, (list, tuple, np.ndarray, pd.Series)):
        items = list(np.asarray(value, dtype=object).ravel()[:3])
        return f"lists ({items!r})"
    if isinstance(value, dict):
        return f"records ({str(value)[:40]})"
    if isinstance(value, (np.datetime64, np.timedelta64, pd.Timestamp, pd.Timedelta)) or hasattr(value, "isoformat"):
        return f"date-times ({value})"
    if isinstance(value, (str, bytes)):
        return None  # text: a number written as text, or the bad value the finiteness check names
    if isinstance(value, numbers.Number):
        return None
    return f"{type(value).__name__} values ({str(value)[:40]})"


def _not_numbers(col: str, raw: np.ndarray, source: str) -> str | None:
    """The sentence refusing column ``col`` when its type is not numbers (None when it may hold numbers)."""
    kind = raw.dtype.kind
    fix = "store the measured values as real numbers (float columns), one per row"
    if kind == "b":
        if col in FLAG_COLUMNS:
            return None
        return f"{source}: column '{col}' holds booleans (true/false), not numbers; {fix}."
    if kind == "c":
        imag = float(np.nanmax(np.abs(raw.imag))) if raw.size else 0.0
        return (f"{source}: column '{col}' holds complex numbers (imaginary part up to {imag:.3g}); a measured "
                f"{'current' if col.startswith('i_') else 'quantity'} is real: {fix}.")
    if kind in "mM":
        what = "durations" if kind == "m" else "date-times"
        return f"{source}: column '{col}' holds {what}, not numbers; {fix} (only 't' may be a timestamp)."
    if kind in "US":
        return f"{source}: column '{col}' holds text ('{raw[0]}' in data row 1), not numbers; {fix}."
    if kind == "O":
        for row, value in enumerate(raw[: min(raw.size, 64)]):
            what = _describe(value)
            if what is not None and (col not in FLAG_COLUMNS or not what.startswith("booleans")):
                return f"{source}: column '{col}' holds {what} in data row {row + 1}, not numbers; {fix}."
        return None
    if kind not in "fiu":
        return f"{source}: column '{col}' holds {raw.dtype} values, not numbers; {fix}."
    return None


def check_numbers(columns: dict, source: str, names: list[str]) -> None:
    """Every value of the columns ``names`` (those present) a finite number, else a DataError naming the
    column, what it holds instead (text, booleans, complex numbers, lists, date-times) or its first bad row."""
    for col in names:
        if col not in columns:
            continue
        raw = columns[col]
        if raw.dtype.kind in "fiu" and np.all(np.isfinite(raw)):
            continue  # the common case, without pd.to_numeric's per-column cost
        if raw.dtype.kind == "b" and col in FLAG_COLUMNS:
            continue
        refusal = _not_numbers(col, raw, source)
        if refusal is not None:
            raise DataError(refusal)
        values, bad = _as_numbers(raw)
        if not bad.any():
            first = raw[0]
            if isinstance(first, (str, bytes)):
                raise DataError(f"{source}: column '{col}' holds text ('{first}' in data row 1), not numbers; store "
                                "the measured values as real numbers (float columns), one per row.")
            continue
        rows = np.flatnonzero(~bad)
        stride = np.diff(rows)
        if rows.size >= 2 and stride.min() == stride.max() and stride[0] > 1:
            raise DataError(
                f"{source}: column '{col}' has a value only on every {stride[0]}th row: it was logged at a lower "
                f"sample rate than 't'; resample '{col}' onto the time base of 't'."
            )
        row = int(np.flatnonzero(bad)[0])
        value = raw[row]
        described = _describe(value)
        if described is not None and not described.startswith("booleans"):
            raise DataError(f"{source}: column '{col}' holds {described} in data row {row + 1}, not numbers; store "
                            "the measured values as real numbers (float columns), one per row.")
        if col == "t" and isinstance(value, str) and _DATE_TIME.match(value.strip()):
            raise DataError(f"{source}: column 't' holds date-times as text ('{value.strip()}' in data row {row + 1}), "
                            "not seconds; give t in seconds (or write it as a Parquet timestamp column).")
        what = "a missing value" if _blank(value) else f"'{str(value)[:40]}'"
        raise DataError(
            f"{source}: column '{col}' has {what} in data row {row + 1} ({int(bad.sum())} bad value(s) in all); "
            "every value must be a finite number: remove or repair those rows."
        )


def _blank(value: Any) -> bool:
    import pandas as pd

    try:
        return bool(pd.isna(value))
    except (TypeError, ValueError):
        return False


def _as_numbers(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``raw`` as float64 (NaN where a value is not a number) and where it is not a finite number."""
    if raw.dtype.kind in "fiub":
        values = raw.astype(float)
    else:
        import pandas as pd

        try:
            values = pd.to_numeric(raw, errors="coerce")
        except (TypeError, ValueError):
            values = np.full(raw.shape, np.nan)
        values = np.asarray(values)
        if values.dtype.kind not in "fiub":  # complex, or objects pandas left alone
            values = np.array([_number(v) for v in raw], dtype=float)
        values = values.astype(float)
    return values, ~np.isfinite(values)


def _number(value: Any) -> float:
    if isinstance(value, (numbers.Real, np.bool_)):
        return float(value)
    return float("nan")
