"""Errors drivecal raises for bad input: one actionable sentence each.

The CLI turns any :class:`DrivecalError` into that sentence on stderr and exit
status 2, with no traceback.
"""

from __future__ import annotations


class DrivecalError(ValueError):
    """Bad input: the message names the file or field and says how to fix it."""


class PlanError(DrivecalError):
    """An infeasible or malformed bench plan."""


class DataError(DrivecalError):
    """Bench data that cannot be used as it is."""
