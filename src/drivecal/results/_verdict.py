"""The verdict of one fit as a record: its status, the headline a report leads with, and the findings.

It is the result JSON's ``verdict`` section (``drivecal.diagnose.verdict`` computes it; ``drivecal.fit``
attaches it to the Calibration it returns).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from .._status import Status
from ._checks import _Check


@dataclasses.dataclass(frozen=True)
class Verdict:
    """How one calibration ended.

    Attributes:
        status: a :class:`Status` (its ``key`` is the JSON's word: calibrated, partial, mismatch, failed);
            a key is accepted too.
        headline: the sentence a report leads with, e.g. ``"partially calibrated: Ld, lambda_m not
            identifiable by this plan"``.
        details: every finding, most serious first.
    """

    status: Status
    headline: str
    details: tuple[str, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "status", Status(self.status))
        object.__setattr__(self, "details", tuple(self.details))

    @property
    def ok(self) -> bool:
        """Whether the estimates are usable: calibrated, or partially (the identifiable ones)."""
        return self.status.ok

    @property
    def exit_code(self) -> int:
        """The exit status ``drivecal fit`` reports for it (0 only for calibrated)."""
        return self.status.exit_code

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``verdict``: ``{"status": key, "headline": ..., "details": [...]}``."""
        return {"status": self.status.key, "headline": self.headline, "details": list(self.details)}

    @classmethod
    def from_dict(cls, d: Any, source: str = "result", field: str = "verdict") -> Verdict:
        """Read a result JSON's ``verdict``.

        Raises:
            DataError: not an object, a key missing, a status that is not a :class:`Status` key, or a
                headline or detail that is not text; one sentence naming ``source`` and ``field``.
        """
        if d is None:
            _Check(source).fail(field, "is null where a verdict is needed")
        _Check(source).verdict(d, field)
        return cls(Status(d["status"]), d["headline"], tuple(d["details"]))

    def lines(self) -> list[str]:
        """``[[Verdict]] <headline> (status: <key>)``, then one indented line per finding."""
        return [f"[[Verdict]] {self.headline} (status: {self.status.key})"] + [f"    {d}" for d in self.details]

    def __str__(self) -> str:
        return "\n".join(self.lines())

    def __repr__(self) -> str:
        """``Verdict(partial: 'partially calibrated: ...'; 1 detail)``."""
        n = len(self.details)
        return f"Verdict({self.status.key}: {self.headline!r}; {n} detail{'' if n == 1 else 's'})"
