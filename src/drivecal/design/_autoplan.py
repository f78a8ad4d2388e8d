"""Auto-plan: a feasible, identifiable bench plan scaled to the motor at hand.

From the datasheet motor and the bench's limits (DC-link voltage, current
limit, speed limit, time budget) it builds the standard three segments —
locked d-step (R, Ld), locked q-step (Lq), free spin-up (lambda_m) — with

* **amplitudes** from the current limit and R: each step drives a steady
  current of :data:`STEP_CURRENT_FRACTION` of the limit (``v = i * R``), never
  more than :data:`VOLTAGE_FRACTION` of the voltage circle ``v_dc / sqrt(3)``;
  the margins leave room for a datasheet that is 10 % off;
* **sample rate** from the fastest electrical time constant ``min(Ld, Lq) / R``
  (at least :data:`SAMPLES_PER_TIME_CONSTANT` samples per time constant, and at
  most :data:`PLAN_MAX_ELECTRICAL_STEP` electrical radians per sample in the
  spin-up): drivecal's forward model takes one RK4 step per sample, whose
  error then stays orders of magnitude below any sensor noise;
* **durations** from the time constants: :data:`LOCKED_TIME_CONSTANTS` ``L/R``
  per locked step, :data:`SPIN_TIME_CONSTANTS` spin-up times for the free
  segment (the mechanical time constant ``tm = J*R / (1.5 p^2 lambda_m^2)``, or
  ``sqrt(tm * Lq/R)``, a quarter period of the electromechanical oscillation,
  when that is longer), each at least :data:`MIN_SEGMENT_SAMPLES` samples;
* a **spin-up voltage** whose predicted peak speed stays under
  :data:`SPEED_FRACTION` of ``max_speed`` and of the no-load speed the voltage
  allows (the open-loop step response overshoots by the electromechanical
  damping, accounted for).

The total sample count is rounded up to a power of two, lengthening every
segment alike, so that plans of different
motors share one compiled fit; a binding time budget shortens the segments
instead, down to :data:`MIN_LOCKED_TIME_CONSTANTS` and
:data:`MIN_SPIN_TIME_CONSTANTS`.

When mechanical parameters (J, B, T_coulomb, T_load) are requested, the
spin-up runs on to a steady speed and the mechanical test continues it: a
low-speed run (and a reversed one for T_load) and a short-circuit braking,
sized in ``_mechanical``.

When saturation coefficients (sat_d, sat_q, sat_dq) are requested, the locked steps become
those ``_saturation_plan`` lays out: steps at three current levels per saturating axis, up to 0.8 of
the current limit, and combined d+q steps for the cross-saturation. A motor without a magnet
(``lambda_m = 0``, a synchronous reluctance machine) gets no free spin-up (v_q alone makes no torque
there, and there is no back-EMF to show); it can then estimate neither lambda_m nor the mechanics.

The plan is then judged by :func:`drivecal.design.assess_design` on the
nominal motor, for the requested parameters (with its saturating law where it has one); a segment
whose predicted peak current or speed breaks a limit is scaled down and the plan judged again. When
the motor is linear (its saturation unknown), the free segments are then held to a current a motor
whose inductances have fallen to half would keep under the limit (``_saturation_plan``; stated in
the report's notes). It binds where the inductance holds the spin-up's current down (slow electrical,
fast mechanical time constants, a spin-up boosted past a locked step's voltage); on the seed motor's
plans it does not bind. When no feasible, identifiable plan
exists, :class:`~drivecal.errors.DrivecalError` says why in one sentence.
"""

from __future__ import annotations

import dataclasses
import math

from ._assess import MAX_ELECTRICAL_STEP as _DESIGN_MAX_STEP
from ._assess import DesignReport, assess_design, predict_segments
from ._mechanical import SETTLE_SPIN_TIMES, friction_samples, mechanical_requested, mechanical_segments, run_voltages
from ._saturation_plan import (SATURATION_TOP_FRACTION, LockedStep, margin_note, saturation_requested,
                               saturation_steps, weakened)
from .._stats import next_power_of_two
from ..errors import DrivecalError
from ..identify import magnetic_reasons
from ..model import Experiment, model_experiment
from ..physics import ESTIMABLE, ESTIMATED, MotorParams, is_saturating
from ..plan import Plan, Segment

