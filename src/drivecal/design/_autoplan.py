"""Auto-plan: a feasible, identifiable bench plan scaled to the motor at hand and to the bench's real limits.

From the datasheet motor and the bench's limits (DC-link voltage, current limit, speed limit, the rotor
clamp's torque limit, the inverter's sample rate and dead time, time budget) it builds the standard
segments — locked d-step (R, Ld), locked q-step (Lq), free spin-up (lambda_m) — with the margins of
``_bench_limits``:

* **sample rate**: the bench's, else a real inverter's 10 kHz, raised towards 40 kHz only where the
  fastest electrical time constant or the spin-up's electrical speed needs it (``choose_sample_rate``);
* **amplitudes** from the current limit and R: each step drives a steady current of
  :data:`STEP_CURRENT_FRACTION` of the limit (``v = i * R``; the q-step less where its torque would
  pass :data:`TORQUE_MARGIN` of the clamp's limit), never more than :data:`VOLTAGE_FRACTION` of the
  voltage circle ``v_dc / sqrt(3)``;
* **dead time**: a step under :data:`DEAD_TIME_MARGIN` times the expected dead-time voltage
  ``v_dc * t_dead * f_s`` is raised to it where the current margin allows; where not, v_dead must
  be fitted: the plan gains a second d-step at :data:`DEAD_TIME_SECOND_LEVEL` of the current (the
  dead-time voltage is the same at both currents, R's drop is not), every locked step adds the
  dead time's drop to reach its current, the spin-up the voltage the dead time takes from it where
  that matters (``_spin_dead_time``), and the plan is judged with v_dead estimated (notes, ``limits``);
* **durations** from the time constants: :data:`LOCKED_TIME_CONSTANTS` ``L/R`` per locked step,
  :data:`SPIN_TIME_CONSTANTS` spin-up times (the mechanical time constant
  ``tm = J*R / (1.5 p^2 lambda_m^2)``, or ``sqrt(tm * Lq/R)``, a quarter period of the
  electromechanical oscillation, when that is longer) after the spin-up's ramp, each at least
  :data:`MIN_SEGMENT_SAMPLES` samples;
* a **spin-up ramp** on v_q to the back-EMF of :data:`SPIN_SPEED_FRACTION` of the speed limit
  (``max_speed``, and the no-load speed the voltage allows), as fast as keeps its acceleration current
  near a locked step's: a voltage step would surge to ``v/R`` and, held to the current limit, spin a
  large motor to a few per cent of its rated speed, where lambda_m's back-EMF hardly shows; a rotor too heavy
  to get there within :data:`MAX_RAMP_SAMPLES` spins to the speed it reaches in that time.

The total sample count is rounded up to a power of two, lengthening every segment alike, so that plans of
different motors share one compiled fit; a binding time budget shortens the segments instead, down to
:data:`MIN_LOCKED_TIME_CONSTANTS` and :data:`MIN_SPIN_TIME_CONSTANTS`.

When mechanical parameters (J, B, T_coulomb, T_load) are requested, the spin-up is a voltage step that runs
on to a steady speed and the mechanical test continues it: a low-speed run (and a reversed one for T_load)
and a short-circuit braking, sized in ``_mechanical``.

When saturation coefficients (sat_d, sat_q, sat_dq) are requested, the locked steps become
those ``_saturation_plan`` lays out: steps at three current levels per saturating axis, up to 0.8 of
the current limit, and combined d+q steps for the cross-saturation. A motor without a magnet
(``lambda_m = 0``, a synchronous reluctance machine) gets no free spin-up (v_q alone makes no torque
there, and there is no back-EMF to show); it can then estimate neither lambda_m nor the mechanics.
These plans report the dead-time margin but do not lay out what identifies v_dead.

The plan is then judged by :func:`drivecal.design.assess_design` on the nominal motor, for the requested
parameters (with its saturating law where it has one); a segment whose predicted peak current, speed or
clamp torque breaks a limit is scaled down and the plan judged again. When the motor is linear (its
saturation unknown), the free segments are then held to a current a motor whose inductances have fallen
to half would keep under the limit (``_saturation_plan``; stated in the report's notes). It binds where
the inductance holds the spin-up's current down (slow electrical, fast mechanical time constants, a
spin-up boosted past a locked step's voltage); on the seed motor's plans it does not bind. When no
feasible, identifiable plan exists, :class:`~drivecal.errors.DrivecalError` says why in one sentence.
"""

