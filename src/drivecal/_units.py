"""Physical quantities in TOML files and tables: numbers with units read (``"3.2 mH"``) and printed (``3.2 mH``).

Every physical value is either a plain number in SI units or a string with a
unit, e.g. ``duration = "10 ms"``, ``v_d = "8 V"``, ``Ld = "3.2 mH"``; a unit of
the wrong kind is refused with a message naming the expected unit. The file
schemas built on it (strict keys, one-sentence errors) are ``_schema``'s. Base
layer: imports only ``errors`` and the standard library.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Any, NamedTuple

from .errors import DrivecalError

_PREFIXES = {"": 1.0, "k": 1e3, "M": 1e6, "m": 1e-3, "u": 1e-6, "µ": 1e-6, "μ": 1e-6, "n": 1e-9}
#: Base units by quantity; the unit written in a file must be one of these with a prefix.
_UNITS = {
    "time": ("s",),
    "frequency": ("Hz",),
    "voltage": ("V",),
    "current": ("A",),
    "resistance": ("ohm", "Ohm", "Ω"),
    "inductance": ("H",),
    "flux": ("Wb", "V*s", "Vs"),
    "inertia": ("kg*m^2", "kg m^2", "kgm^2"),
    "friction": ("N*m*s", "Nms", "N m s"),
    "speed": ("rad/s",),
    "torque": ("N*m", "Nm", "N m"),
    "temperature": ("degC", "°C", "C"),
    "temperature coefficient": ("1/K",),
    "rotor angle": ("rad",),
}
#: Units that are no prefix of a base unit, by quantity: their factor to SI.
_SCALED = {"rotor angle": {"deg": math.pi / 180.0, "°": math.pi / 180.0}}
_EXAMPLE = {"time": "10 ms", "frequency": "20 kHz", "voltage": "8 V", "current": "30 A", "resistance": "0.45 ohm",
            "inductance": "3.2 mH", "flux": "0.0533 Wb", "inertia": "1.2e-3 kg*m^2", "friction": "8e-5 N*m*s",
            "speed": "300 rad/s", "torque": "0.1 N*m", "temperature": "75 degC",
            "temperature coefficient": "3.93e-3 1/K", "rotor angle": "20 deg"}
_NUMBER_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


class _UnitError(ValueError):
    pass


def parse_quantity(value: Any, quantity: str) -> float:
    """A number (SI) or ``"<number> <prefix><unit>"`` string, converted to SI.

    Raises ``ValueError`` with a message that names the expected unit.
    """
    if isinstance(value, bool):
        raise _UnitError(f"expected a {quantity} such as '{_EXAMPLE[quantity]}', got {value!r}")
    if isinstance(value, (int, float)):
        return _finite(value, value, quantity)
    if not isinstance(value, str):
        raise _UnitError(f"expected a {quantity} such as '{_EXAMPLE[quantity]}', got {_short(value)}")
    match = _NUMBER_UNIT.match(value)
    if not match:
        raise _UnitError(f"{_short(value)} is not a number with a unit; write e.g. '{_EXAMPLE[quantity]}'")
    number, unit = float(match.group(1)), match.group(2)
    if unit == "":
        return _finite(number, value, quantity)
    if unit in _SCALED.get(quantity, {}):
        return _finite(number * _SCALED[quantity][unit], value, quantity)
    for base in _UNITS[quantity]:
        if unit.endswith(base) and unit[: -len(base)] in _PREFIXES:
            return _finite(number * _PREFIXES[unit[: -len(base)]], value, quantity)
    raise _UnitError(
        f"'{value}' has unit '{unit}' but a {quantity} in {_UNITS[quantity][0]} is expected; "
        f"write e.g. '{_EXAMPLE[quantity]}'"
    )


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters: a message stays one readable line."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _finite(number: float | int, value: Any, quantity: str) -> float:
    try:
        x = float(number)
    except OverflowError:
        x = math.inf
    if not math.isfinite(x):
        raise _UnitError(f"expected a finite {quantity} such as '{_EXAMPLE[quantity]}', got {_short(value)}")
    return x


def read_toml(path: str | Path) -> dict:
    """A TOML file's table; a missing file or bad syntax is one DrivecalError sentence."""
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise DrivecalError(f"{path}: no such file; check the path.") from None
    except tomllib.TOMLDecodeError as exc:
        raise DrivecalError(f"{path}: not valid TOML ({exc}); fix the syntax.") from None


#: Display units (what a person reads: mΩ, mH, mWb) of the SI units in tables; the JSON stays SI.
_DISPLAY = {"ohm": "Ω", "H": "H", "Wb": "Wb", "V": "V", "A": "A", "s": "s", "Hz": "Hz", "N*m": "N·m",
            "N*m*s": "N·m·s"}
