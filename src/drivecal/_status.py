"""How a calibration ended: the one status vocabulary of drivecal.

The verdict, the result JSON, the CLI's exit status and the fleet table all
speak it. Each status has a key (the result JSON's ``verdict.status``), a label
(the fleet table's ``status`` column and the headline), an actionable message
and the exit status a command reports for it.
"""

from __future__ import annotations

import enum


class _Vocabulary(enum.Enum):
    """A status word with its key (the JSON's), label (tables), exit code (the CLI's) and actionable message."""

    def __new__(cls, key: str, label: str, exit_code: int, message: str):
        obj = object.__new__(cls)
        obj._value_ = key
        obj.label = label
        obj.exit_code = exit_code
        obj.message = message
        return obj

    @property
    def key(self) -> str:
        """The result JSON's word for it."""
        return self.value

    def __str__(self) -> str:
        return self.label


class Status(_Vocabulary):
    """How one motor's calibration ended, most serious last.

    ``Status("partial")`` looks a status up by its key; :meth:`from_label` by its label.
    """

    #: Every requested parameter fitted, the residuals are what the sensor noise explains.
    CALIBRATED = ("calibrated", "calibrated", 0,
                  "every requested parameter is calibrated; the intervals are honest at their nominal rate")
    #: The fit converged but the plan could not identify some parameters.
    PARTIAL = ("partial", "partially calibrated", 3,
               "some parameters are not identifiable by this plan: they are held at the prior and not calibrated; "
               "add the segment the identifiability report names (e.g. a free spin-up for lambda_m) and run again")
    #: The model does not explain the data to the noise level.
    MISMATCH = ("mismatch", "model mismatch", 4,
                "the model does not explain the data to the noise level: the intervals are not to be trusted; "
                "model the cause the verdict names (delay, dead time, offsets) and fit again")
    #: The solver did not converge.
    NOT_CONVERGED = ("failed", "not converged", 5,
                     "the fit did not converge: check the prior (motor file) against the datasheet and the data "
                     "against the plan")
    #: The input could not be read or failed a check.
    INVALID = ("invalid", "invalid file", 2,
               "the bench file was refused: the reason names the field and the fix")

    @property
    def ok(self) -> bool:
        """Whether its estimates are usable (calibrated, or partially: the identifiable ones)."""
        return self in (Status.CALIBRATED, Status.PARTIAL)

    @classmethod
    def from_label(cls, label: str) -> Status:
        """The status whose fleet-table label is ``label``."""
        for status in cls:
            if status.label == label:
                return status
        raise ValueError(f"{label!r} is not a drivecal status label")


class Spec(_Vocabulary):
    """How one motor compares with its specification (the motor file's ``[tolerance]``), judged with
    the 95 % intervals: the production line's pass/fail. Keys, labels, exit codes and messages as
    :class:`Status`. "not calibrated" exits with the verdict's own code (:attr:`Status.exit_code`).
    """

    #: Every toleranced parameter's whole 95 % interval lies within its limits.
    PASS = ("pass", "pass", 0, "every toleranced parameter lies within its limits, its whole 95 % interval included")
    #: Some parameter's whole 95 % interval lies outside its limits.
    FAIL = ("fail", "fail", 6, "out of specification: the 95 % interval of the named parameters lies outside "
                               "their limits")
    #: Some interval straddles a limit (or a toleranced parameter was not identified), none lies outside.
    INCONCLUSIVE = ("inconclusive", "inconclusive", 7,
                    "the data cannot decide: an interval straddles a limit; the advice says how many more samples "
                    "or which plan change would decide")
    #: The calibration itself did not succeed (not converged, or model mismatch): nothing to judge.
    NOT_CALIBRATED = ("not_calibrated", "not calibrated", 1,
                      "not judged: the calibration did not succeed (see its verdict); calibrate it again")
    #: The bench file was refused.
    INVALID = ("invalid", "invalid file", 2, "not judged: the bench file was refused (see the reason)")



# optimistix reports how a solve ended as an equinox enumeration item; drivecal keeps it as a plain integer
# (it crosses vmap, numpy and the result JSON). equinox has no public integer or index -> message for its items,
# so these two functions are the only code that reads its internals.


def solver_code(result) -> object:
    """The integer code (an array under ``jit``/``vmap``) of an ``optimistix.RESULTS`` item."""
    return result._value


def solver_message(code: int) -> str:
    """The message optimistix gives for result ``code`` ('' for success)."""
    import optimistix as optx

    return optx.RESULTS._index_to_message[int(code)]