from __future__ import annotations

import dataclasses
import math

from ._assess import MAX_ELECTRICAL_STEP as _DESIGN_MAX_STEP, DesignReport, assess_design, predict_segments
from ._bench_limits import (CURRENT_MARGIN, DEAD_TIME_MARGIN, DEFAULT_DEAD_TIME, LOCKED_TIME_CONSTANTS,
                            MAX_RAMP_SAMPLES, MIN_LOCKED_TIME_CONSTANTS, MIN_SAMPLES_PER_TIME_CONSTANT,
                            MIN_SEGMENT_SAMPLES, MIN_SPIN_TIME_CONSTANTS, PLAN_MAX_ELECTRICAL_STEP, SAMPLE_RATES,
                            SAMPLES_PER_TIME_CONSTANT, SPEED_FRACTION, SPIN_SPEED_FRACTION, SPIN_TIME_CONSTANTS,
                            STEP_CURRENT_FRACTION, TORQUE_MARGIN, VOLTAGE_FRACTION, BenchLimits, MotorTimes,
                            choose_sample_rate, clamp_current, dead_time_drop, expected_dead_voltage,
                            expected_dead_width, ramp_speed)
from ._mechanical import SETTLE_SPIN_TIMES, friction_samples, mechanical_requested, mechanical_segments, run_voltages
from ._saturation_plan import (SATURATION_TOP_FRACTION, LockedStep, margin_note, saturation_requested,
                               saturation_steps, weakened, with_saturation_steps)
from ._spin_dead_time import spin_through_dead_time
from .._stats import next_power_of_two
from ..errors import DrivecalError
from ..physics import ESTIMABLE, ESTIMATED, MotorParams, is_saturating
from ..plan import Plan, Segment, waveforms

__all__ = ["CURRENT_MARGIN", "LOCKED_TIME_CONSTANTS", "MIN_LOCKED_TIME_CONSTANTS", "MIN_SAMPLES_PER_TIME_CONSTANT",
           "MIN_SEGMENT_SAMPLES", "MIN_SPIN_TIME_CONSTANTS", "MotorTimes", "PLAN_MAX_ELECTRICAL_STEP",
           "SAMPLES_PER_TIME_CONSTANT", "SPEED_FRACTION", "SPIN_TIME_CONSTANTS", "STEP_CURRENT_FRACTION",
           "VOLTAGE_FRACTION", "auto_design", "auto_plan", "with_saturation_steps"]

#: Bench sample rates auto-plan chooses from (Hz): real inverters' 10 to 40 kHz.
MIN_SAMPLE_RATE = SAMPLE_RATES[0]
MAX_SAMPLE_RATE = SAMPLE_RATES[-1]
#: Nominal sensor noise as a fraction of the current limit (full scale), for predicted intervals (A/A).
NOISE_FRACTION = 0.002
#: Peak over steady speed allowed for in the spin-up ramp's electrical speed (sample rate), -.
RAMP_OVERSHOOT = 1.1
#: The second locked d-step's current, as a share of the first's, where v_dead is fitted: two currents tell
#: the dead-time voltage (the same at both) from R (proportional to the current).
DEAD_TIME_SECOND_LEVEL = 0.5
#: Where v_dead is fitted, the locked steps add the expected dead-time drop and leave room under the current
#: limit for a dead-time voltage this share off the expected one.
DEAD_TIME_TOLERANCE = 0.1
#: ... and refuse where that leaves the d-step less than this share of the current limit.
MIN_DEAD_TIME_STEP = 0.2
_ATTEMPTS = 8


def _bucket(n: int) -> int:
    """The smallest power of two at or above ``n`` (a compiled fit is shared per size)."""
    return next_power_of_two(n, minimum=2)


def _spread(counts: list[int], total: int) -> list[int]:
    """``counts`` scaled to sum to ``total`` (rounding absorbed by the longest)."""
    scaled = [int(math.floor(c * total / sum(counts))) for c in counts]
    scaled[max(range(len(counts)), key=lambda j: counts[j])] += total - sum(scaled)
    return scaled


