"""Plans that see the iron's saturation and stay under the current limit.

What a plan must hold to show the saturation law's coefficients (``physics._magnetics``;
``identify._magnetic_reasons`` says why each is hidden otherwise):

* ``sat_d`` / ``sat_q``: locked steps at several current levels on their axis. Auto-plan drives
  :data:`SATURATION_LEVELS` = 1/3, 2/3 and all of :data:`SATURATION_TOP_FRACTION` = 0.8 of the current
  limit (about 0.27, 0.53 and 0.8 of it). The top level goes as near the limit as the plan's own
  margin allows: saturation shows most at the largest current (the law's terms grow as ``|i|**S``), and
  a locked step's steady current is ``v/R`` whatever the iron does (saturation only shortens the
  way there), so its peak is known up to R: 0.8 leaves a resistance 10 % under its datasheet value
  (the margin auto-plan leaves everywhere) at 0.89 of the limit. The levels apart (each at most 1/2
  of the next, where ``identify`` counts a new level below 0.8) show the inductance's fall itself, not
  only its value at one current; the lowest keeps data near the small-signal range.
* the iron bridge of a PM-assisted motor (``sat_b``, ``sat_bp``, ``k_q``, ``psi_n``): it saturates
  asymmetrically in i_d (the magnet's flux it carries is pushed up or down), so the d levels get one
  negative step too, at the middle level (2/3 of the top: field-weakening current, well clear of
  demagnetising the magnet).
* ``sat_dq``: both axes energised together: locked steps with ``(+v, +v)`` and ``(+v, -v)`` on
  ``(d, q)`` (:data:`COMBINED_SIGNS`), each axis at ``1/sqrt(2)`` of the top level, so that ``|i_dq|``
  settles at the top level too. The cross term acts only where both axes carry current.

The per-unit coefficients carry their axis's inductance (``sat_q = a_qq * Lq * (Lq*i_ref)**T`` in
Hinkkanen's coefficients ``a_q0 = 1/Lq``, ``a_qq``, ...): any error of ``Lq`` moves ``sat_q`` along,
so on a machine that saturates from zero current (Hinkkanen's SyRM: ``T = 1``) their predicted
correlation exceeds ``identify``'s 0.99 whatever the plan, even where each is pinned to a few per
cent. :func:`law_verdict` then judges the plan in the law's own coefficients, where the data do
tell the terms apart (0.90 for the SyRM's auto-plan), and says so in the design report's notes.

**Margin for unknown saturation.** When the motor given is linear (only its small-signal Ld, Lq
known), the locked steps are safe as they are (their steady current ``v/R`` does not depend on L)
but the free spin-up's peak current does: it is held down by the inductance until the back-EMF has
built up. The spin-up is sized so that a motor whose Ld and Lq have fallen to
:data:`SATURATED_INDUCTANCE_FRACTION` = 50 % (and one half-way there, 75 %: the peak need not grow
monotonically as L falls) stays under the current limit: the incremental
inductance of interior-PM and PM-assisted synchronous reluctance machines typically falls to about
half of its small-signal value between rated and peak current (the q axis most), and taking the
fallen value at every current, not only at the limit, is the conservative side (on the seed motor's
plans the 50 % stand-in's spin-up peak lies above that of laws halving, or quartering, the secant
inductance at the limit). Pure reluctance machines fall further (Hinkkanen's 6.7-kW SyRM to under
20 % on q and 8 % on d at 32 A): give their law. With
the saturating law given, its own prediction sizes the plan and no margin is added.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ._bench_limits import LOCKED_TIME_CONSTANTS, MIN_SEGMENT_SAMPLES, VOLTAGE_FRACTION
from ..identify import COND_MAX, CORR_MAX, WEAK_RELATIVE_CI, Identifiability, magnetic_reasons, sensitivity_jacobian
from ..model import Experiment, model_experiment
from ..physics import BRIDGE, MAGNETIC, MotorParams, hinkkanen_law, is_saturating, search_scale
from ..plan import Plan, Segment

#: The steady currents of the locked steps on a saturating axis, as fractions of the top level.
SATURATION_LEVELS = (1.0 / 3.0, 2.0 / 3.0, 1.0)
#: The top level of the saturation steps as a fraction of the current limit (see the module docstring).
SATURATION_TOP_FRACTION = 0.8
#: The (d, q) signs of the combined steps that show the cross-saturation.
COMBINED_SIGNS = ((1.0, 1.0), (1.0, -1.0))
#: The fraction of their small-signal values Ld and Lq may fall to where the motor's law is not given.
SATURATED_INDUCTANCE_FRACTION = 0.5
#: The inductance a per-unit coefficient carries (its axis's; sat_dq: both).
_CARRIES = {"sat_d": ("Ld",), "sat_q": ("Lq",), "sat_dq": ("Ld", "Lq")}


@dataclasses.dataclass(frozen=True)
class LockedStep:
    """A locked constant-voltage step of an auto-plan: its name, voltages (V) and time constant (s)."""

    name: str
    v_d: float
    v_q: float
    tau: float

    def scaled(self, factor: float) -> LockedStep:
        return dataclasses.replace(self, v_d=self.v_d * factor, v_q=self.v_q * factor)


def saturation_requested(names: tuple[str, ...]) -> bool:
    """Whether any saturation coefficient (the iron bridge's among them) is among ``names``."""
    return any(n in MAGNETIC or n in BRIDGE for n in names)


def saturation_steps(names: tuple[str, ...], v_top: float, tau_d: float, tau_q: float) -> tuple[LockedStep, ...]:
    """The locked steps that show the requested coefficients, d levels first, then q, then the combined ones.

    ``v_top``: the top level's voltage (V, ``SATURATION_TOP_FRACTION * current_limit * R`` inside the
    voltage circle). Per axis "locked d-step low", "locked d-step" (the middle level) and "locked
    d-step high"; an axis whose coefficient is not requested gets the middle one only (its inductance
    still needs it); the combined steps last as long as the slower axis.
    """
    middle = SATURATION_LEVELS[len(SATURATION_LEVELS) // 2]
    suffix = {SATURATION_LEVELS[0]: " low", middle: "", SATURATION_LEVELS[-1]: " high"}
    steps = []
    for axis, tau, name in (("d", tau_d, "sat_d"), ("q", tau_q, "sat_q")):
        levels = SATURATION_LEVELS if name in names else (middle,)
        for level in levels:
            label = f"locked {axis}-step" + suffix[level]
            v = level * v_top
            steps.append(LockedStep(label, v if axis == "d" else 0.0, v if axis == "q" else 0.0, tau))
        if axis == "d" and set(BRIDGE) & set(names):  # the bridge saturates asymmetrically in i_d: both signs
            steps.append(LockedStep("locked d-step negative", -middle * v_top, 0.0, tau))
    if "sat_dq" in names:
        v = v_top / math.sqrt(2.0)
        for sd, sq in COMBINED_SIGNS:
            label = f"locked dq-step {'+' if sd > 0 else '-'}d{'+' if sq > 0 else '-'}q"
            steps.append(LockedStep(label, sd * v, sq * v, max(tau_d, tau_q)))
    return tuple(steps)


def weakened(motor: MotorParams) -> tuple[MotorParams, ...]:
    """Linear stand-ins for ``motor`` saturating: Ld and Lq fallen to :data:`SATURATED_INDUCTANCE_FRACTION`,
    and half-way there (a spin-up's peak current need not grow monotonically as the inductance falls)."""
    fractions = (0.5 * (1.0 + SATURATED_INDUCTANCE_FRACTION), SATURATED_INDUCTANCE_FRACTION)
    return tuple(motor.replace(Ld=f * float(motor.Ld), Lq=f * float(motor.Lq)) for f in fractions)


def margin_note(peak: float, current_limit: float, scaled: float | None) -> str:
    """The design report's note on the spin-up's margin for unknown saturation."""
    frac = SATURATED_INDUCTANCE_FRACTION
    what = (f"spin-up voltage scaled by {scaled:.3g} so that " if scaled is not None and scaled < 1.0 else "")
    return (f"saturation margin: the motor's law is not given, so the free segments are sized for Ld and Lq fallen "
            f"to {100 * frac:.0f} % of their small-signal values (typical of interior-PM and PM-assisted "
            f"reluctance machines near peak current; and to {50 * (1 + frac):.0f} %): {what}their predicted peak "
            "current would then be at most "
            f"{peak:.3g} A, under the current limit {current_limit:.3g} A; the locked steps settle at v/R "
            "whatever the inductance")


def law_note(motor: MotorParams) -> str:
    """The design report's note that the peaks are the saturating law's."""
    shown = MAGNETIC + tuple(n for n in BRIDGE if float(getattr(motor, n)) != 0.0)
    terms = ", ".join(f"{n} = {float(getattr(motor, n)):.4g}" for n in shown)
    return (f"peak currents predicted with the motor's saturating magnetic law ({terms} at i_ref = "
            f"{float(motor.i_ref):.4g} A)")


#: The fitted names in Hinkkanen's coefficients (``physics.hinkkanen_law``'s keys).
_LAW_KEYS = {"Ld": "a_d0", "Lq": "a_q0", "sat_d": "a_dd", "sat_q": "a_qq", "sat_dq": "a_dq"}


def _law_coefficients(values: jnp.ndarray, names: tuple[str, ...], motor: MotorParams) -> jnp.ndarray:
    """``names``' values with Ld, Lq and the per-unit coefficients replaced by Hinkkanen's ``1/Ld``, ``1/Lq``,
    ``a_dd``, ``a_qq``, ``a_dq`` (``physics.hinkkanen_law``; traceable in ``values``)."""
    law = hinkkanen_law(motor.replace(**dict(zip(names, values))))
    return jnp.stack([law[_LAW_KEYS[n]] if n in _LAW_KEYS else v for n, v in zip(names, values)])


def law_verdict(ident: Identifiability, experiment: Experiment, motor: MotorParams,
                names: tuple[str, ...]) -> tuple[Identifiability, str | None]:
    """``ident`` judged again in the law's own coefficients where only the per-unit coupling made it weak.

    Applies where every weak parameter is a saturation coefficient or an inductance it carries, the
    rank is full and nothing is dead or confounded: the predicted covariance is carried to
    Hinkkanen's coefficients (:func:`_law_coefficients`, linearised at ``motor``); if no pair
    correlates above ``CORR_MAX`` there and each interval is within ``WEAK_RELATIVE_CI`` of its value,
    those parameters are identified (the note says so, with both
    correlations). Otherwise ``ident`` unchanged and no note.
    """
    weak = set(ident.weak_params)
    carried = {m for n in MAGNETIC if n in weak for m in _CARRIES[n]} | {n for n in MAGNETIC if n in names}
    if (not weak or not weak <= carried or not weak & set(MAGNETIC) or ident.dead_params
            or ident.confounded_params or ident.rank < len(names) or ident.fit_names != tuple(names)):
        return ident, None
    for i, n in enumerate(names):  # each still pinned down: no interval wider than identify allows
        value = abs(float(getattr(motor, n)))
        if n in weak and not (value == 0.0 or ident.predicted_ci95[i] <= WEAK_RELATIVE_CI * value):
            return ident, None
    experiment = model_experiment(experiment, motor, names)
    scale = np.asarray(search_scale(motor, names, np)[1], dtype=float)
    jac = np.asarray(sensitivity_jacobian(motor, experiment, names)) * scale
    cov = np.linalg.inv(jac.T @ jac) * np.outer(scale, scale)  # absolute units (noise cancels in correlations)
    theta = jnp.asarray([float(getattr(motor, n)) for n in names])
    jl = np.asarray(jax.jacfwd(lambda th: _law_coefficients(th, names, motor))(theta))
    law = jl @ cov @ jl.T

    def worst(c: np.ndarray) -> tuple[float, str]:
        sd = np.sqrt(np.diag(c))
        r = np.abs(c / np.outer(sd, sd)) - np.eye(len(names))
        i, j = np.unravel_index(int(np.argmax(r)), r.shape)
        return float(r[i, j]), f"{names[i]}/{names[j]}"

    before, pair = worst(cov)
    after, _ = worst(law)
    if not after < CORR_MAX:
        return ident, None
    reasons = {k: v for k, v in ident.reasons.items() if k not in weak}
    judged = dataclasses.replace(ident, weak_params=(), identifiable=ident.condition_number <= COND_MAX,
                                 reasons=reasons)
    note = (f"{pair} correlate {before:.4f}: the per-unit saturation coefficients carry their axis's inductance "
            f"(sat_q = a_qq*Lq*(Lq*i_ref)**T), so an error of the inductance moves them along; in the law's own "
            f"coefficients (Hinkkanen's a_d0 = 1/Ld, a_q0 = 1/Lq, a_dd, a_qq, a_dq) the largest correlation is "
            f"{after:.4f}, under {CORR_MAX}: the plan identifies the law")
    return judged, note


def motor_note(motor: MotorParams) -> str | None:
    """The note saying which magnetic model predicted the peaks (None for a linear motor)."""
    return law_note(motor) if is_saturating(motor) else None


def with_saturation_steps(plan: Plan, motor: MotorParams, names: tuple[str, ...]) -> tuple[Plan, tuple[str, ...]]:
    """``plan`` with the locked steps that show the requested saturation coefficients it cannot see, and their names.

    What ``identify`` finds hidden (one current level on an axis, no d and q current together) gets
    the steps auto-plan would lay out for it (``_saturation_plan``: three levels on the axis up to
    :data:`SATURATION_TOP_FRACTION` of the plan's current limit, or the two combined d+q steps),
    :data:`LOCKED_TIME_CONSTANTS` electrical time constants long, inserted before the first free
    segment (the rotor stays clamped until then). ``plan`` unchanged (and no names) when nothing is
    hidden or no coefficient is requested.
    """
    names = tuple(names)
    hidden = magnetic_reasons(model_experiment(Experiment.from_plan(plan), motor, names), motor, names)
    if not hidden:
        return plan, ()
    r, fs = float(motor.R), plan.sample_rate
    v_top = min(SATURATION_TOP_FRACTION * plan.current_limit * r, VOLTAGE_FRACTION * plan.voltage_limit)
    wanted = tuple(hidden)
    axes = {"sat_d": "locked d-", "sat_q": "locked q-"}
    steps = [st for st in saturation_steps(wanted, v_top, float(motor.Ld) / r, float(motor.Lq) / r)
             if not any(st.name.startswith(prefix) and n not in wanted for n, prefix in axes.items())]
    taken = {seg.name for seg in plan.segments}
    added = []
    for st in steps:
        n = max(int(math.ceil(LOCKED_TIME_CONSTANTS * st.tau * fs)), MIN_SEGMENT_SAMPLES)
        name = st.name if st.name not in taken else f"{st.name} (saturation)"
        taken.add(name)
        added.append(Segment(name, n / fs, locked=True, v_d=st.v_d, v_q=st.v_q))
    at = next((i for i, seg in enumerate(plan.segments) if not seg.locked), len(plan.segments))
    while 0 < at < len(plan.segments) and plan.segments[at].continues:
        at -= 1  # not inside a chain of continuing segments
    segments = plan.segments[:at] + tuple(added) + plan.segments[at:]
    return dataclasses.replace(plan, segments=segments), tuple(seg.name for seg in added)
