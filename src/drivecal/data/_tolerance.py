"""Tolerances of a motor file's ``[tolerance]`` table: the specification a production line gates a unit on.

Each key names an estimable parameter; its value is written in one of these forms (the nominal value
is the motor file's)::

    [tolerance]
    R = "5 %"                       # two-sided, relative to the nominal: 0.95 R .. 1.05 R
    Ld = "0.2 mH"                   # two-sided, absolute: Ld - 0.2 mH .. Ld + 0.2 mH
    lambda_m = "-3 %"               # one-sided: at least 0.97 lambda_m, no upper limit
    Lq = "+10 %"                    # one-sided: at most 1.1 Lq, no lower limit
    J = ["-5 %", "+20 %"]           # asymmetric: 0.95 J .. 1.2 J
    B = { min = "5e-5 N*m*s", max = "1.2e-4 N*m*s" }   # absolute limits (either may be left out)

``"±5 %"`` and ``"+-5 %"`` are the two-sided form spelt out. :class:`Tolerance` keeps the limits in SI
units; judging an estimate against them (with its interval) is :func:`drivecal.results.judge_spec`.
"""

from __future__ import annotations

import math
import re
from typing import Any, NamedTuple

from ..errors import DrivecalError
from .._parameters import ESTIMABLE, UNITS
from .._units import parse_quantity

#: The quantity (units table of ``_units``) of each parameter a tolerance may name; None: a plain number.
_QUANTITY: dict[str, str | None] = {
    "R": "resistance", "Ld": "inductance", "Lq": "inductance", "lambda_m": "flux", "J": "inertia",
    "B": "friction", "T_coulomb": "torque", "T_load": "torque", "v_dead": "voltage", "i_dead": "current",
    "offset_d": "current", "offset_q": "current", "offset_a": "current", "offset_b": "current",
    "alpha_R": "temperature coefficient", "delay": None, "encoder_offset": "rotor angle",
}
_SIGNED = re.compile(r"^\s*(±|\+-|\+/-|\+|-)?\s*(.*?)\s*$")
_FORMS = ("'5 %' (two-sided), '-5 %' or '+5 %' (one-sided), an absolute width such as '0.02 ohm', "
          "['-3 %', '+5 %'], or { min = ..., max = ... }")


class Tolerance(NamedTuple):
    """The limits a parameter must lie within, SI units (its unit in :data:`drivecal.physics.UNITS`).

    Attributes:
        low: lower limit, or None (no lower limit: one-sided).
        high: upper limit, or None (no upper limit).
        text: the tolerance as the motor file wrote it, for tables and messages.
    """

    low: float | None
    high: float | None
    text: str

    def describe(self, unit: str) -> str:
        """The limits in words, e.g. ``'0.4275 .. 0.4725 ohm'`` or ``'>= 0.0517 Wb'``."""
        if self.low is not None and self.high is not None:
            return f"{self.low:.5g} .. {self.high:.5g} {unit}"
        return f">= {self.low:.5g} {unit}" if self.low is not None else f"<= {self.high:.5g} {unit}"


def _width(text: str, name: str, nominal: float, source: str) -> float:
    """A tolerance's width in SI: ``'5 %'`` of the nominal's magnitude, or an absolute quantity."""
    body = text.strip()
    if body.endswith("%"):
        try:
            fraction = float(body[:-1]) / 100.0
        except ValueError:
            fraction = math.nan
        if nominal == 0:
            raise DrivecalError(f"{source}: tolerance '{name}' = {text!r} is relative but the nominal {name} is 0; "
                                f"give an absolute width with a unit ({UNITS[name]}).")
        width = fraction * abs(nominal)
    else:
        quantity = _QUANTITY[name]
        try:
            width = float(body) if quantity is None else parse_quantity(body, quantity)
        except ValueError as exc:
            raise DrivecalError(f"{source}: tolerance '{name}' = {text!r}: {exc}.") from None
    if not (math.isfinite(width) and width > 0):
        raise DrivecalError(f"{source}: tolerance '{name}' = {text!r} is not a positive width; write {_FORMS}.")
    return width