@dataclasses.dataclass(frozen=True)
class _Levels:
    steps: tuple[LockedStep, ...]  # the locked steps, in plan order
    v_spin: float  # 0: no free spin-up
    sample_rate: float
    rise: float = 0.0  # the spin-up's ramp (s); 0: a voltage step

    def scaled(self, factors: tuple[float, ...]) -> _Levels:
        """Segment voltages multiplied by ``factors`` (one per locked step, then the spin-up's)."""
        return dataclasses.replace(self, steps=tuple(s.scaled(f) for s, f in zip(self.steps, factors)),
                                   v_spin=self.v_spin * factors[-1])


def _segment_samples(times: MotorTimes, fs: float, budget: float | None, runs: int = 0,
                     steady: int = 0, taus: tuple[float, ...] | None = None, spin: bool = True,
                     rise: float = 0.0) -> list[int]:
    """Samples per segment: the locked steps (time constants ``taus``, default the d- and the q-step's),
    the spin-up (unless not ``spin``; ``rise`` (s) longer: its ramp and settling) and ``runs`` continuing runs of the
    mechanical test (the last the braking), the spin-up and every run but the braking ``steady`` samples longer."""
    taus = (times.tau_d, times.tau_q) if taus is None else taus
    settle = SETTLE_SPIN_TIMES * times.spin_time * fs
    full = [max(LOCKED_TIME_CONSTANTS * tau * fs, MIN_SEGMENT_SAMPLES) for tau in taus]
    if spin:
        full.append(max((SPIN_TIME_CONSTANTS * times.spin_time + rise) * fs + (steady if runs else 0),
                        MIN_SEGMENT_SAMPLES))
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


SPIN_UP = "free spin-up"


def _plan(levels: _Levels, counts: list[int], v_dc: float, current_limit: float,
          max_speed: float | None, names: tuple[str, ...] = ESTIMATED, noise: float | None = None,
          max_torque: float | None = None, drop=None) -> Plan:
    """The plan of ``levels`` and sample ``counts``; it records the sensor ``noise`` (A) it was designed for.
    ``drop(i_d, i_q)``: the dead-time voltage each locked step adds for its current ``v / R`` (None: none)."""
    fs = levels.sample_rate
    k = len(levels.steps)
    mechanics = mechanical_requested(names)
    runs = mechanical_segments(levels.v_spin, names, counts[k + 1:], fs) if mechanics else ()
    spin = ()
    if levels.v_spin:
        v_q = (levels.v_spin if not levels.rise
               else waveforms.ramp(counts[k], fs, level=levels.v_spin, rise=levels.rise))
        spin = (Segment(SPIN_UP, counts[k] / fs, locked=False, v_d=0.0, v_q=v_q),)
    steps = []
    for s, n in zip(levels.steps, counts):
        extra = (0.0, 0.0) if drop is None else drop(s.v_d, s.v_q)
        steps.append(Segment(s.name, n / fs, locked=True, v_d=s.v_d + extra[0], v_q=s.v_q + extra[1]))
    return Plan(
        segments=tuple(steps) + spin + runs,
        sample_rate=fs,
        v_dc=float(v_dc),
        current_limit=float(current_limit),
        max_speed=None if max_speed is None else float(max_speed),
        current_noise=noise,
        max_torque=None if max_torque is None else float(max_torque),
    )


def _check_inputs(motor: MotorParams, v_dc: float, current_limit: float, max_speed, budget, sample_rate,
                  names: tuple[str, ...], max_torque=None, dead_time=0.0) -> None:
    unknown = [n for n in names if n not in ESTIMABLE]
    if unknown or not names:
        raise DrivecalError(f"unknown parameter(s) to estimate: {', '.join(unknown) or '(none given)'}; "
                            f"choose from {', '.join(ESTIMABLE)}.")
    for name, value, unit in (("v_dc", v_dc, "V"), ("current_limit", current_limit, "A"),
                              ("max_speed", max_speed, "rad/s"), ("budget", budget, "s"),
                              ("sample_rate", sample_rate, "Hz"), ("max_torque", max_torque, "N*m")):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise DrivecalError(f"{name} must be a positive number of {unit}, got {value!r}.")
    if not (math.isfinite(dead_time) and dead_time >= 0):
        raise DrivecalError(f"dead_time must be a number of seconds >= 0 (0: an inverter that compensates it), "
                            f"got {dead_time!r}.")
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


