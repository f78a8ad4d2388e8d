"""Where the dead time eats the spin-up: its voltage raised by what the dead time takes from it.

A plan whose locked steps fit ``v_dead`` (the dead time is too large to leave out) is judged last on the
motor with its expected dead time. On a motor whose dead-time voltage is a large part of the spin-up's
(a 346 V drive at 40 kHz with 1 us: 13.8 V of a 31 V spin-up), the rotor then spins to a fraction of the
speed planned for lambda_m's back-EMF; the spin-up's voltage adds the loss back.
"""

from __future__ import annotations

from typing import Any, Callable

from ._assess import DesignReport, predict_segments
from ._saturation_plan import weakened
from ..physics import MotorParams, is_saturating
from ..plan import Plan

#: Where the dead time leaves the spin-up under this share of the speed planned without it, the spin-up's
#: voltage adds what the dead time takes.
SPIN_REACH = 0.9


def spin_through_dead_time(planned: DesignReport, final: DesignReport, levels: Any, judge: Callable,
                           dead_motor: MotorParams, current_limit: float) -> tuple[DesignReport, Any, tuple[str, ...]]:
    """The spin-up voltage raised by what the dead time takes from it, where that leaves the spin-up
    under :data:`SPIN_REACH` of the speed it was planned for without it (``final``: the plan judged on
    the motor with its dead time). The speed follows the voltage left after the loss, so each try adds
    the loss the last one showed. A try is not taken over a limit ``judge(levels, final=True)`` checks, nor
    where ``dead_motor`` (the motor with its expected dead time) would pass ``current_limit`` (A) with its
    inductances fallen (the saturation margin, ``_saturation_plan.weakened``) unless its law is given.

    ``levels``: the plan's voltages (``_autoplan._Levels``); returns the final report, the levels and a note."""
    def reach(report: DesignReport) -> float:
        return max(s.peak_speed for s, seg in zip(report.segments, report.plan.segments) if not seg.locked)

    target, v_spin = reach(planned), levels.v_spin
    first = reach(final) / target
    for _ in range(3):
        share = reach(final) / target
        if share >= SPIN_REACH:
            break
        candidate_levels = levels.scaled((1.0,) * len(levels.steps) + (2.0 - share,))
        candidate = judge(candidate_levels, final=True)
        if not candidate.ok or not _saturation_safe(candidate.plan, dead_motor, current_limit):
            break
        final, levels = candidate, candidate_levels
    if levels.v_spin == v_spin:
        return final, levels, ()
    return final, levels, (f"dead time: the spin-up's voltage is raised from {v_spin:.3g} V to {levels.v_spin:.3g} V "
                           f"by what the dead time takes from it (without, the rotor would spin to {first:.0%} of "
                           "its planned speed)",)


def _saturation_safe(plan: Plan, dead_motor: MotorParams, current_limit: float) -> bool:
    """Whether the free segments stay under ``current_limit`` (A) on ``dead_motor`` with its inductances fallen."""
    return is_saturating(dead_motor) or current_limit >= max(
        p.peak_current for m in weakened(dead_motor) for p in predict_segments(plan, m) if not p.locked)
