"""What the selection decided about each candidate: the choice record, its notes and its statistics.

Shared by the forward search (``_select``) and the backward step (``_backward``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..diagnose import EFFECTS, MAGNETIC_EFFECTS
from ..physics import ESTIMABLE, MAGNETIC, MotorParams, flux_of_currents
from ..results import Calibration

#: Every candidate of the selection: the bench effects, then the terms of the saturating law.
CANDIDATES = {**EFFECTS, **MAGNETIC_EFFECTS}

#: A saturation term is kept only where, fitted, it changes the flux at the tested currents by at least this
#: fraction of the linear machine's flux swing there (2 %). Below it the term may be statistically clear (a
#: switching inverter's duty-dependent ripple at 20 mA noise shows as 0.7 % "saturation" of a linear motor)
#: but it is not the iron: the linear model's Ld, Lq are then the tested range's average, within that.
MATERIAL_SATURATION = 0.02


@dataclasses.dataclass(frozen=True)
class EffectChoice:
    """What the selection decided about one candidate: a bench effect or a term of the saturating law.

    Attributes:
        effect: a key of ``diagnose.EFFECTS`` (``delay``, ``dead_time``, ``offsets``) or of
            ``diagnose.MAGNETIC_EFFECTS`` (``saturation_d``, ``saturation_q``, ``cross_saturation``).
        included: the final fit estimates it.
        how: ``"selected"`` (by the tests), ``"requested"`` (named by the user),
            ``"not supported"`` (its tests fell short), ``"not identifiable"``
            (the plan cannot show it), ``"too small"`` (a saturation term below
            ``MATERIAL_SATURATION``), ``"masked"`` (a saturation term not fitted because a bench
            effect the fit leaves out explains more), ``"fixed"`` (the delay given with
            ``--delay``) or ``"not tested"`` (``--effects none``).
        test: the evidence: ``"likelihood ratio"``, ``"score"`` or ``""``.
        statistic: the test's statistic (-), NaN when untested.
        dof: its degrees of freedom.
        p_value: its p-value, NaN when untested.
        p_threshold: the level it was judged at.
        estimate: per parameter ``(value, standard error)`` in its unit: the fit's
            when included, else the one-step estimate from the final fit.
        note: one sentence for the report.
    """

    effect: str
    included: bool
    how: str
    test: str = ""
    statistic: float = math.nan
    dof: int = 0
    p_value: float = math.nan
    p_threshold: float = math.nan
    estimate: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (NaN as null)."""
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {"effect": self.effect, "included": self.included, "how": self.how, "test": self.test,
                "statistic": num(self.statistic), "dof": self.dof, "p_value": num(self.p_value),
                "p_threshold": num(self.p_threshold),
                "estimate": {n: {"value": num(v), "se": num(s)} for n, (v, s) in self.estimate.items()},
                "note": self.note}


def names_with(names: tuple[str, ...], extra: tuple[str, ...]) -> tuple[str, ...]:
    """``names`` and ``extra`` together, in ``physics.ESTIMABLE``'s order."""
    wanted = set(names) | set(extra)
    return tuple(n for n in ESTIMABLE if n in wanted)


def lr_statistic(before: Calibration, after: Calibration) -> float:
    """``m ln(RSS_before / RSS_after)``: the likelihood-ratio statistic of nested Gaussian fits (-)."""
    return float(before.num_residuals * math.log(float(before.rss) / float(after.rss)))


def fitted_estimate(cal: Calibration, params: tuple[str, ...]) -> dict[str, tuple[float, float]]:
    return {n: (float(cal.estimate[cal.names.index(n)]), float(cal.se[cal.names.index(n)]))
            for n in params if n in cal.fit_names}


def one_step(test: dict[str, Any]) -> dict[str, tuple[float, float]]:
    return {n: (v["estimate"], v["se"]) for n, v in test["one_step"].items()}


def saturation_size(motor: MotorParams, term: str, currents: np.ndarray) -> float:
    """How much saturation term ``term`` (``sat_d``, ``sat_q``, ``sat_dq``) alone changes the flux (fraction).

    The largest change of ``psi_d`` or ``psi_q`` over the measured currents (A, shape (M, 2); up to
    2000 of them), each divided by that axis's linear flux swing at the largest tested current
    (``Ld * max|i_d|``, ``Lq * max|i_q|``, each at least a tenth of the other axis's current).
    """
    c = np.asarray(currents, dtype=float).reshape(-1, 2)
    c = c[np.all(np.isfinite(c), axis=1)][:: max(1, len(c) // 2000)]
    if c.size == 0:
        return 0.0
    only = motor.replace(**{n: (getattr(motor, n) if n == term else 0.0) for n in MAGNETIC})
    psi_d, psi_q = (np.asarray(f) for f in flux_of_currents(c[:, 0], c[:, 1], only))
    peak = np.max(np.abs(c), axis=0)
    peak = np.maximum(peak, 0.1 * peak.max())
    if peak.max() <= 0.0:
        return 0.0
    change_d = np.max(np.abs(psi_d - float(motor.lambda_m) - float(motor.Ld) * c[:, 0])) / (float(motor.Ld) * peak[0])
    change_q = np.max(np.abs(psi_q - float(motor.Lq) * c[:, 1])) / (float(motor.Lq) * peak[1])
    return float(max(change_d, change_q))


def choice_note(effect: str, included: bool, how: str, ident: Any = None) -> str:
    """The report's sentence on ``effect`` decided ``how`` (``ident``: the identifiability that refused it)."""
    what = CANDIDATES[effect][2]
    if how == "requested":
        return f"{what}: fitted as requested"
    if how == "selected":
        return f"{what}: fitted, the data support it (likelihood-ratio test)"
    if how == "not identifiable":
        reasons = "; ".join(f"{n}: {r}" for n, r in (getattr(ident, "reasons", None) or {}).items())
        return f"{what}: suggested by the residuals, but this plan cannot estimate it" + (f" ({reasons})"
                                                                                          if reasons else "")
    if how == "not tested":
        return f"{what}: not tested (--effects none)" if not included else what
    if how == "too small":
        return f"{what}: below the {100 * MATERIAL_SATURATION:g} % of the flux that is modelled"
    return f"{what}: not supported by the data"