def _step_voltage(r: float, current: float, cap: float, need: float, v_max: float) -> float:
    """A locked step's voltage ``R * i`` (V): ``current``, under ``cap`` (A); raised to the dead-time margin
    ``need`` (V) where that stays within the current margin and ``cap``; inside ``v_max``."""
    v = min(current, cap) * r
    if v < need <= min(CURRENT_MARGIN * current / STEP_CURRENT_FRACTION, cap) * r:
        v = need
    return min(v, v_max)


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
    max_torque: float | None = None,
    dead_time: float = DEFAULT_DEAD_TIME,
) -> DesignReport:
    """:func:`auto_plan` and its assessment on ``motor`` (the :class:`DesignReport`).

    Args: as :func:`auto_plan`, plus
        noise_sigma: sensor noise (A) for the predicted intervals and the
            mechanical test's length; default :data:`NOISE_FRACTION` of ``current_limit``.
            The plan records it (``Plan.current_noise``), so its file carries it to
            ``drivecal design`` and ``drivecal simulate``.

    The report's ``limits`` (:class:`BenchLimits`) say where the sample rate came from, the
    expected dead-time voltage and whether ``v_dead`` must be fitted; its ``waveforms`` hold the
    spin-up ramp's plan-file table.
    """
    names = tuple(n for n in ESTIMABLE if n in names)
    _check_inputs(motor, v_dc, current_limit, max_speed, budget, sample_rate, names, max_torque, dead_time)
    mechanics, saturation = mechanical_requested(names), saturation_requested(names)
    times = MotorTimes.of(motor)
    sigma = NOISE_FRACTION * current_limit if noise_sigma is None else float(noise_sigma)
    r, p, lam = float(motor.R), float(motor.pole_pairs), float(motor.lambda_m)
    v_max = VOLTAGE_FRACTION * v_dc / math.sqrt(3.0)
    no_load = (v_dc / math.sqrt(3.0)) / (p * lam) if lam else math.inf  # rad/s: back-EMF meets the voltage circle
    w_limit = no_load if max_speed is None else min(max_speed, no_load)
    w_cap = SPEED_FRACTION * w_limit
    tau = min(times.tau_d, times.tau_q)
    i_step = STEP_CURRENT_FRACTION * current_limit
    ripple = v_dc / (8.0 * min(float(motor.Ld), float(motor.Lq)) * current_limit)  # PWM ripple x rate / limit
    ramp = bool(lam) and not mechanics  # the standard spin-up: a ramp up to a set speed
    if ramp:
        w_spin = SPIN_SPEED_FRACTION * w_limit
        fs, fs_source = choose_sample_rate(tau, RAMP_OVERSHOOT * p * w_spin, sample_rate, ripple)
        w_spin = min(w_spin, PLAN_MAX_ELECTRICAL_STEP * fs / (RAMP_OVERSHOOT * p))  # a slow bench: spin slower
        # Accelerate at half the steady current a locked step draws (refined below on the prediction), slower
        # where the ramp would outgrow MAX_RAMP_SAMPLES.
        w_spin, rise, ramp_note = ramp_speed(motor, w_spin, 0.5 * i_step, fs)
        v_spin = min(p * lam * w_spin, v_max)
        rise = max(rise, 2.0 * times.spin_time, 2.0 * times.tau_q)
    else:
        # The spin-up starts like a locked q-step (current <= v/R) and settles at w = v/(p lambda_m),
        # after an overshoot set by the electromechanical damping.
        v_spin = min(i_step * r, v_max, w_cap * p * lam / times.overshoot) if lam else 0.0
        fs, fs_source = choose_sample_rate(tau, times.overshoot * v_spin / lam if lam else 0.0, sample_rate, ripple)
        rise, ramp_note = 0.0, ()
    v_dead = expected_dead_voltage(motor, v_dc, dead_time, fs)
    i_dead = expected_dead_width(motor, v_dead, fs)
    need = DEAD_TIME_MARGIN * v_dead
    v_d_step = _step_voltage(r, i_step, math.inf, need, v_max)
    v_q_step = _step_voltage(r, i_step, clamp_current(motor, max_torque), need, v_max)
    # Under the margin the dead time is part of what a step measures: the standard plan then fits v_dead,
    # with a second d-step current to tell it from R and every locked step adding its drop.
    fit_dead = 0 < min(v_d_step, v_q_step) < need and not (mechanics or saturation)
    if fit_dead:
        # Every step then adds the expected dead-time drop, and a dead-time voltage DEAD_TIME_TOLERANCE off moves
        # its current by that share of the drop over R: the d-step goes as high as leaves that room (where the
        # dead time's smooth sign has turned, which tells it from R), the q-step no higher.
        slack = DEAD_TIME_TOLERANCE * abs(dead_time_drop(v_dead, i_dead, current_limit, 0.0)[0]) / r
        i_top = min(CURRENT_MARGIN * current_limit, current_limit - slack)
        if i_top < MIN_DEAD_TIME_STEP * current_limit:
            raise DrivecalError(
                f"the expected dead-time voltage {v_dead:.3g} V is too large for open-loop locked steps on this motor: "
                f"{DEAD_TIME_TOLERANCE * 100:g} % of it drives {slack:.3g} A through R = {r:.3g} ohm, leaving no step "
                f"current under the limit {current_limit:g} A; give the bench's dead time (--dead-time, 0 where the "
                "inverter compensates it) or the motor file's v_dead.")
        v_d_step = min(i_top * r, v_max)
        # the clamp too: a q current the dead time's error raises by slack_q must stay under its torque margin
        slack_q = DEAD_TIME_TOLERANCE * abs(dead_time_drop(v_dead, i_dead, 0.0, current_limit)[1]) / r
        i_q = min(v_q_step / r, clamp_current(motor, max_torque) - slack_q, i_top)
        if max_torque is not None and i_q < MIN_DEAD_TIME_STEP * STEP_CURRENT_FRACTION * current_limit:
            raise DrivecalError(
                f"the rotor clamp's limit {max_torque:g} N*m leaves the locked q-step {max(i_q, 0.0):.3g} A once "
                f"{DEAD_TIME_TOLERANCE * 100:g} % of the expected dead-time voltage {v_dead:.3g} V is allowed for "
                f"({slack_q:.3g} A); raise --max-torque, or give the bench's dead time (--dead-time).")
        v_q_step = i_q * r
    if saturation:
        v_top = min(SATURATION_TOP_FRACTION * current_limit * r, v_max)
        steps = saturation_steps(names, v_top, times.tau_d, times.tau_q)
    else:
        steps = (LockedStep("locked d-step", v_d_step, 0.0, times.tau_d),
                 LockedStep("locked q-step", 0.0, v_q_step, times.tau_q))
        if fit_dead:
            steps = steps[:1] + (LockedStep("locked d-step, half current", DEAD_TIME_SECOND_LEVEL * v_d_step, 0.0,
                                            times.tau_d),) + steps[1:]
    levels = _Levels(steps, v_spin, fs, rise)
    dead_motor = motor.replace(v_dead=v_dead, i_dead=i_dead) if fit_dead else motor
    dead_names = tuple(n for n in ESTIMABLE if n in names + ("v_dead",)) if fit_dead else names

    def drop(v_d: float, v_q: float) -> tuple[float, float]:
        return dead_time_drop(v_dead, i_dead, v_d / r, v_q / r)

    def judge(levels: _Levels, final: bool = False) -> DesignReport:
        runs = len(run_voltages(levels.v_spin, names)) if mechanics else 0
        steady = friction_samples(motor, names, levels.v_spin, sigma) if mechanics else 0
        # After a ramp the currents settle over a few electrical time constants (v_d = 0 leaves an i_d
        # that the rotation drives, which lowers the speed until it has decayed).
        extra = levels.rise + LOCKED_TIME_CONSTANTS * max(times.tau_d, times.tau_q) if levels.rise else 0.0
        counts = _segment_samples(times, fs, budget, runs, steady, tuple(s.tau for s in levels.steps),
                                  spin=bool(levels.v_spin), rise=extra)
        plan = _plan(levels, counts, v_dc, current_limit, max_speed, names, sigma, max_torque,
                     drop if final and fit_dead else None)
        if final and fit_dead:  # on the motor with its dead time, v_dead estimated too
            return assess_design(plan, dead_motor, noise_sigma=sigma, names=dead_names)
        return assess_design(plan, motor, noise_sigma=sigma, names=names)

    report = judge(levels)
    for _ in range(_ATTEMPTS):
        if report.ok:
            break
        scale = _scale_down(report, current_limit, w_limit, w_cap, plan_torque=max_torque, ramp=bool(levels.rise))
        longer = _ramp_stretch(report, current_limit) if levels.rise else 1.0
        if scale is None and longer == 1.0:
            break  # feasible but not identifiable: smaller amplitudes will not help
        levels = dataclasses.replace(levels if scale is None else levels.scaled(scale), rise=levels.rise * longer)
        report = judge(levels)
    if report.ok and levels.v_spin and levels.rise:
        report, levels = _fit_ramp(report, levels, judge, current_limit, times)
    elif report.ok and levels.v_spin:
        # The spin-up's back-EMF keeps its current well under a locked step's: spin it faster,
        # within the same current, the speed cap, the voltage circle and the electrical step.
        free = [s for s in report.segments if not s.locked]  # the spin-up and the runs that continue it
        boost = min(i_step / max(s.peak_current for s in free), w_cap / max(s.peak_speed for s in free),
                    v_max / levels.v_spin, PLAN_MAX_ELECTRICAL_STEP / max(s.peak_electrical_step for s in free))
        if boost > 1.05:
            boosted_levels = levels.scaled((1.0,) * len(levels.steps) + (boost,))
            boosted = judge(boosted_levels)
            if boosted.ok:
                report, levels = boosted, boosted_levels
    if report.ok and levels.v_spin and not is_saturating(motor):
        report, levels = _saturation_margin(report, levels, judge, motor, current_limit)
    if report.ok:
        notes = report.notes
        if fit_dead:
            final = judge(levels, final=True)
            if final.ok and levels.v_spin:
                final, levels, spin_note = spin_through_dead_time(report, final, levels, judge, dead_motor,
                                                                  current_limit)
                ramp_note += spin_note
            if not final.ok:
                raise DrivecalError(f"the expected dead-time voltage {v_dead:.3g} V is above a tenth of the locked "
                                    f"steps' and this plan cannot tell it from R ({final.identifiability.summary()});"
                                    " lower --dead-time if the inverter compensates it, or raise the current limit.")
            report = final
        limits = BenchLimits(fs_source, float(dead_time), v_dead, i_dead, fit_dead, w_limit, max_torque,
                             report.identifiability.names)
        notes += limits.dead_time_notes(report.plan) + ramp_note
        wave = ({(SPIN_UP, "v_q"): {"kind": "ramp", "level": levels.v_spin, "rise": levels.rise}}
                if levels.v_spin and levels.rise else {})
        return dataclasses.replace(report, notes=notes, limits=limits, waveforms=wave)
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


