"""The bench's real limits and the margins every plan keeps from them (auto-plan and D-optimal design alike).

* **Sample rate.** A drive samples its currents once per PWM period, 8 to 40 kHz on real inverters.
  A plan runs at :data:`DEFAULT_SAMPLE_RATE` (10 kHz) unless the bench's rate is given; only a
  motor whose fastest electrical time constant would get fewer than
  :data:`SAMPLES_PER_TIME_CONSTANT` samples, or whose spin-up would turn more than
  :data:`PLAN_MAX_ELECTRICAL_STEP` electrical rad per sample, gets the next of
  :data:`SAMPLE_RATES`, up to 40 kHz. Durations come from time constants, not sample counts, so
  the plan's shape does not follow the rate.
* **Dead time.** During the dead time of each PWM period a phase follows its current's diode:
  it loses ``v_dead = V_dc * t_dead * f_s`` volts against its current (``physics.dead_time_error``),
  ``t_dead`` :data:`DEFAULT_DEAD_TIME` unless given. A locked step well above it
  (:data:`DEAD_TIME_MARGIN` times) reads R with the dead time a small correction; below that
  the dead-time voltage is part of what the step measures and ``v_dead`` must be fitted.
* **Clamp torque.** A locked q-axis current twists the rotor clamp with
  ``Te = 1.5 p (lambda_m i_q + (Ld - Lq) i_d i_q)``; a plan holds it under
  :data:`TORQUE_MARGIN` of the clamp's limit.
* **Current, voltage, speed, length.** Peaks under :data:`CURRENT_MARGIN` of the current limit,
  voltages inside :data:`VOLTAGE_FRACTION` of the circle ``v_dc/sqrt(3)``, free segments under
  :data:`SPEED_FRACTION` of the speed limit, every segment at least :data:`MIN_SEGMENT_SAMPLES`
  samples and a locked one at least :data:`MIN_LOCKED_TIME_CONSTANTS` electrical time constants
  of the axes it drives.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..errors import DrivecalError
from ..physics import MotorParams, dead_time_error, stable_dead_width
from ..plan import Plan, Segment

#: Steady current of a locked step, and the current scale of the spin-up, as a fraction of the current limit.
STEP_CURRENT_FRACTION = 0.5
#: Largest share of the voltage circle ``v_dc / sqrt(3)`` a segment commands.
VOLTAGE_FRACTION = 0.9
#: Largest predicted peak speed as a share of ``max_speed`` (and of the no-load speed).
SPEED_FRACTION = 0.8
#: Largest predicted peak current as a share of the current limit before a segment is scaled down.
CURRENT_MARGIN = 0.8
#: Largest clamp torque of a locked segment as a share of the clamp's limit (``max_torque``).
TORQUE_MARGIN = 0.8
#: Samples per fastest electrical time constant: RK4's local error ~ (dt/tau)^5 / 120 ~ 1e-7 of the current.
SAMPLES_PER_TIME_CONSTANT = 10
#: Fewest samples per electrical time constant accepted from a user-given sample rate.
MIN_SAMPLES_PER_TIME_CONSTANT = 3
#: Electrical angle per sample (rad) above which RK4 at one step per sample loses accuracy (design refuses it).
MAX_ELECTRICAL_STEP = 0.5
#: Electrical angle per sample (rad) in the spin-up: a fifth of what design accepts, RK4 phase error ~1e-7.
PLAN_MAX_ELECTRICAL_STEP = 0.2 * MAX_ELECTRICAL_STEP
#: Locked-step length in electrical time constants L/R: the transient (L) and a steady tail (R).
LOCKED_TIME_CONSTANTS = 6.0
#: Free spin-up length in spin-up times (see :class:`MotorTimes`).
SPIN_TIME_CONSTANTS = 4.0
#: Shortest segments a time budget may force (and D-optimal design may choose).
MIN_LOCKED_TIME_CONSTANTS = 3.0
MIN_SPIN_TIME_CONSTANTS = 1.5
#: Fewest samples per segment (noise averaging), unless a budget forbids.
MIN_SEGMENT_SAMPLES = 200
#: A real inverter's PWM (and current sampling) rate when the bench's is not given (Hz).
DEFAULT_SAMPLE_RATE = 10_000.0
#: The rates auto-plan steps up through when a motor needs more than the default (Hz): 10 to 40 kHz.
SAMPLE_RATES = (10_000.0, 16_000.0, 20_000.0, 25_000.0, 32_000.0, 40_000.0)
#: Largest PWM current ripple (half its peak-to-peak, ``v_dc / (8 L f_s)``) as a share of the current limit that
#: the default sample rate accepts: a drive's PWM rate keeps the ripple a small part of the current.
RIPPLE_FRACTION = 0.2
#: Dead time per switching edge when the bench's is not given (s): a typical IGBT inverter's.
DEFAULT_DEAD_TIME = 1e-6
#: A locked step's voltage must be this many times the expected dead-time voltage, or v_dead is fitted.
DEAD_TIME_MARGIN = 10.0
#: The spin-up's steady speed as a share of the speed limit (max_speed, or the no-load speed): high enough
#: for lambda_m's back-EMF, under SPEED_FRACTION with the ramp's overshoot.
SPIN_SPEED_FRACTION = 0.6
#: Longest spin-up ramp in samples: a bench log of a few seconds, and a fit (and its Jacobian) that stays
#: small. A rotor too heavy to reach its speed within it at the current a locked step draws spins slower.
MAX_RAMP_SAMPLES = 2**15


@dataclasses.dataclass(frozen=True)
class MotorTimes:
    """Characteristic times of a motor (s) and its electromechanical damping.

    Attributes:
        tau_d, tau_q: electrical time constants ``Ld/R``, ``Lq/R`` (s).
        tau_m: mechanical time constant ``J*R / (1.5 p^2 lambda_m^2)`` (s); infinite without a magnet.
        zeta: damping ratio ``sqrt(tau_m / tau_q) / 2`` of the spin-up (i_d ~ 0, B ~ 0).
        spin_time: ``max(tau_m, sqrt(tau_m * tau_q))`` (s): how long the speed takes to build up.
    """

    tau_d: float
    tau_q: float
    tau_m: float
    zeta: float
    spin_time: float

    @classmethod
    def of(cls, motor: MotorParams) -> MotorTimes:
        r, p, lam = float(motor.R), float(motor.pole_pairs), float(motor.lambda_m)
        tau_d, tau_q = float(motor.Ld) / r, float(motor.Lq) / r
        if lam == 0.0:  # no magnet (a synchronous reluctance motor): v_q alone turns nothing
            return cls(tau_d, tau_q, math.inf, math.inf, math.inf)
        tau_m = float(motor.J) * r / (1.5 * p**2 * lam**2)
        return cls(tau_d, tau_q, tau_m, 0.5 * math.sqrt(tau_m / tau_q), max(tau_m, math.sqrt(tau_m * tau_q)))

    @property
    def overshoot(self) -> float:
        """Peak over final speed of the open-loop step response (1 to 2, -)."""
        if self.zeta >= 1.0:
            return 1.0
        return 1.0 + math.exp(-math.pi * self.zeta / math.sqrt(1.0 - self.zeta**2))


def choose_sample_rate(tau: float, w_e_peak: float, given: float | None, ripple: float = 0.0) -> tuple[float, str]:
    """The plan's sample rate (Hz) and where it came from, in words.

    ``tau``: the fastest electrical time constant (s); ``w_e_peak``: the spin-up's highest electrical
    speed (rad/s); ``ripple``: the PWM current ripple times the rate over the current limit
    (``v_dc / (8 L) / current_limit``, Hz). A ``given`` rate is the bench's: kept when it gives at least
    :data:`MIN_SAMPLES_PER_TIME_CONSTANT` samples per ``tau``. Otherwise the first of
    :data:`SAMPLE_RATES` with :data:`SAMPLES_PER_TIME_CONSTANT` samples per ``tau``, at most
    :data:`PLAN_MAX_ELECTRICAL_STEP` rad per sample and a ripple at most :data:`RIPPLE_FRACTION` of the
    current limit, else the last one if it gives :data:`MIN_SAMPLES_PER_TIME_CONSTANT` samples per
    ``tau`` (the spin-up is then held slower).

    Raises:
        DrivecalError: the rate cannot resolve ``tau`` (one sentence, with the rate it needs).
    """
    if given is not None:
        if given * tau < MIN_SAMPLES_PER_TIME_CONSTANT:
            raise DrivecalError(
                f"sample_rate {given:g} Hz gives {given * tau:.2g} samples per electrical time constant "
                f"({tau:.3g} s); sample at least {MIN_SAMPLES_PER_TIME_CONSTANT / tau:.3g} Hz or leave it to auto-plan."
            )
        return float(given), "the bench's"
    for rate in SAMPLE_RATES:
        if (rate * tau >= SAMPLES_PER_TIME_CONSTANT and w_e_peak / rate <= PLAN_MAX_ELECTRICAL_STEP
                and ripple / rate <= RIPPLE_FRACTION):
            if rate == DEFAULT_SAMPLE_RATE:
                return rate, "default: a typical inverter's PWM rate"
            base = DEFAULT_SAMPLE_RATE
            why = ("the motor's electrical time constant" if base * tau < SAMPLES_PER_TIME_CONSTANT
                   else "the spin-up's electrical speed" if w_e_peak / base > PLAN_MAX_ELECTRICAL_STEP
                   else "the PWM current ripple")
            return rate, f"raised from the default {base / 1e3:g} kHz for {why}"
    top = SAMPLE_RATES[-1]
    if top * tau < MIN_SAMPLES_PER_TIME_CONSTANT:
        raise DrivecalError(
            f"the motor's electrical time constant {tau:.3g} s needs a sample rate of "
            f"{MIN_SAMPLES_PER_TIME_CONSTANT / tau:.3g} Hz, above the {top / 1e3:g} kHz of real inverters that "
            "auto-plan considers; give sample_rate explicitly if the bench can do it."
        )
    return top, f"the highest auto-plan considers ({top / 1e3:g} kHz)"


def expected_dead_voltage(motor: MotorParams, v_dc: float, dead_time: float, sample_rate: float) -> float:
    """The dead-time voltage a phase loses (V): the motor file's ``v_dead`` where it states one,
    else ``v_dc * dead_time * sample_rate``."""
    stated = float(motor.v_dead)
    return stated if stated > 0 else float(v_dc) * float(dead_time) * float(sample_rate)


def expected_dead_width(motor: MotorParams, v_dead: float, sample_rate: float) -> float:
    """The smooth sign's width (A) for the dead-time model of this motor: the motor's ``i_dead``, at least
    what one RK4 step per sample can integrate (``physics.stable_dead_width``).

    The PWM ripple's dead zone around zero current is computed from the period's voltages
    (``physics.switching_ripple``); what is left to the smooth sign (``physics.dead_time_error``) is the
    switches' capacitance and the sampled current's chatter about a switching edge, unless the motor's
    small inductance and the dead-time voltage call for more to keep the model stable.
    """
    return float(stable_dead_width(float(motor.i_dead), float(v_dead), float(motor.Ld), float(motor.Lq),
                                   1.0 / float(sample_rate)))


def dead_time_drop(v_dead: float, i_dead: float, i_d: float, i_q: float) -> tuple[float, float]:
    """The dq voltage (V) the dead time takes from a locked rotor (at electrical angle 0) carrying
    ``(i_d, i_q)`` (A): what a step must add to drive that current."""
    e_d, e_q = dead_time_error(i_d, i_q, 0.0, v_dead, max(float(i_dead), 1e-9))
    return -float(e_d), -float(e_q)


def ramp_speed(motor: MotorParams, w_spin: float, i_accel: float,
               sample_rate: float) -> tuple[float, float, tuple[str, ...]]:
    """The spin-up ramp's speed (rad/s, mechanical), its rise (s) and the note on it: ``w_spin`` unless
    accelerating the rotor to it at the torque of ``i_accel`` (A) takes longer than :data:`MAX_RAMP_SAMPLES`
    (a third of it left for the refinement on the prediction), else the speed it reaches in that time.

    With ``v_d = 0`` the rotation drives ``i_d ~ w_e * Lq/R * i_q``: the q current that accelerates the
    rotor is that much smaller, and the ramp ``hypot(1, w_e * tau_q)`` times longer.
    """
    p, lam = float(motor.pole_pairs), float(motor.lambda_m)
    a = float(motor.J) / (1.5 * p * lam * i_accel)  # s per rad/s: the rise without the coupling
    b = p * float(motor.Lq / motor.R)  # s: the coupling's growth with the mechanical speed
    longest = MAX_RAMP_SAMPLES / sample_rate / 1.5
    if a * w_spin * math.hypot(1.0, b * w_spin) <= longest:
        return w_spin, a * w_spin * math.hypot(1.0, b * w_spin), ()
    k = (longest / a) ** 2  # a w sqrt(1 + b^2 w^2) = longest, for w
    w = math.sqrt(k) if b == 0 else math.sqrt((math.sqrt(1.0 + 4.0 * b * b * k) - 1.0) / (2.0 * b * b))
    note = (f"the spin-up ramps to {w:.3g} rad/s, not {w_spin:.3g} rad/s: at half a locked step's current the "
            f"rotor (J = {float(motor.J):.3g} kg*m^2) would need {a * w_spin * math.hypot(1.0, b * w_spin):.3g} s to "
            f"get there, over the {MAX_RAMP_SAMPLES} samples a spin-up may last; lambda_m's interval says whether "
            "its back-EMF suffices (raise the current limit for a faster ramp).")
    return w, longest, (note,)


def clamp_current(motor: MotorParams, max_torque: float | None) -> float:
    """Largest locked q current (A, i_d = 0) whose torque stays under :data:`TORQUE_MARGIN` of ``max_torque``."""
    kt = 1.5 * float(motor.pole_pairs) * float(motor.lambda_m)
    if max_torque is None or kt == 0.0:
        return math.inf
    return TORQUE_MARGIN * float(max_torque) / kt


def speed_limit(plan: Plan, motor: MotorParams) -> float:
    """Highest mechanical speed (rad/s) a free segment may reach: ``max_speed``, the no-load
    speed ``v_dc/sqrt(3) / (p * lambda_m)`` and the RK4 bound of ``design`` (rad per sample)."""
    p, lam = float(motor.pole_pairs), float(motor.lambda_m)
    limits = [plan.voltage_limit / (p * lam) if lam else math.inf, MAX_ELECTRICAL_STEP * plan.sample_rate / p]
    if plan.max_speed is not None:
        limits.append(float(plan.max_speed))
    return min(limits)


def margin_problems(report: Any, motor: MotorParams) -> tuple[str, ...]:
    """Where a judged plan (a :class:`~drivecal.design.DesignReport`) leaves the margins auto-plan keeps, one
    sentence each: a predicted peak current over :data:`CURRENT_MARGIN` of the limit, a voltage outside
    :data:`VOLTAGE_FRACTION` of the circle, a free segment over :data:`SPEED_FRACTION` of
    :func:`speed_limit`, a clamp torque over :data:`TORQUE_MARGIN` of ``max_torque``, a segment shorter
    than :func:`min_durations` (to the sample)."""
    plan, out = report.plan, []
    tol = 1e-6
    w_lim = SPEED_FRACTION * speed_limit(plan, motor)
    for seg, pred, least in zip(plan.segments, report.segments, min_durations(plan, motor)):
        where = f"segment '{seg.name}'"
        if seg.num_samples(plan.sample_rate) + 1e-9 < math.floor(least * plan.sample_rate + 1e-9):
            out.append(f"{where} lasts {seg.duration:.4g} s, under its least {least:.4g} s")
        volts = float(np.max(np.hypot(*_volts(seg, plan.sample_rate))))
        if volts > VOLTAGE_FRACTION * plan.voltage_limit * (1 + tol):
            out.append(f"{where} commands {volts:.4g} V, over {VOLTAGE_FRACTION:g} of the voltage circle")
        if pred.peak_current > CURRENT_MARGIN * plan.current_limit * (1 + tol):
            out.append(f"{where} peaks at {pred.peak_current:.4g} A, over {CURRENT_MARGIN:g} of the current limit")
        if not seg.locked and pred.peak_speed > w_lim * (1 + tol):
            out.append(f"{where} reaches {pred.peak_speed:.4g} rad/s, over {SPEED_FRACTION:g} of the speed limit")
        torque_limit = math.inf if plan.max_torque is None else TORQUE_MARGIN * plan.max_torque
        if seg.locked and pred.peak_torque > torque_limit * (1 + tol):
            out.append(f"{where} puts {pred.peak_torque:.4g} N*m on the clamp, over {TORQUE_MARGIN:g} of max_torque")
    return tuple(out)


def min_durations(plan: Plan, motor: MotorParams) -> np.ndarray:
    """Shortest duration (s) each segment may have: :data:`MIN_SEGMENT_SAMPLES` samples, and a locked one
    :data:`MIN_LOCKED_TIME_CONSTANTS` electrical time constants of the axes it drives (a free one
    :data:`MIN_SPIN_TIME_CONSTANTS` spin-up times, unless it continues another)."""
    times = MotorTimes.of(motor)
    out = []
    for seg in plan.segments:
        least = MIN_SEGMENT_SAMPLES / plan.sample_rate
        if seg.locked:
            taus = [tau for axis, tau in (("v_d", times.tau_d), ("v_q", times.tau_q)) if np.any(getattr(seg, axis))]
            least = max([least] + [MIN_LOCKED_TIME_CONSTANTS * tau for tau in taus])
        elif not seg.continues and math.isfinite(times.spin_time):
            least = max(least, MIN_SPIN_TIME_CONSTANTS * times.spin_time)
        out.append(least)
    return np.asarray(out)


@dataclasses.dataclass(frozen=True)
class BenchLimits:
    """What an auto-plan was sized for and how it keeps its margins.

    Attributes:
        sample_rate_source: where the sample rate came from, in words.
        dead_time: dead time per switching edge assumed (s).
        v_dead: expected dead-time voltage per phase (V).
        i_dead: the smooth sign's width of its transition (A) (:func:`expected_dead_width`).
        v_dead_fitted: the locked steps are under :data:`DEAD_TIME_MARGIN` times ``v_dead``, so the
            plan carries what identifies it (a second d-step current, steps that add the dead-time
            drop) and ``v_dead`` must be fitted.
        speed_limit: the highest speed a free segment may reach (rad/s): ``max_speed`` or the no-load
            speed the voltage allows, whichever is lower.
        max_torque: the rotor clamp's limit (N*m), or None where not given.
        names: the parameters the plan was judged for (``v_dead`` among them when fitted).
    """

    sample_rate_source: str
    dead_time: float
    v_dead: float
    i_dead: float
    v_dead_fitted: bool
    speed_limit: float
    max_torque: float | None
    names: tuple[str, ...]

    def dead_time_ratio(self, plan: Plan) -> float:
        """Smallest locked step's ``|v_dq|`` over ``v_dead`` (inf without dead time or locked steps)."""
        volts = [float(np.max(np.hypot(*_volts(seg, plan.sample_rate)))) for seg in plan.segments if seg.locked]
        volts = [v for v in volts if v > 0]
        return min(volts) / self.v_dead if volts and self.v_dead > 0 else math.inf

    def dead_time_notes(self, plan: Plan) -> tuple[str, ...]:
        """The sentence on the dead time where the plan's locked steps are under :data:`DEAD_TIME_MARGIN`
        times ``v_dead`` (none where they are above it)."""
        ratio = self.dead_time_ratio(plan)
        if not math.isfinite(ratio) or ratio >= DEAD_TIME_MARGIN:
            return ()
        origin = (f"v_dc {plan.v_dc:g} V x dead time {self.dead_time * 1e6:g} us x {plan.sample_rate:g} Hz"
                  if self.dead_time else "the motor file's v_dead")
        head = (f"the expected dead-time voltage is {self.v_dead:.3g} V ({origin}) and the smallest locked step only "
                f"{ratio:.2g} times it (under {DEAD_TIME_MARGIN:g})")
        if self.v_dead_fitted:
            return (f"{head}: v_dead must be fitted (add v_dead to the motor file's estimate, with v_dead = "
                    f"\"{self.v_dead:.3g} V\" as its prior and i_dead = \"{self.i_dead:.3g} A\" as its transition's "
                    "width); the locked steps add its drop to reach their currents, and a second "
                    "d-step current tells it from R.",)
        return (f"{head}: R reads the dead time too; this plan (with saturation or mechanical parameters) does not "
                "lay out what tells them apart.",)

    def to_dict(self, report: Any) -> dict[str, Any]:
        """JSON (SI): the limits, the dead-time margin and the checks, per segment."""
        ratio = self.dead_time_ratio(report.plan)
        return {
            "sample_rate": report.plan.sample_rate, "sample_rate_source": self.sample_rate_source,
            "dead_time": self.dead_time, "v_dead": self.v_dead, "i_dead": self.i_dead,
            "dead_time_ratio": ratio if math.isfinite(ratio) else None, "dead_time_margin": DEAD_TIME_MARGIN,
            "v_dead_fitted": self.v_dead_fitted, "speed_limit": self.speed_limit,
            "max_torque": self.max_torque, "names": list(self.names),
            "margins": {"current": CURRENT_MARGIN, "voltage": VOLTAGE_FRACTION, "speed": SPEED_FRACTION,
                        "torque": TORQUE_MARGIN, "min_segment_samples": MIN_SEGMENT_SAMPLES},
        }


def _volts(seg: Segment, sample_rate: float) -> tuple[np.ndarray, np.ndarray]:
    v = seg.voltages(sample_rate)
    return v[:, 0], v[:, 1]