#: Steady current of a locked step, and the current scale of the spin-up, as a fraction of the current limit.
STEP_CURRENT_FRACTION = 0.5
#: Largest share of the voltage circle ``v_dc / sqrt(3)`` a segment commands.
VOLTAGE_FRACTION = 0.9
#: Largest predicted peak speed as a share of ``max_speed`` (and of the no-load speed).
SPEED_FRACTION = 0.8
#: Largest predicted peak current as a share of the current limit before a segment is scaled down.
CURRENT_MARGIN = 0.8
#: Samples per fastest electrical time constant: RK4's local error ~ (dt/tau)^5 / 120 ~ 1e-7 of the current.
SAMPLES_PER_TIME_CONSTANT = 10
#: Electrical angle per sample (rad) in the spin-up: a fifth of what design accepts, RK4 phase error ~1e-7.
PLAN_MAX_ELECTRICAL_STEP = 0.2 * _DESIGN_MAX_STEP
#: Locked-step length in electrical time constants L/R: the transient (L) and a steady tail (R).
LOCKED_TIME_CONSTANTS = 6.0
#: Free spin-up length in spin-up times (see the module docstring).
SPIN_TIME_CONSTANTS = 4.0
#: Shortest segments a time budget may force.
MIN_LOCKED_TIME_CONSTANTS = 3.0
MIN_SPIN_TIME_CONSTANTS = 1.5
#: Fewest samples per segment (noise averaging), unless a budget forbids.
MIN_SEGMENT_SAMPLES = 200
#: Bench sample rates considered (Hz).
MIN_SAMPLE_RATE = 1_000.0
MAX_SAMPLE_RATE = 200_000.0
#: Fewest samples per electrical time constant accepted from a user-given sample rate.
MIN_SAMPLES_PER_TIME_CONSTANT = 3
#: Nominal sensor noise as a fraction of the current limit (full scale), for predicted intervals (A/A).
NOISE_FRACTION = 0.002
_ATTEMPTS = 8
_NICE = (1.0, 1.25, 1.6, 2.0, 2.5, 3.2, 4.0, 5.0, 6.4, 8.0)


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


def _nice_ceil(x: float) -> float:
    """The smallest of 1, 1.25, 1.6, 2, 2.5, 3.2, 4, 5, 6.4, 8 x 10^k at or above ``x``."""
    k = math.floor(math.log10(x))
    for m in _NICE + (10.0,):
        if m * 10.0**k >= x * (1 - 1e-12):
            return m * 10.0**k
    return 10.0 ** (k + 1)  # pragma: no cover


def _bucket(n: int) -> int:
    """The smallest power of two at or above ``n`` (a compiled fit is shared per size)."""
    return next_power_of_two(n, minimum=2)


def _spread(counts: list[int], total: int) -> list[int]:
    """``counts`` scaled to sum to ``total`` (rounding absorbed by the longest)."""
    scaled = [int(math.floor(c * total / sum(counts))) for c in counts]
    i = max(range(len(counts)), key=lambda j: counts[j])
    scaled[i] += total - sum(scaled)
    return scaled


@dataclasses.dataclass(frozen=True)
class _Levels:
    steps: tuple[LockedStep, ...]  # the locked steps, in plan order
    v_spin: float  # 0: no free spin-up
    sample_rate: float

    def scaled(self, factors: tuple[float, ...]) -> _Levels:
        """Segment voltages multiplied by ``factors`` (one per locked step, then the spin-up's)."""
        return dataclasses.replace(self, steps=tuple(s.scaled(f) for s, f in zip(self.steps, factors)),
                                   v_spin=self.v_spin * factors[-1])


def _sample_rate(times: MotorTimes, motor: MotorParams, v_spin: float, given: float | None) -> float:
    tau = min(times.tau_d, times.tau_q)
    # Peak electrical speed of the spin-up: overshoot * v / lambda_m (rad/s).
    w_e_peak = times.overshoot * v_spin / float(motor.lambda_m) if v_spin else 0.0
    if given is not None:
        if given * tau < MIN_SAMPLES_PER_TIME_CONSTANT:
            raise DrivecalError(
                f"sample_rate {given:g} Hz gives {given * tau:.2g} samples per electrical time constant "
                f"({tau:.3g} s); sample at least {MIN_SAMPLES_PER_TIME_CONSTANT / tau:.3g} Hz or leave it to auto-plan."
            )
        return float(given)
    need = max(SAMPLES_PER_TIME_CONSTANT / tau, w_e_peak / PLAN_MAX_ELECTRICAL_STEP, MIN_SAMPLE_RATE)
    if need > MAX_SAMPLE_RATE:
        raise DrivecalError(
            f"the motor's electrical time constant {tau:.3g} s needs a sample rate of {need:.3g} Hz, above the "
            f"{MAX_SAMPLE_RATE:g} Hz auto-plan considers; give sample_rate explicitly if the bench can do it."
        )
    return _nice_ceil(need)


