"""The checks on one result document: each failure is one sentence naming the file and the field, with the fix.

:func:`drivecal.results.validate_fit` and the Verdict's reader use them; the message is a
:class:`drivecal.errors.DataError` (bad input: the CLI prints it and exits 2).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..errors import DataError
from .._status import Status

#: The fix for a result with a bad field.
_REFIT = "refit, or pass the result JSON as `drivecal fit` or `drivecal demo` wrote it"
#: Largest integer a count in a result may be (int64 and float64-exact).
_MAX_INT = 2**53


def _what(v: Any) -> str:
    """A JSON value's kind, in words, for messages."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "a boolean"
    if isinstance(v, (int, float)):
        return "NaN" if v != v else ("infinite" if isinstance(v, float) and not math.isfinite(v) else "a number")
    return {str: "a string", list: "a list", dict: "an object"}.get(type(v), type(v).__name__)


def _key(k: str) -> str:
    """A key from the file, as it can go into a one-line message."""
    return k if k.isidentifier() and len(k) <= 40 else repr(k[:40])


class _Check:
    """Checks on one result document; each failure is one sentence naming ``source`` and the field."""

    def __init__(self, source: str):
        self.source = source

    def fail(self, field: str, problem: str, fix: str = _REFIT) -> None:
        raise DataError(f"{self.source}: {field} {problem}; {fix}.")

    def obj(self, v: Any, field: str, *, null: bool = False) -> dict | None:
        if v is None and null:
            return None
        if not isinstance(v, dict):
            self.fail(field, f"is {_what(v)}, not an object")
        return v

    def lst(self, v: Any, field: str, *, length: int | None = None, null: bool = False) -> list | None:
        if v is None and null:
            return None
        if not isinstance(v, list):
            self.fail(field, f"is {_what(v)}, not a list")
        if length is not None and len(v) != length:
            self.fail(field, f"has {len(v)} entries where {length} are needed")
        return v

    def num(self, v: Any, field: str, *, null: bool = True, finite: bool = False) -> float:
        """A number (null and non-finite allowed unless told): returned as a float, NaN for null."""
        if v is None:
            if not null:
                self.fail(field, "is null where a number is needed")
            return math.nan
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            self.fail(field, f"is {_what(v)}, not a number")
        if isinstance(v, int) and abs(v) > 1e300:
            self.fail(field, "is too large a number")
        x = float(v)
        if finite and not math.isfinite(x):
            self.fail(field, f"is {_what(v)} where a finite number is needed")
        return x

    def nums(self, v: Any, field: str, *, length: int | None = None) -> list[float]:
        """A list of numbers or nulls."""
        items = self.lst(v, field, length=length)
        if all(type(x) is float or x is None for x in items):  # the common case, fast
            return [math.nan if x is None else x for x in items]
        return [self.num(x, f"{field}[{i}]") for i, x in enumerate(items)]

    def integer(self, v: Any, field: str, lo: int = 0, hi: int = _MAX_INT) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            if isinstance(v, float) and v.is_integer() and lo <= v <= hi:
                return int(v)
            self.fail(field, f"is {_what(v)}, not a whole number")
        if not lo <= v <= hi:
            self.fail(field, f"is {v if abs(v) < 1e15 else 'out of range'}; it must lie in [{lo}, {hi}]")
        return v

    def boolean(self, v: Any, field: str) -> bool:
        if not isinstance(v, bool):
            self.fail(field, f"is {_what(v)}, not true or false")
        return v

    def string(self, v: Any, field: str, *, null: bool = False) -> str | None:
        if v is None and null:
            return None
        if not isinstance(v, str):
            self.fail(field, f"is {_what(v)}, not a string")
        return v

    def strings(self, v: Any, field: str) -> list[str]:
        items = self.lst(v, field)
        for i, x in enumerate(items):
            self.string(x, f"{field}[{i}]")
        return items

    def number_map(self, v: Any, field: str) -> None:
        """null, or an object of numbers (or nulls)."""
        for k, x in (self.obj(v, field, null=True) or {}).items():
            self.num(x, f"{field}.{_key(k)}")

    def matrix(self, v: Any, field: str, n: int) -> np.ndarray:
        rows = self.lst(v, field, length=n)
        return np.array([self.nums(r, f"{field}[{i}]", length=n) for i, r in enumerate(rows)], dtype=float
                        ).reshape(n, n)

    def verdict(self, v: Any, field: str) -> dict | None:
        """null, or ``{status, headline, details}``: ``status`` a :class:`Status` key, the others text."""
        verdict = self.obj(v, field, null=True)
        if verdict is None:
            return None
        for k in ("status", "headline", "details"):
            if k not in verdict:
                self.fail(f"{field}.{k}", "is missing")
        status = self.string(verdict["status"], f"{field}.status")
        if status not in Status._value2member_map_:
            self.fail(f"{field}.status", f"is {_key(status)}, not a drivecal status "
                                         f"({', '.join(s.key for s in Status)})")
        self.string(verdict["headline"], f"{field}.headline")
        self.strings(verdict["details"], f"{field}.details")
        return verdict
