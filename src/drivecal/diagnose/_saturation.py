"""Saturation check: does an inductance change with current?

When a run holds two or more locked steps on one axis at different current
levels, each step is fitted on its own (R and that axis's inductance). Iron
that saturates shows a lower inductance at the higher current; if two levels
disagree beyond their intervals, the single fitted value is an average of
different machines, and drivecal says so instead of averaging silently.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..data import BenchData
from ..physics import MotorParams

#: Two levels whose estimates differ by more than this many combined standard
#: errors disagree (3: a 0.3 % false-alarm rate per pair for a linear machine).
Z_LIMIT = 3.0
#: Levels closer than this ratio of peak currents are the same level.
MIN_LEVEL_RATIO = 1.25

_AXES = {"Ld": 0, "Lq": 1}


@dataclasses.dataclass(frozen=True)
class LevelEstimate:
    """One locked step fitted on its own.

    Attributes:
        parameter: ``"Ld"`` or ``"Lq"``.
        segment: the segment's name.
        current: peak |current| on that axis in the segment (A).
        estimate: the inductance fitted from this segment alone (H).
        se: its standard error (H).
    """

    parameter: str
    segment: str
    current: float
    estimate: float
    se: float


@dataclasses.dataclass(frozen=True)
class SaturationCheck:
    """Per-level inductances and what they say.

    Attributes:
        levels: every per-segment estimate, by parameter and current.
        saturating: parameters whose levels disagree beyond ``z_limit``.
        largest_z: per tested parameter, the largest disagreement of a higher
            level with the lowest one (combined SE, R's uncertainty included).
        findings: one plain sentence per tested parameter.
        z_limit: the disagreement threshold (combined standard errors).
    """

    levels: tuple[LevelEstimate, ...]
    saturating: tuple[str, ...]
    largest_z: dict[str, float]
    findings: tuple[str, ...]
    z_limit: float = Z_LIMIT

    @property
    def tested(self) -> tuple[str, ...]:
        return tuple(self.largest_z)

    def to_dict(self) -> dict[str, Any]:
        return {
            "levels": [dataclasses.asdict(x) for x in self.levels],
            "saturating": list(self.saturating),
            "largest_z": dict(self.largest_z),
            "findings": list(self.findings),
            "z_limit": self.z_limit,
        }


def _steps(bench: BenchData, parameter: str) -> list[tuple[int, float]]:
    """Locked segments that excite ``parameter``'s axis only: (index, peak |current| A)."""
    axis = _AXES[parameter]
    out = []
    for k, seg in enumerate(bench.segments):
        if seg.locked and np.any(seg.voltages[:, axis]) and not np.any(seg.voltages[:, 1 - axis]):
            out.append((k, float(np.max(np.abs(seg.currents[:, axis])))))
    return out


def check_saturation(bench: BenchData, prior: MotorParams, *, z_limit: float = Z_LIMIT,
                     modelled: bool = False) -> SaturationCheck:
    """Fit each locked single-axis step alone and compare the inductances across current levels.

    Args:
        bench: the recorded run.
        prior: nominal motor (start and prior of the per-step fits).
        z_limit: disagreement, in combined standard errors, that counts as a change.
        modelled: the calibration fitted a saturating law: a change is what it models (the finding says so),
            not an average to avoid.

    Returns:
        A :class:`SaturationCheck`; a parameter with fewer than two distinct
        current levels (peaks apart by at least 25 %) is not tested.
    """
    from ..fitting import fit

    levels, saturating, largest, findings = [], [], {}, []
    for parameter in _AXES:
        steps = _steps(bench, parameter)
        currents = [c for _, c in steps]
        if len(steps) < 2 or max(currents) < MIN_LEVEL_RATIO * max(min(currents), 1e-12):
            continue
        # R comes from the lowest level, where the iron is linear; the higher levels fit
        # only the inductance, so R cannot absorb the bend a saturating step shows. Their
        # intervals carry R's uncertainty through dL/dR (a second fit at a nudged R).
        steps.sort(key=lambda s: s[1])
        k0, current0 = steps[0]
        low = fit(dataclasses.replace(bench, segments=(bench.segments[k0],)), prior, names=("R", parameter))
        if not (low.converged and all(low.identifiable)):
            continue
        r_low, l_low = float(low.estimate[0]), float(low.estimate[1])
        var_r, var_l, cov_rl = low.covariance[0, 0], low.covariance[1, 1], low.covariance[0, 1]
        found = [LevelEstimate(parameter, bench.segments[k0].name, current0, l_low, math.sqrt(var_l))]
        zs = []
        for k, current in steps[1:]:
            single = dataclasses.replace(bench, segments=(bench.segments[k],))
            at = fit(single, low.motor, names=(parameter,))
            nudged = fit(single, low.motor.replace(R=r_low * (1 + 1e-4)), names=(parameter,))
            if not (at.converged and nudged.converged):
                continue
            l_k, se_k = float(at.estimate[0]), float(at.se[0])
            slope = (float(nudged.estimate[0]) - l_k) / (r_low * 1e-4)
            found.append(LevelEstimate(parameter, bench.segments[k].name, current, l_k,
                                       math.sqrt(se_k**2 + slope**2 * var_r)))
            # l_k - l_low with l_k = l_k(r_low): both depend on the low step's (R, L) estimate.
            var_diff = se_k**2 + slope**2 * var_r + var_l - 2.0 * slope * cov_rl
            zs.append(abs(l_k - l_low) / math.sqrt(var_diff))
        levels += found
        if not zs:
            continue
        z = max(zs)
        largest[parameter] = float(z)
        lo, hi = min(found, key=lambda x: x.current), max(found, key=lambda x: x.current)
        detail = (f"{lo.estimate * 1e3:.4g} mH at {lo.current:.3g} A vs {hi.estimate * 1e3:.4g} mH at "
                  f"{hi.current:.3g} A")
        if z > z_limit:
            saturating.append(parameter)
            findings.append(
                f"{parameter} changes with current ({detail}; levels up to {z:.1f} SE apart): the iron saturates, "
                + ("as the fitted saturating law models (the flux maps give the inductance at each current)."
                   if modelled else f"and one fitted {parameter} would average different machines; calibrate at "
                   "the operating current or fit the levels separately.")
            )
        else:
            findings.append(f"{parameter} is the same at every current level ({detail}; at most {z:.1f} SE apart).")
    return SaturationCheck(tuple(levels), tuple(saturating), largest, tuple(findings), z_limit)