def _signed(text: Any, name: str, nominal: float, source: str) -> tuple[str, float]:
    """``(sign, width)`` of one tolerance string: sign '±' (two-sided), '+' (upper) or '-' (lower)."""
    if not isinstance(text, str):
        raise DrivecalError(f"{source}: tolerance '{name}' = {text!r} is not understood; write {_FORMS}.")
    sign, body = _SIGNED.match(text).groups()
    return ("±" if sign in (None, "±", "+-", "+/-") else sign), _width(body, name, nominal, source)


def _limit(value: Any, name: str, source: str, key: str) -> float:
    quantity = _QUANTITY[name]
    try:
        return float(value) if quantity is None else parse_quantity(value, quantity)
    except (TypeError, ValueError) as exc:
        raise DrivecalError(f"{source}: tolerance '{name}.{key}' = {value!r}: {exc}; give the {key}imum "
                            f"value of {name} in {UNITS[name]}.") from None


def tolerance_of(name: str, value: Any, nominal: float, source: str = "motor") -> Tolerance:
    """The :class:`Tolerance` of parameter ``name`` written as ``value`` in a motor file (forms above).

    ``nominal`` (SI) is the motor file's value of the parameter. Anything else is refused with one
    sentence naming the file, the key and the forms.
    """
    if name not in _QUANTITY or name not in ESTIMABLE:
        raise DrivecalError(f"{source}: [tolerance] names '{name}', which drivecal does not estimate; "
                            f"choose from {', '.join(n for n in ESTIMABLE if n in _QUANTITY)}.")
    if isinstance(value, dict):
        unknown = sorted(set(value) - {"min", "max"})
        if unknown or not value:
            raise DrivecalError(f"{source}: tolerance '{name}' has keys {unknown or 'none'}; give min and/or max.")
        low = _limit(value["min"], name, source, "min") if "min" in value else None
        high = _limit(value["max"], name, source, "max") if "max" in value else None
        if low is not None and high is not None and not low < high:
            raise DrivecalError(f"{source}: tolerance '{name}': min ({low:g}) must be below max ({high:g}).")
        text = ", ".join(f"{k} {value[k]}" for k in ("min", "max") if k in value)
        return Tolerance(low, high, text)
    if isinstance(value, list):
        if len(value) != 2:
            raise DrivecalError(f"{source}: tolerance '{name}' = {value!r} must list two widths, the lower one "
                                "signed '-' and the upper one signed '+', e.g. ['-3 %', '+5 %'].")
        (s_low, w_low), (s_high, w_high) = (_signed(v, name, nominal, source) for v in value)
        if (s_low, s_high) != ("-", "+"):
            raise DrivecalError(f"{source}: tolerance '{name}' = {value!r}: write the lower width with '-' first "
                                "and the upper one with '+' second, e.g. ['-3 %', '+5 %'].")
        return Tolerance(nominal - w_low, nominal + w_high, f"{value[0]} / {value[1]}")
    sign, width = _signed(value, name, nominal, source)
    low = nominal - width if sign in ("±", "-") else None
    high = nominal + width if sign in ("±", "+") else None
    return Tolerance(low, high, str(value))


def tolerances_of(table: Any, nominal: dict[str, float], source: str = "motor") -> dict[str, Tolerance]:
    """Every tolerance of a motor file's ``[tolerance]`` table, in drivecal's parameter order."""
    if not isinstance(table, dict):
        raise DrivecalError(f"{source}: 'tolerance' must be a table such as [tolerance] R = \"5 %\".")
    found = {name: tolerance_of(name, value, nominal.get(name, 0.0), source) for name, value in table.items()}
    return {name: found[name] for name in ESTIMABLE if name in found}