def _segment_samples(times: MotorTimes, fs: float, budget: float | None, runs: int = 0,
                     steady: int = 0, taus: tuple[float, ...] | None = None, spin: bool = True) -> list[int]:
    """Samples per segment: the locked steps (time constants ``taus``, default the d- and the q-step's),
    the spin-up (unless not ``spin``) and ``runs`` continuing runs of the mechanical test (the last the
    braking), the spin-up and every run but the braking ``steady`` samples longer."""
    taus = (times.tau_d, times.tau_q) if taus is None else taus
    settle = SETTLE_SPIN_TIMES * times.spin_time * fs
    full = [max(LOCKED_TIME_CONSTANTS * tau * fs, MIN_SEGMENT_SAMPLES) for tau in taus]
    if spin:
        full.append(max(SPIN_TIME_CONSTANTS * times.spin_time * fs + (steady if runs else 0), MIN_SEGMENT_SAMPLES))
    full += [max(settle + (steady if k < runs - 1 else 0), MIN_SEGMENT_SAMPLES) for k in range(runs)]
    full = [int(math.ceil(n)) for n in full]
    total = sum(full)
    limit = None if budget is None else int(math.floor(budget * fs + 1e-9))
    if limit is None or _bucket(total) <= limit:
        return _spread(full, _bucket(total))
    if total <= limit:
        return full
    least = [int(math.ceil(MIN_LOCKED_TIME_CONSTANTS * tau * fs)) for tau in taus]
    least += [int(math.ceil(MIN_SPIN_TIME_CONSTANTS * times.spin_time * fs))] * (runs + (1 if spin else 0))
    least = [max(n, 2) for n in least]
    if sum(least) > limit:
        need = sum(least) / fs
        raise DrivecalError(
            f"budget {budget:g} s is too short for this motor: the plan needs at least {need:.3g} s "
            f"({MIN_LOCKED_TIME_CONSTANTS:g} electrical time constants per locked step"
            + (f" and {MIN_SPIN_TIME_CONSTANTS:g} spin-up times of {times.spin_time:.3g} s per free segment"
               if spin else "")
            + "); give a budget "
            "of at least "
            f"{need:.3g} s."
        )
    # Shorten every segment alike, between its least and its full length.
    share = (limit - sum(least)) / (total - sum(least))
    counts = [lo + int(math.floor(share * (hi - lo))) for lo, hi in zip(least, full)]
    return counts


def _plan(levels: _Levels, counts: list[int], v_dc: float, current_limit: float,
          max_speed: float | None, names: tuple[str, ...] = ESTIMATED, noise: float | None = None) -> Plan:
    """The plan of ``levels`` and sample ``counts``; it records the sensor ``noise`` (A) it was designed for."""
    fs = levels.sample_rate
    k = len(levels.steps)
    mechanics = mechanical_segments(levels.v_spin, names, counts[k + 1:], fs) if mechanical_requested(names) else ()
    spin = (Segment("free spin-up", counts[k] / fs, locked=False, v_d=0.0, v_q=levels.v_spin),) if levels.v_spin else ()
    return Plan(
        segments=tuple(Segment(s.name, n / fs, locked=True, v_d=s.v_d, v_q=s.v_q)
                       for s, n in zip(levels.steps, counts)) + spin + mechanics,
        sample_rate=fs,
        v_dc=float(v_dc),
        current_limit=float(current_limit),
        max_speed=None if max_speed is None else float(max_speed),
        current_noise=noise,
    )


def _check_inputs(motor: MotorParams, v_dc: float, current_limit: float, max_speed, budget, sample_rate,
                  names: tuple[str, ...]) -> None:
    unknown = [n for n in names if n not in ESTIMABLE]
    if unknown or not names:
        raise DrivecalError(f"unknown parameter(s) to estimate: {', '.join(unknown) or '(none given)'}; "
                            f"choose from {', '.join(ESTIMABLE)}.")
    for name, value, unit in (("v_dc", v_dc, "V"), ("current_limit", current_limit, "A"),
                              ("max_speed", max_speed, "rad/s"), ("budget", budget, "s"),
                              ("sample_rate", sample_rate, "Hz")):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise DrivecalError(f"{name} must be a positive number of {unit}, got {value!r}.")
    for name in ESTIMATED + ("pole_pairs", "J"):
        value = float(getattr(motor, name))
        if name == "lambda_m" and value == 0.0:  # no magnet: locked steps only
            spun = [n for n in names if n == "lambda_m" or mechanical_requested((n,))]
            if spun:
                raise DrivecalError(f"the motor has no magnet (lambda_m = 0), so auto-plan gives it no free spin-up "
                                    f"and cannot estimate {', '.join(spun)}; leave them out of the names.")
            continue
        if not (math.isfinite(value) and value > 0):
            raise DrivecalError(f"the motor's {name} must be a positive number, got {value!r}.")