def _fit_ramp(report: DesignReport, levels: _Levels, judge, current_limit: float,
              times: MotorTimes) -> tuple[DesignReport, _Levels]:
    """The spin-up ramp made as short as keeps its predicted peak current near a locked step's (the
    acceleration current is the rotor's inertia times the ramp's slope), never under two spin-up times."""
    target = STEP_CURRENT_FRACTION * current_limit
    least = max(2.0 * times.spin_time, 2.0 * times.tau_q)
    for _ in range(4):
        peak = max(s.peak_current for s in report.segments if not s.locked)
        if 0.8 * target <= peak <= target:
            break
        rise = max(min(levels.rise * peak / (0.9 * target), MAX_RAMP_SAMPLES / levels.sample_rate), least)
        if abs(rise - levels.rise) <= 0.01 * levels.rise:
            break
        candidate_levels = dataclasses.replace(levels, rise=rise)
        candidate = judge(candidate_levels)
        if not candidate.ok:
            break
        report, levels = candidate, candidate_levels
    return report, levels


def _saturation_margin(report: DesignReport, levels: _Levels, judge, motor: MotorParams,
                       current_limit: float) -> tuple[DesignReport, _Levels]:
    """``report`` (and its levels) with its free segments held under ``current_limit`` on a motor whose
    inductances have fallen (``_saturation_plan.weakened``), the spin-up voltage scaled down where needed;
    the margin in its notes."""
    fallen = weakened(motor)
    factor = 1.0
    for _ in range(_ATTEMPTS):
        peak = max(s.peak_current for m in fallen for s in predict_segments(report.plan, m) if not s.locked)
        if peak <= current_limit:
            note = margin_note(peak, current_limit, factor)
            return dataclasses.replace(report, notes=report.notes + (note,)), levels
        step = CURRENT_MARGIN * current_limit / peak
        factor *= step
        levels = levels.scaled((1.0,) * len(levels.steps) + (step,))
        report = judge(levels)
        if not report.ok:
            break
    raise DrivecalError(f"no spin-up found that a motor whose inductances fall to half (saturation) would keep "
                        f"under the current limit {current_limit:g} A; raise the current limit or give the motor's "
                        "saturation law (sat_d, sat_q, sat_dq).")


