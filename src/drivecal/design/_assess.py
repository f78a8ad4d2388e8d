"""Judging a plan before bench time: feasibility, identifiability, predicted intervals.

Everything here runs on the nominal motor (the datasheet values), with the
same forward model and Jacobian the fit uses, so what ``design`` predicts is
what ``fit`` will report when the motor is close to nominal. A motor with a saturating
magnetic law (any of sat_d, sat_q, sat_dq non-zero) is predicted with it: the forward model then
integrates the flux linkages (``model._flux``), so the peak currents are the saturating machine's.
Where a plan's only weakness is the per-unit saturation coefficients' coupling to their axis's
inductance, it is judged again in the law's own coefficients (``_saturation_plan.law_verdict``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..model import Experiment, model_experiment, simulated_states
from ..identify import Identifiability, assess_identifiability
from ..physics import ESTIMATED, MotorParams, flux_of_currents, is_saturating
from ..plan import Plan
from ._bench_limits import MAX_ELECTRICAL_STEP
from ._saturation_plan import law_verdict, motor_note


@dataclasses.dataclass(frozen=True)
class SegmentPrediction:
    """What one segment is predicted to do on the nominal motor.

    Attributes:
        name: segment label.
        locked: rotor locked.
        peak_current: largest ``|i_dq|`` (A) = peak phase current (amplitude-invariant).
        peak_current_time: when it is reached, from the segment start (s).
        peak_speed: largest ``|w_m|`` (rad/s); 0 when locked.
        peak_electrical_step: largest ``w_e * dt`` (rad), the electrical angle
            swept in one sample period.
        finite: the simulated state stayed finite.
        peak_torque: largest ``|Te|`` (N*m), ``Te = 1.5 p (lambda_m i_q + (Ld - Lq) i_d i_q)`` (the flux
            linkages' ``1.5 p (psi_d i_q - psi_q i_d)`` on a saturating motor); on a locked segment the
            torque the rotor clamp holds.
    """

    name: str
    locked: bool
    peak_current: float
    peak_current_time: float
    peak_speed: float
    peak_electrical_step: float
    finite: bool
    peak_torque: float = 0.0


@dataclasses.dataclass(frozen=True)
class DesignReport:
    """A plan judged on a nominal motor.

    Attributes:
        plan: the plan.
        motor: the nominal motor.
        segments: per-segment predictions.
        problems: feasibility problems, one sentence each (empty when feasible).
        identifiability: rank, condition number, dead/weak parameters, predicted CIs.
        notes: how the prediction was made and what the plan was sized for, one sentence each
            (the saturating law used; the margin for unknown saturation; a judgement in the
            law's own coefficients).
        limits: the bench limits an auto-plan was sized for and its margins against them
            (:class:`~drivecal.design.BenchLimits`), or None for a plan judged as given.
        waveforms: per ``(segment name, axis)``, the plan-file table of a waveform the plan was
            built from (an auto-plan's spin-up ramp), for :func:`drivecal.plan.write_plan`.
    """

    plan: Plan
    motor: MotorParams
    segments: tuple[SegmentPrediction, ...]
    problems: tuple[str, ...]
    identifiability: Identifiability
    notes: tuple[str, ...] = ()
    limits: Any = None
    waveforms: dict = dataclasses.field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return not self.problems

    @property
    def ok(self) -> bool:
        """Feasible and identifies every requested parameter."""
        return self.feasible and self.identifiability.identifiable

    def to_dict(self) -> dict[str, Any]:
        ident = self.identifiability
        return {
            "feasible": self.feasible,
            "identifiable": ident.identifiable,
            "problems": list(self.problems),
            "segments": [dataclasses.asdict(s) for s in self.segments],
            "identifiability": ident.to_dict(),
            "predicted": {
                n: {"se": _num(ident.predicted_se[i]), "ci95_half_width": _num(ident.predicted_ci95[i]),
                    "relative_ci95": _num(ident.predicted_ci95[i] / float(getattr(self.motor, n)))
                    if float(getattr(self.motor, n)) != 0.0 else None}
                for i, n in enumerate(ident.names)
            },
            "noise_sigma": ident.noise_sigma,
            "current_limit": self.plan.current_limit,
            "voltage_limit": self.plan.voltage_limit,
            "max_speed": self.plan.max_speed,
            "max_torque": self.plan.max_torque,
            "notes": list(self.notes),
            **({"limits": self.limits.to_dict(self)} if self.limits is not None else {}),
        }


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None




def _torque(motor: MotorParams, i_d: np.ndarray, i_q: np.ndarray) -> np.ndarray:
    """Electrical torque (N*m) at the currents: the flux linkages' on a saturating motor, else the dq law's."""
    p = float(motor.pole_pairs)
    if is_saturating(motor):
        psi_d, psi_q = (np.asarray(x) for x in flux_of_currents(i_d, i_q, motor))
        return 1.5 * p * (psi_d * i_q - psi_q * i_d)
    return 1.5 * p * (float(motor.lambda_m) * i_q + (float(motor.Ld) - float(motor.Lq)) * i_d * i_q)


def predict_segments(plan: Plan, motor: MotorParams) -> tuple[SegmentPrediction, ...]:
    """Simulate the plan on ``motor`` (drivecal's forward model) and summarise each segment."""
    states = simulated_states(motor, model_experiment(Experiment.from_plan(plan), motor, ()))
    torque = np.abs(_torque(motor, states[:, 0], states[:, 1]))
    out, k = [], 0
    for seg in plan.segments:
        n = seg.num_samples(plan.sample_rate)
        x, te = states[k : k + n], torque[k : k + n]
        k += n
        finite = bool(np.all(np.isfinite(x)))
        current = np.hypot(x[:, 0], x[:, 1])
        j = int(np.nanargmax(np.where(np.isfinite(current), current, np.inf))) if finite else int(
            np.argmax(~np.isfinite(current)))
        speed = np.abs(x[:, 2])
        out.append(
            SegmentPrediction(
                name=seg.name,
                locked=seg.locked,
                peak_current=float(current[j]) if finite else math.inf,
                peak_current_time=j / plan.sample_rate,
                peak_speed=float(np.max(speed)) if finite else math.inf,
                peak_electrical_step=float(motor.pole_pairs) * float(np.max(speed)) / plan.sample_rate
                if finite else math.inf,
                finite=finite,
                peak_torque=float(np.max(te)) if finite else math.inf,
            )
        )
    return tuple(out)


def _problems(plan: Plan, motor: MotorParams, segments: tuple[SegmentPrediction, ...]) -> tuple[str, ...]:
    problems = []
    for seg, s in zip(plan.segments, segments):
        where = f"segment '{s.name}'"
        if not s.finite:
            problems.append(f"{where}: the open-loop run goes unstable (the simulated state diverges); "
                            "lower the voltage or shorten the segment.")
            continue
        if s.peak_current > plan.current_limit:
            problems.append(f"{where}: predicted peak current {s.peak_current:.3g} A at "
                            f"t = {s.peak_current_time:.4g} s exceeds the current limit {plan.current_limit:.3g} A; "
                            "lower the voltage or shorten the segment.")
        if s.locked and plan.max_torque is not None and s.peak_torque > plan.max_torque:
            problems.append(f"{where}: the locked rotor's clamp would hold {s.peak_torque:.3g} N*m, above "
                            f"max_torque {plan.max_torque:.3g} N*m; lower the q-axis voltage of the segment.")
        if not s.locked:
            flux = float(motor.pole_pairs) * float(motor.lambda_m)
            no_load = plan.voltage_limit / flux if flux > 0 else math.inf  # no magnet: no back-EMF limit
            if plan.max_speed is not None and s.peak_speed > plan.max_speed:
                problems.append(f"{where}: the free spin-up runs away to {s.peak_speed:.4g} rad/s, above max_speed "
                                f"{plan.max_speed:.4g} rad/s; shorten the segment or lower v_q.")
            elif s.peak_speed > 1.05 * no_load:
                problems.append(f"{where}: the simulated speed {s.peak_speed:.4g} rad/s exceeds the no-load speed "
                                f"{no_load:.4g} rad/s the voltage limit allows: the open-loop run is unstable.")
            back_emf = float(motor.pole_pairs) * s.peak_speed * float(motor.lambda_m)
            if seg.inverter == "off" and back_emf > plan.voltage_limit:
                problems.append(f"{where}: the inverter is off but the back-EMF at {s.peak_speed:.4g} rad/s is "
                                f"{back_emf:.3g} V, outside the DC link's reach v_dc/sqrt(3) = "
                                f"{plan.voltage_limit:.3g} V: current would flow through the diodes and brake the "
                                "rotor; coast down from a lower speed or raise v_dc.")
            if s.peak_electrical_step > MAX_ELECTRICAL_STEP:
                problems.append(f"{where}: the rotor turns {s.peak_electrical_step:.2f} electrical rad per sample; "
                                f"raise the sample rate or keep the speed lower (at most {MAX_ELECTRICAL_STEP} rad).")
    return tuple(problems)


def assess_design(
    plan: Plan,
    motor: MotorParams,
    *,
    noise_sigma: float = 0.02,
    names: tuple[str, ...] = ESTIMATED,
    delay_samples: int = 0,
) -> DesignReport:
    """Judge ``plan`` on the nominal ``motor`` before any bench time.

    Args:
        plan: the experiment (the voltage circle is checked first and raises).
        motor: nominal motor, with its bench effects.
        noise_sigma: expected current-sensor noise (A), for the predicted intervals.
        names: parameters to estimate.
        delay_samples: the inverter's PWM/computation delay (samples).
    """
    plan.check_feasible()
    segments = predict_segments(plan, motor)
    experiment = Experiment.from_plan(plan, delay_samples=delay_samples)
    ident = assess_identifiability(experiment, motor, noise_sigma=noise_sigma, names=names)
    ident, law = law_verdict(ident, experiment, motor, tuple(names))
    notes = tuple(n for n in (motor_note(motor), law) if n)
    return DesignReport(plan=plan, motor=motor, segments=segments, problems=_problems(plan, motor, segments),
                        identifiability=ident, notes=notes)
