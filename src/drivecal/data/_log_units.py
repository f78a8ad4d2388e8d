"""The units a bench logs its channels in, and their conversion to drivecal's SI units.

A format file's ``[units]`` table names the unit each channel is logged in
(``i_d = "mA"``, ``w_m = "rpm"``); a file that carries units of its own (MDF4,
TDMS, HDF5 attributes) is checked against it. Every unit is a scale and an
offset onto the column's SI unit: ``si = scale * logged + offset``.
"""

from __future__ import annotations

import difflib
import math

import numpy as np

from ..errors import DataError

#: unit -> (quantity, scale, offset) onto the quantity's SI unit (A, V, s, rad/s, rad, degC, 1).
LOG_UNITS: dict[str, tuple[str, float, float]] = {
    "A": ("current", 1.0, 0.0), "mA": ("current", 1e-3, 0.0), "kA": ("current", 1e3, 0.0),
    "V": ("voltage", 1.0, 0.0), "mV": ("voltage", 1e-3, 0.0), "kV": ("voltage", 1e3, 0.0),
    "s": ("time", 1.0, 0.0), "ms": ("time", 1e-3, 0.0), "us": ("time", 1e-6, 0.0),
    "rad/s": ("speed", 1.0, 0.0), "rpm": ("speed", 2.0 * math.pi / 60.0, 0.0),
    "Hz": ("speed", 2.0 * math.pi, 0.0),  # mechanical revolutions per second
    "rad": ("angle", 1.0, 0.0), "deg": ("angle", math.pi / 180.0, 0.0),
    "degC": ("temperature", 1.0, 0.0), "K": ("temperature", 1.0, -273.15),
    "1": ("flag", 1.0, 0.0),
}
#: Other spellings of the units above, as files and people write them.
_ALIASES = {"µs": "us", "μs": "us", "1/min": "rpm", "min^-1": "rpm", "U/min": "rpm", "r/min": "rpm",
            "rev/s": "Hz", "°": "deg", "°C": "degC", "C": "degC", "Celsius": "degC", "rad/sec": "rad/s",
            "sec": "s", "-": "1", "": "1", "bool": "1"}
#: The quantity, SI unit and meaning of each drivecal column a format file can map.
COLUMN_QUANTITY: dict[str, str] = {
    "t": "time", "v_d": "voltage", "v_q": "voltage", "i_d": "current", "i_q": "current", "w_m": "speed",
    "theta_e": "angle", "theta_m": "angle", "temperature": "temperature", "locked": "flag",
    "i_a": "current", "i_b": "current", "i_c": "current", "v_a": "voltage", "v_b": "voltage", "v_c": "voltage",
}
SI_UNIT = {"time": "s", "voltage": "V", "current": "A", "speed": "rad/s", "angle": "rad", "temperature": "degC",
           "flag": "1"}
#: The drivecal columns a format file maps: the measured and applied quantities, and the text columns.
MAPPABLE = ("segment", "serial", *COLUMN_QUANTITY)


def canonical_unit(unit: str) -> str | None:
    """The unit's name in :data:`LOG_UNITS` (``"µs"`` -> ``"us"``), or None when it is not known."""
    text = str(unit).strip()
    text = _ALIASES.get(text, text)
    return text if text in LOG_UNITS else None


def check_unit(column: str, unit: str, where: str) -> str:
    """The canonical name of ``unit`` for ``column``; a DataError when it is unknown or of another quantity."""
    quantity = COLUMN_QUANTITY[column]
    known = canonical_unit(unit)
    choices = [u for u, (q, _, _) in LOG_UNITS.items() if q == quantity]
    if known is None:
        close = difflib.get_close_matches(str(unit), list(LOG_UNITS) + list(_ALIASES), n=2)
        hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
        raise DataError(f"{where}: unknown unit '{unit}' for '{column}'{hint}; write one of "
                        f"{', '.join(choices)}.")
    if LOG_UNITS[known][0] != quantity:
        raise DataError(f"{where}: unit '{unit}' for '{column}' is a {LOG_UNITS[known][0]}, but '{column}' is a "
                        f"{quantity}; write one of {', '.join(choices)}.")
    return known


def same_unit(a: str, b: str) -> bool:
    """Two known units that convert alike (``"rpm"`` and ``"1/min"``)."""
    ka, kb = canonical_unit(a), canonical_unit(b)
    return ka is not None and kb is not None and LOG_UNITS[ka] == LOG_UNITS[kb]


def to_si(values: np.ndarray, unit: str) -> np.ndarray:
    """``values`` logged in the known ``unit`` as float64 in the SI unit of its quantity (unchanged for SI)."""
    _, scale, offset = LOG_UNITS[canonical_unit(unit)]
    if scale == 1.0 and offset == 0.0:
        return values
    return np.asarray(values, dtype=float) * scale + offset
