"""Pass/fail against the specification: each toleranced parameter judged with its 95 % interval.

A parameter **passes** when its whole interval lies within its limits, **fails** when the whole interval
lies outside them, and is **inconclusive** otherwise (the interval straddles a limit, or the plan did not
identify the parameter). A motor fails when any parameter fails, is inconclusive when none fails and any
is inconclusive, and passes when all pass; a calibration that did not succeed is not judged.

For an inconclusive parameter the advice says how many times the samples would decide, if the estimate
stays where it is: the interval's half-width shrinks as 1/sqrt(samples), and it decides once it is below
the distance from the estimate to the nearest limit. The same arithmetic, vectorised, judges a fleet's
results table (:func:`judge_arrays`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..data import Tolerance
from ..physics import UNITS
from .._status import Spec, Status

#: Per-parameter outcome codes of :func:`judge_arrays`.
PASS, FAIL, INCONCLUSIVE = 0, 1, 2
_OUTCOME = {PASS: "pass", FAIL: "fail", INCONCLUSIVE: "inconclusive"}


def judge_arrays(estimate: Any, ci_low: Any, ci_high: Any, identifiable: Any, tolerance: Tolerance
                 ) -> tuple[np.ndarray, np.ndarray]:
    """One parameter of many motors against ``tolerance``: outcome codes and the samples factor that decides.

    Args:
        estimate, ci_low, ci_high: (K,) estimates and their 95 % interval (SI units; NaN: not estimated).
        identifiable: (K,) whether the plan identified the parameter.
        tolerance: its limits (SI).

    Returns:
        ``(outcome, factor)``, each (K,): :data:`PASS`, :data:`FAIL` or :data:`INCONCLUSIVE`, and for
        inconclusive ones with an interval, how many times the samples would shrink the interval enough to
        decide if the estimate stayed put (``inf`` when it sits on a limit, NaN when not identified).
    """
    e, lo, hi = (np.asarray(a, dtype=float) for a in (estimate, ci_low, ci_high))
    known = np.asarray(identifiable, dtype=bool) & np.isfinite(e) & np.isfinite(lo) & np.isfinite(hi)
    low = -np.inf if tolerance.low is None else tolerance.low
    high = np.inf if tolerance.high is None else tolerance.high
    with np.errstate(invalid="ignore"):
        inside = (lo >= low) & (hi <= high)
        outside = (lo > high) | (hi < low)
        # The half-width that would decide: the estimate's distance to the limit its interval crosses.
        distance = np.where((e >= low) & (e <= high), np.minimum(e - low, high - e), np.maximum(e - high, low - e))
        half = 0.5 * (hi - lo)
        factor = np.where(distance > 0, (half / np.where(distance > 0, distance, 1.0)) ** 2, np.inf)
    outcome = np.where(known & inside, PASS, np.where(known & outside, FAIL, INCONCLUSIVE))
    factor = np.where(known, np.where(outcome == INCONCLUSIVE, factor, 1.0), np.nan)
    return outcome, factor


@dataclasses.dataclass(frozen=True)
class ParameterJudgement:
    """One parameter against its tolerance (SI units).

    Attributes:
        name: the parameter.
        outcome: "pass", "fail" or "inconclusive".
        estimate: its estimate; ci95: its 95 % interval ``(low, high)`` (NaN when not identified).
        tolerance: the limits and how the motor file wrote them.
        samples_factor: for an inconclusive one, the samples (as a multiple of this test's) that would
            decide if the estimate stayed put; NaN when the plan did not identify it, 1 otherwise.
    """

    name: str
    outcome: str
    estimate: float
    ci95: tuple[float, float]
    tolerance: Tolerance
    samples_factor: float

    def advice(self) -> str:
        """What would decide an inconclusive parameter, in one sentence ('' for pass or fail)."""
        unit = UNITS[self.name]
        if self.outcome != "inconclusive":
            return ""
        if not math.isfinite(self.samples_factor):
            if math.isnan(self.samples_factor):
                return (f"{self.name} was not identified by this plan: add it to 'estimate' and a segment that "
                        f"excites it (`drivecal plan` / `drivecal design` say which).")
            return (f"{self.name} = {self.estimate:.5g} {unit} sits on a limit ({self.tolerance.describe(unit)}): "
                    "no longer test decides it; judge it by a repeat test.")
        return (f"{self.name}: the 95 % interval [{self.ci95[0]:.5g}, {self.ci95[1]:.5g}] {unit} straddles a limit "
                f"({self.tolerance.describe(unit)}); about {self.samples_factor:.2g}x the samples (a longer test, "
                f"or the plan repeated {math.ceil(self.samples_factor)} times) would decide if the estimate stays at "
                f"{self.estimate:.5g} {unit}, or a plan with more excitation of {self.name} (`drivecal design` "
                "predicts its interval).")

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (``spec.parameters[i]``)."""
        return {"name": self.name, "outcome": self.outcome, "estimate": _num(self.estimate),
                "ci95": [_num(self.ci95[0]), _num(self.ci95[1])], "tolerance": self.tolerance.text,
                "low": self.tolerance.low, "high": self.tolerance.high, "unit": UNITS[self.name],
                "samples_factor": _num(self.samples_factor), "advice": self.advice() or None}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclasses.dataclass(frozen=True)
class SpecJudgement:
    """A motor against its specification.

    Attributes:
        status: the motor's :class:`drivecal.results.Spec`.
        parameters: one judgement per toleranced parameter (empty when not judged).
        reason: why it was not judged (not calibrated, invalid file), else ''.
    """

    status: Spec
    parameters: tuple[ParameterJudgement, ...] = ()
    reason: str = ""

    @property
    def failed(self) -> tuple[str, ...]:
        """The parameters out of specification."""
        return tuple(p.name for p in self.parameters if p.outcome == "fail")

    @property
    def headline(self) -> str:
        """One line: the status, and the failed or undecided parameters."""
        if self.status is Spec.FAIL:
            return "fail: out of specification: " + ", ".join(self.failed)
        if self.status is Spec.INCONCLUSIVE:
            return "inconclusive: " + ", ".join(p.name for p in self.parameters if p.outcome == "inconclusive")
        if self.status is Spec.PASS:
            return f"pass: {len(self.parameters)} parameters within their limits"
        return f"{self.status.label}: {self.reason}"

    def advice(self) -> list[str]:
        """A sentence per inconclusive parameter (what would decide it)."""
        return [p.advice() for p in self.parameters if p.outcome == "inconclusive"]

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``spec`` section."""
        return {"status": self.status.key, "headline": self.headline, "failed": list(self.failed),
                "parameters": [p.to_dict() for p in self.parameters], "advice": self.advice()}


def motor_outcome(outcomes: Any) -> Spec:
    """A motor's status from its parameters' outcome codes (fail beats inconclusive beats pass)."""
    outcomes = np.asarray(outcomes)
    if np.any(outcomes == FAIL):
        return Spec.FAIL
    return Spec.INCONCLUSIVE if np.any(outcomes == INCONCLUSIVE) else Spec.PASS


def judge_spec(names: tuple[str, ...], estimate: Any, ci95: Any, identifiable: Any,
               tolerance: dict[str, Tolerance], status: Status = Status.CALIBRATED) -> SpecJudgement:
    """A calibrated motor against ``tolerance`` (the motor file's ``[tolerance]``).

    Args:
        names: the calibration's parameter names; estimate (len(names),), ci95 (len(names), 2) and
            identifiable (len(names),) as :class:`drivecal.results.Calibration` holds them (SI units).
        tolerance: ``{name: Tolerance}``; a toleranced parameter the calibration did not estimate is
            inconclusive (it was not measured).
        status: the calibration's verdict: a calibration that did not succeed (model mismatch, not
            converged, invalid file) is not judged.
    """
    if status is Status.INVALID:
        return SpecJudgement(Spec.INVALID, reason=status.message)
    if not status.ok:
        return SpecJudgement(Spec.NOT_CALIBRATED, reason=f"the calibration's verdict is {status.label}")
    judged = []
    for name, tol in tolerance.items():
        if name in names:
            i = names.index(name)
            e, lo, hi, ok = float(estimate[i]), float(ci95[i][0]), float(ci95[i][1]), bool(identifiable[i])
        else:
            e, lo, hi, ok = math.nan, math.nan, math.nan, False
        outcome, factor = judge_arrays([e], [lo], [hi], [ok], tol)
        judged.append(ParameterJudgement(name, _OUTCOME[int(outcome[0])], e, (lo, hi), tol, float(factor[0])))
    return SpecJudgement(motor_outcome([{"pass": PASS, "fail": FAIL}.get(p.outcome, INCONCLUSIVE)
                                        for p in judged]), tuple(judged))
