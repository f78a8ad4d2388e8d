"""Errors drivecal raises for bad input: one actionable sentence each.

The CLI turns any :class:`DrivecalError` into that sentence on stderr and exit
status 2, with no traceback; :class:`ClusterLost` (a batch's dask cluster gone)
into its sentence and exit status 8.
"""

from __future__ import annotations


class DrivecalError(ValueError):
    """Bad input: the message names the file or field and says how to fix it."""


class PlanError(DrivecalError):
    """An infeasible or malformed bench plan."""


class DataError(DrivecalError):
    """Bench data that cannot be used as it is."""


class ClusterLost(DrivecalError):
    """The dask cluster of a batch could not be reached, or was lost (its scheduler, or every worker).

    Not bad input: ``drivecal batch`` ends with its own exit status (8), the sentence on stderr. The rows
    saved so far are kept for ``--resume``. ``lost``: what was lost (a phrase); ``fix``: what brings it
    back; ``saved``, ``total``: motors saved and in the run, where known.
    """

    def __init__(self, message: str, *, lost: str = "", fix: str = "", saved: int | None = None,
                 total: int | None = None):
        super().__init__(message)
        self.lost, self.fix, self.saved, self.total = lost or message, fix, saved, total