def _ramp_stretch(report: DesignReport, current_limit: float) -> float:
    """How much longer the spin-up's ramp must be for its current (the acceleration's) to fall inside the limit."""
    peak = max(s.peak_current for s in report.segments if not s.locked)
    return peak / (CURRENT_MARGIN * current_limit) if peak > current_limit else 1.0


def _scale_down(report: DesignReport, current_limit: float, w_limit: float,
                w_cap: float, plan_torque: float | None = None, ramp: bool = False) -> tuple[float, ...] | None:
    """Voltage factors (one per locked step, then the spin-up's) that bring predicted peaks back inside the
    limits (the clamp's ``plan_torque`` too), or None if none broke; the runs that continue the spin-up scale
    with it. A spin-up ``ramp``'s current is left to :func:`_ramp_stretch` (a slower ramp, not a lower speed)."""
    scale = [1.0] * len(report.segments)
    for i, s in enumerate(report.segments):
        if not s.finite:
            scale[i] = 0.5
            continue
        if s.peak_current > current_limit and (s.locked or not ramp):
            scale[i] = min(scale[i], CURRENT_MARGIN * current_limit / s.peak_current)
        if s.locked and plan_torque is not None and s.peak_torque > plan_torque:
            scale[i] = min(scale[i], TORQUE_MARGIN * plan_torque / s.peak_torque)
        if not s.locked and s.peak_speed > w_limit:
            scale[i] = min(scale[i], w_cap / s.peak_speed)
        if not s.locked and s.peak_electrical_step > _DESIGN_MAX_STEP:
            scale[i] = min(scale[i], SPEED_FRACTION * _DESIGN_MAX_STEP / s.peak_electrical_step)
    k = sum(1 for s in report.segments if s.locked)
    scale = scale[:k] + [min(scale[k:], default=1.0)]
    return None if all(f == 1.0 for f in scale) else tuple(scale)