#: Units shown as written, without a prefix (a prefix on kg·m², rad/s or a controller gain would mislead).
_PLAIN = {"kg*m^2": "kg·m²", "V/(A*s)": "V/(A·s)", "-": ""}
_DISPLAY_PREFIXES = ((1e9, "G"), (1e6, "M"), (1e3, "k"), (1.0, ""), (1e-3, "m"), (1e-6, "µ"), (1e-9, "n"))


def display_unit(reference: float, unit: str) -> tuple[float, str]:
    """The scale and the unit as shown for quantities of about ``reference`` (SI ``unit``).

    The SI prefix puts ``|reference|`` in [1, 1000): ``display_unit(0.0032, "H")`` is
    ``(1e-3, "mH")``. A table column (or a row of a parameter table) takes one
    reference, e.g. the estimate, so every number in it shares the prefix.
    Units without a prefix form (``-``, ``samples``, ``1/K``, ``kg*m^2``) keep
    scale 1 and are shown as written (``-`` as ``""``).
    """
    shown = _DISPLAY.get(unit)
    if shown is None:
        return 1.0, _PLAIN.get(unit, unit)
    ref = abs(float(reference))
    if ref == 0.0 or not math.isfinite(ref):
        return 1.0, shown
    for scale, prefix in _DISPLAY_PREFIXES:
        if ref >= scale * 0.9995:
            return scale, prefix + shown
    return scale, prefix + shown


def format_value(value: float, scale: float = 1.0, se: float | None = None) -> str:
    """The number ``value / scale`` alone (the unit is the column's), with the digits ``se`` supports.

    With a standard error (or another uncertainty to match, in the same SI
    unit), the digits go down to its second significant digit:
    ``format_value(0.0032003, 1e-3, 5.7e-7)`` is ``"3.20030"``, and an SE
    formatted against itself shows two significant digits
    (``format_value(5.7e-7, 1e-3, 5.7e-7)`` is ``"0.00057"``). Without one
    (or a zero or non-finite one), four significant digits. A non-finite value is ``"-"``.
    """
    value = float(value)
    if not math.isfinite(value):
        return "-"
    if se is None or not math.isfinite(float(se)) or float(se) <= 0.0:
        return f"{value / scale:.4g}"
    decimals = max(0, 1 - math.floor(math.log10(float(se) / scale)))
    return f"{value / scale:.{decimals}f}"


class EstimateCells(NamedTuple):
    """An estimate's cells in a table row, all in one engineering unit (see :func:`estimate_cells`)."""

    scale: float  #: SI per shown unit, for the row's other numbers (``format_value(prior, cells.scale)``)
    unit: str  #: the unit as shown, e.g. ``"mH"`` (``"-"`` for a plain number)
    estimate: str
    se: str  #: two significant digits; ``"-"`` without an SE
    ci: tuple[str, ...]  #: the interval's ends, to the estimate's digits


def estimate_cells(value: float, unit: str, se: float | None = None, ci: tuple = ()) -> EstimateCells:
    """An estimate, its SE and interval ends as a table row shows them (the fit table, ``print(cal)``, the HTML
    summary): one prefix for the row, chosen by the larger of the value and the SE, and every number to the
    SE's second significant digit. Without a usable SE (a parameter held at its prior): four significant digits."""
    usable = se is not None and math.isfinite(float(se)) and float(se) > 0.0
    se = float(se) if usable else None
    scale, shown = display_unit(max(abs(float(value)), se or 0.0), unit)
    return EstimateCells(scale, shown or "-", format_value(value, scale, se),
                         "-" if se is None else format_value(se, scale, se),
                         tuple("-" if x is None else format_value(x, scale, se) for x in ci))


def format_quantity(value: float, unit: str, se: float | None = None) -> str:
    """``value`` (SI ``unit``) for a person: an SI prefix that puts it in [1, 1000), digits matching ``se``.

    With a standard error, the value keeps the digits down to the SE's second
    significant digit and is followed by ``± se`` in the same prefix, e.g.
    ``format_quantity(0.0032003, "H", 5.7e-7)`` is ``"3.20030 ± 0.00057 mH"``;
    without one, four significant digits (``"3.2 mH"``). The prefix follows the
    larger of the value and the SE (``"0.0 ± 2.0 mA"``). Units without a
    prefix form (``-``, ``samples``, ``1/K``, ``degC``, ``rad``) are printed as given.

    Args:
        value: the quantity in SI units.
        unit: its SI unit as in :data:`drivecal.physics.UNITS`.
        se: its standard error (same unit; or another uncertainty to print after ``±``, e.g. a
            95 % half-width), or None.
    """
    value = float(value)
    if not math.isfinite(value):
        return f"{value} {unit}".strip()
    cells = estimate_cells(value, unit, se)
    suffix = "" if cells.unit == "-" else f" {cells.unit}"
    return f"{cells.estimate}{'' if cells.se == '-' else ' ± ' + cells.se}{suffix}"
