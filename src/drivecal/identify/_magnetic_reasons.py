"""Why a plan cannot see the magnetic saturation's coefficients, and which segment would show them.

The saturation law (``physics._magnetics``) bends each axis's flux with its own current (``sat_d``,
``sat_q``) and with the other axis's (``sat_dq``). What a plan must hold to show each, judged on the
nominal motor's predicted currents (the plan's structure, whatever the data's noise):

* ``sat_d``: d-axis current at two or more distinct levels. One level (each segment reaching about the
  same peak ``|i_d|``) fixes only the inductance's fall at that current as the law's assumed shape
  (its exponent) carries it there; one step cannot separate an inductance that falls with current
  from a constant one that fits its transient as well (R, Ld and a delay bend it too), nor say where
  the linear range ends. Levels apart show the fall itself.
* ``sat_q``: the same on the q axis.
* ``sat_dq``: d- and q-axis current at the same time: the cross term acts only where both flow (a
  locked d step alone and a locked q step alone never move it).

A coefficient the plan cannot see is dead (held at its prior, like alpha_R at one temperature), with
a reason that names the segment that would show it.
"""

from __future__ import annotations

import numpy as np

from ..model import Experiment, simulate_states
from ..physics import MAGNETIC, MotorParams

#: A segment whose peak current on an axis is below this fraction of the plan's largest on that axis
#: reaches no level there (a remnant, such as a free rotor's coupling into the other axis).
LEVEL_FLOOR = 0.1
#: Two segments' peaks are one level unless the smaller is below this fraction of the larger.
LEVEL_STEP = 0.8
#: A sample carries current on both axes when each exceeds this fraction of its axis's largest.
TOGETHER = 0.1

#: What would show each coefficient.
MAGNETIC_FIX = {
    "sat_d": "add locked d-axis steps at two or more levels up to the current limit (e.g. at 1/3, 2/3 and the "
             "full limit)",
    "sat_q": "add locked q-axis steps at two or more levels up to the current limit (e.g. at 1/3, 2/3 and the "
             "full limit)",
    "sat_dq": "add a combined d+q step (both axes energised together: v_d and v_q stepped at once, e.g. with "
              "each axis's current near half the limit)",
}


def current_levels(currents: np.ndarray, segment_start: np.ndarray) -> tuple[tuple[float, ...], ...]:
    """The distinct current levels (A) the plan reaches on d and on q, each largest first: ``(d_levels, q_levels)``.

    A segment's level on an axis is its peak ``|i|`` there; segments whose peaks lie within
    :data:`LEVEL_STEP` of a larger level's are that level, and peaks below :data:`LEVEL_FLOOR` of the
    axis's largest are none. An axis that carries no current has no level.
    """
    currents = np.abs(np.asarray(currents, dtype=float)[:, :2])
    segment = np.cumsum(np.asarray(segment_start, dtype=bool)) - 1
    segment = np.maximum(segment, 0)  # samples before a first flagged start belong to the first segment
    largest_both = float(currents.max()) if currents.size else 0.0
    out = []
    for axis in range(2):
        peaks = np.zeros(int(segment.max()) + 1 if segment.size else 0)
        np.maximum.at(peaks, segment, currents[:, axis])
        top = float(peaks.max()) if peaks.size else 0.0
        levels: list[float] = []
        if top > 1e-9 * largest_both and top > 0.0:
            for p in sorted(peaks[peaks >= LEVEL_FLOOR * top], reverse=True):
                if not levels or p < LEVEL_STEP * levels[-1]:
                    levels.append(float(p))
        out.append(tuple(levels))
    return tuple(out)


def _both_axes(currents: np.ndarray) -> bool:
    """Whether some sample carries d- and q-axis current together (each above :data:`TOGETHER` of its largest)."""
    a = np.abs(np.asarray(currents, dtype=float)[:, :2])
    top = a.max(axis=0) if a.size else np.zeros(2)
    if not np.all(top > 0):
        return False
    return bool(np.any((a[:, 0] > TOGETHER * top[0]) & (a[:, 1] > TOGETHER * top[1])))


def _self_reason(axis: str, levels: tuple[float, ...]) -> str | None:
    name = f"sat_{axis}"
    if not levels:
        return (f"no {axis}-axis current (i_{axis} stays at zero), so nothing shows how the {axis}-axis inductance "
                f"falls with current; {MAGNETIC_FIX[name]}")
    if len(levels) == 1:
        return (f"one {axis}-axis current level only (|i_{axis}| peaks at {levels[0]:.3g} A) and no {axis}-axis "
                f"current beyond it, so the plan cannot show where the linear range ends: a single step level "
                f"cannot separate a falling inductance from a constant one; {MAGNETIC_FIX[name]}")
    return None


def magnetic_reasons(experiment: Experiment, motor: MotorParams, names: tuple[str, ...],
                     currents: np.ndarray | None = None) -> dict[str, str]:
    """Per saturation coefficient among ``names`` that the plan cannot see, why and which segment would show it.

    Judged on ``motor``'s predicted currents on ``experiment`` (a model experiment: saturating where a
    coefficient is estimated), or on ``currents`` ((M, 2), A) where the caller has them; empty where
    ``names`` holds no coefficient or the plan shows them all.
    """
    wanted = [n for n in MAGNETIC if n in names]
    if not wanted:
        return {}
    if currents is None:
        currents = np.asarray(simulate_states(motor, experiment, keep=2))
    d_levels, q_levels = current_levels(currents, np.asarray(experiment.segment_start))
    reasons = {"sat_d": _self_reason("d", d_levels), "sat_q": _self_reason("q", q_levels), "sat_dq": None}
    if not _both_axes(currents):
        reasons["sat_dq"] = ("no sample with d- and q-axis current at the same time, so cross-saturation (each "
                             "axis's flux bent by the other's current) never acts; " + MAGNETIC_FIX["sat_dq"])
    return {n: reasons[n] for n in wanted if reasons[n]}