def auto_plan(
    motor: MotorParams,
    *,
    v_dc: float,
    current_limit: float,
    max_speed: float | None = None,
    budget: float | None = None,
    sample_rate: float | None = None,
    names: tuple[str, ...] = ESTIMATED,
    max_torque: float | None = None,
    dead_time: float = DEFAULT_DEAD_TIME,
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
        sample_rate: the bench's sample rate (Hz); default
            :data:`~drivecal.design.DEFAULT_SAMPLE_RATE` (10 kHz, a real inverter's),
            raised up to 40 kHz where the motor needs it.
        names: the parameters to estimate; with any of J, B, T_coulomb,
            T_load the plan gains the mechanical test (``_mechanical``).
        max_torque: the rotor clamp's torque limit (N*m); locked steps stay under
            :data:`TORQUE_MARGIN` of it. None: not checked.
        dead_time: the inverter's dead time per switching edge (s), for the expected
            dead-time voltage ``v_dc * dead_time * sample_rate`` (the motor file's
            ``v_dead`` where it states one); 0 for an inverter that compensates it.

    Returns:
        A :class:`Plan` (locked d-step, locked q-step, free spin-up, and the
        mechanical test's continuing runs; a second d-step where v_dead must be fitted)
        that :func:`drivecal.design.assess_design` judges feasible and identifiable on ``motor``.

    Raises:
        DrivecalError: bad limits, or no feasible identifiable plan exists
            (one sentence naming the limit to change).
    """
    return auto_design(motor, v_dc=v_dc, current_limit=current_limit, max_speed=max_speed, budget=budget,
                       sample_rate=sample_rate, names=names, max_torque=max_torque, dead_time=dead_time).plan