def auto_design(
    motor: MotorParams,
    *,
    v_dc: float,
    current_limit: float,
    max_speed: float | None = None,
    budget: float | None = None,
    sample_rate: float | None = None,
    noise_sigma: float | None = None,
    names: tuple[str, ...] = ESTIMATED,
) -> DesignReport:
    """:func:`auto_plan` and its assessment on ``motor`` (the :class:`DesignReport`).

    Args: as :func:`auto_plan`, plus
        noise_sigma: sensor noise (A) for the predicted intervals and the
            mechanical test's length; default :data:`NOISE_FRACTION` of ``current_limit``.
            The plan records it (``Plan.current_noise``), so its file carries it to
            ``drivecal design`` and ``drivecal simulate``.
    """
    names = tuple(n for n in ESTIMABLE if n in names)
    _check_inputs(motor, v_dc, current_limit, max_speed, budget, sample_rate, names)
    mechanics = mechanical_requested(names)
    times = MotorTimes.of(motor)
    sigma = NOISE_FRACTION * current_limit if noise_sigma is None else float(noise_sigma)
    r, p, lam = float(motor.R), float(motor.pole_pairs), float(motor.lambda_m)
    v_max = VOLTAGE_FRACTION * v_dc / math.sqrt(3.0)
    v_step = min(STEP_CURRENT_FRACTION * current_limit * r, v_max)
    no_load = (v_dc / math.sqrt(3.0)) / (p * lam) if lam else math.inf  # rad/s: back-EMF meets the voltage circle
    w_limit = no_load if max_speed is None else min(max_speed, no_load)
    w_cap = SPEED_FRACTION * w_limit
    # The spin-up starts like a locked q-step (current <= v/R) and settles at w = v/(p lambda_m),
    # after an overshoot set by the electromechanical damping.
    v_spin = min(v_step, w_cap * p * lam / times.overshoot) if lam else 0.0
    if saturation_requested(names):
        v_top = min(SATURATION_TOP_FRACTION * current_limit * r, v_max)
        steps = saturation_steps(names, v_top, times.tau_d, times.tau_q)
    else:
        steps = (LockedStep("locked d-step", v_step, 0.0, times.tau_d),
                 LockedStep("locked q-step", 0.0, v_step, times.tau_q))
    levels = _Levels(steps, v_spin, 0.0)

    def judge(levels: _Levels) -> DesignReport:
        fs = _sample_rate(times, motor, levels.v_spin, sample_rate)
        levels = dataclasses.replace(levels, sample_rate=fs)
        runs = len(run_voltages(levels.v_spin, names)) if mechanics else 0
        steady = friction_samples(motor, names, levels.v_spin, sigma) if mechanics else 0
        counts = _segment_samples(times, fs, budget, runs, steady, tuple(s.tau for s in levels.steps),
                                  spin=bool(levels.v_spin))
        plan = _plan(levels, counts, v_dc, current_limit, max_speed, names, sigma)
        return assess_design(plan, motor, noise_sigma=sigma, names=names)

    report = judge(levels)
    for _ in range(_ATTEMPTS):
        if report.ok:
            break
        scale = _scale_down(report, current_limit, w_limit, w_cap)
        if scale is None:
            break  # feasible but not identifiable: smaller amplitudes will not help
        levels = levels.scaled(scale)
        report = judge(levels)
    if report.ok and levels.v_spin:
        # The spin-up's back-EMF keeps its current well under a locked step's: spin it faster,
        # within the same current, the speed cap and the voltage circle, for a tighter lambda_m.
        free = [s for s in report.segments if not s.locked]  # the spin-up and the runs that continue it
        boost = min(STEP_CURRENT_FRACTION * current_limit / max(s.peak_current for s in free),
                    w_cap / max(s.peak_speed for s in free), v_max / levels.v_spin)
        if boost > 1.05:
            boosted_levels = levels.scaled((1.0,) * len(levels.steps) + (boost,))
            boosted = judge(boosted_levels)
            if boosted.ok:
                report, levels = boosted, boosted_levels
        if not is_saturating(motor):
            report = _saturation_margin(report, levels, judge, motor, current_limit)
    if report.ok:
        return report
    if not report.feasible:
        raise DrivecalError(f"no feasible plan found for this motor within the limits: {report.problems[0]}")
    ident = report.identifiability
    weak = ident.dead_params + ident.confounded_params + ident.weak_params
    raise DrivecalError(
        "the auto-plan for this motor does not identify "
        + (", ".join(weak) if weak else f"all parameters (condition number {ident.condition_number:.3g})")
        + ("; the friction shows in the steady free runs: raise the budget or max_speed, or measure with less "
           "noise." if mechanics else "; raise the budget, the current limit or max_speed.")
    )


def _saturation_margin(report: DesignReport, levels: _Levels, judge, motor: MotorParams,
                       current_limit: float) -> DesignReport:
    """``report`` with its free segments held under ``current_limit`` on a motor whose inductances have fallen
    (``_saturation_plan.weakened``), the spin-up voltage scaled down where needed; the margin in its notes."""
    fallen = weakened(motor)
    factor = 1.0
    for _ in range(_ATTEMPTS):
        peak = max(s.peak_current for m in fallen for s in predict_segments(report.plan, m) if not s.locked)
        if peak <= current_limit:
            note = margin_note(peak, current_limit, factor)
            return dataclasses.replace(report, notes=report.notes + (note,))
        step = CURRENT_MARGIN * current_limit / peak
        factor *= step
        levels = levels.scaled((1.0,) * len(levels.steps) + (step,))
        report = judge(levels)
        if not report.ok:
            break
    raise DrivecalError(f"no spin-up found that a motor whose inductances fall to half (saturation) would keep "
                        f"under the current limit {current_limit:g} A; raise the current limit or give the motor's "
                        "saturation law (sat_d, sat_q, sat_dq).")


def _scale_down(report: DesignReport, current_limit: float, w_limit: float,
                w_cap: float) -> tuple[float, ...] | None:
    """Voltage factors (one per locked step, then the spin-up's) that bring predicted peaks back inside the
    limits, or None if none broke; the runs that continue the spin-up scale with it."""
    scale = [1.0] * len(report.segments)
    for i, s in enumerate(report.segments):
        if not s.finite:
            scale[i] = 0.5
            continue
        if s.peak_current > current_limit:
            scale[i] = min(scale[i], CURRENT_MARGIN * current_limit / s.peak_current)
        if not s.locked and s.peak_speed > w_limit:
            scale[i] = min(scale[i], w_cap / s.peak_speed)
        if not s.locked and s.peak_electrical_step > _DESIGN_MAX_STEP:
            scale[i] = min(scale[i], SPEED_FRACTION * _DESIGN_MAX_STEP / s.peak_electrical_step)
    k = sum(1 for s in report.segments if s.locked)
    scale = scale[:k] + [min(scale[k:], default=1.0)]
    return None if all(f == 1.0 for f in scale) else tuple(scale)


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


def auto_plan(
    motor: MotorParams,
    *,
    v_dc: float,
    current_limit: float,
    max_speed: float | None = None,
    budget: float | None = None,
    sample_rate: float | None = None,
    names: tuple[str, ...] = ESTIMATED,
) -> Plan:
    """A feasible, identifiable calibration plan scaled to ``motor``.

    Args:
        motor: the nominal (datasheet) motor: R (ohm), Ld, Lq (H), lambda_m
            (Wb), pole_pairs, J (kg*m^2), B (N*m*s).
        v_dc: the bench's DC-link voltage (V); segments stay inside
            ``VOLTAGE_FRACTION * v_dc / sqrt(3)``.
        current_limit: the bench's peak current limit (A), the largest ``|i_dq|``.
        max_speed: highest mechanical speed allowed in the free spin-up (rad/s);
            default: the no-load speed the voltage allows.
        budget: longest total plan duration (s), or None.
        sample_rate: the bench's sample rate (Hz); default chosen from the
            motor's time constants.
        names: the parameters to estimate; with any of J, B, T_coulomb,
            T_load the plan gains the mechanical test (``_mechanical``).

    Returns:
        A :class:`Plan` (locked d-step, locked q-step, free spin-up, and the
        mechanical test's continuing runs) that :func:`drivecal.design.assess_design`
        judges feasible and identifiable on ``motor``.

    Raises:
        DrivecalError: bad limits, or no feasible identifiable plan exists
            (one sentence naming the limit to change).
    """
    return auto_design(motor, v_dc=v_dc, current_limit=current_limit, max_speed=max_speed, budget=budget,
                       sample_rate=sample_rate, names=names).plan
