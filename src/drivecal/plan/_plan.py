"""Bench plans: segments of applied dq voltage, and their feasibility.

A plan is a list of segments run one after another on the bench, each from
rest unless it continues the one before (``continues``: a coast-down after a
spin-up starts at the speed the spin-up reached). In a segment the rotor is
either locked (standstill test: R, Ld, Lq) or free (spin-up: the only place
lambda_m shows; a coast-down: J and the friction). Voltages are commanded per
sample and held between samples, which is what an inverter's PWM does; with
the inverter off (``inverter = "off"``) its switches are open, no current
flows and the rotor coasts on its friction alone.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Sequence, Union

import numpy as np

from ..errors import PlanError

#: A voltage is a constant (V) or one value per sample (V), held between samples.
Voltage = Union[float, Sequence[float], np.ndarray]


@dataclasses.dataclass(frozen=True)
class Segment:
    """One bench segment.

    Attributes:
        name: label used in tables, files and error messages.
        duration: length of the segment (s); it holds ``round(duration * sample_rate)``
            samples at ``t_k = k / sample_rate``, k = 0, 1, ...
        locked: rotor clamped (True) or free to turn (False).
        v_d, v_q: applied d/q voltage (V): a constant, or a sequence with one
            value per sample, value k applied on ``[t_k, t_k+1)``.
        temperature: winding temperature during the segment (degC), or None
            when not controlled; R follows it (``motor.resistance_at``).
        continues: the segment starts where the previous one ended (currents,
            speed, angle and the delayed command carry over) instead of from rest;
            its first sample is one sample period after the previous one's last.
        inverter: "on" (the voltages are applied) or "off": the bridge's switches
            are open, no current flows (the back-EMF must stay inside the DC link:
            checked where the motor is known) and a free rotor coasts down on its
            friction; the voltages are then 0 (not applied).
    """

    name: str
    duration: float
    locked: bool
    v_d: Voltage = 0.0
    v_q: Voltage = 0.0
    temperature: float | None = None
    continues: bool = False
    inverter: str = "on"

    def num_samples(self, sample_rate: float) -> int:
        """Number of samples ``round(duration * sample_rate)``."""
        return int(round(self.duration * sample_rate))

    def voltages(self, sample_rate: float) -> np.ndarray:
        """Per-sample ``[v_d, v_q]`` (V), shape (num_samples, 2).

        Raises:
            PlanError: a per-sample sequence whose length is not num_samples.
        """
        n = self.num_samples(sample_rate)
        columns = []
        for axis, value in (("v_d", self.v_d), ("v_q", self.v_q)):
            arr = np.asarray(value, dtype=float)
            if arr.ndim == 0:
                arr = np.full(n, float(arr))
            elif arr.shape != (n,):
                raise PlanError(
                    f"segment '{self.name}': {axis} has {arr.size} values but the segment holds "
                    f"{n} samples ({self.duration} s at {sample_rate:g} Hz); give one value per sample "
                    "or a constant."
                )
            columns.append(arr)
        return np.stack(columns, axis=1)


#: The inverter models of ``drivecal simulate`` and the modulations of the switching one.
INVERTER_MODELS = ("averaged", "switching")
INVERTER_MODULATIONS = ("svpwm", "sine")


def inverter_setting_error(dead_time: float, device_drop: float, sample_rate: float,
                           v_dc: float) -> tuple[str, float, str, str] | None:
    """The first switching-inverter setting out of range, as ``(key, value, unit, reason)``; None if both hold.

    The dead time per edge (s) must lie in ``[0, T/2)`` of the carrier period ``T = 1 / sample_rate``
    (Hz), the device drop (V) in ``[0, V_dc/2)``. ``reason`` is the sentence's end, naming the limit
    and the fix; the plan file and the switching plant each put their own subject before it.
    """
    half_period = 0.5 / sample_rate
    if not (math.isfinite(dead_time) and 0.0 <= dead_time < half_period):
        return ("dead_time", dead_time, "s", "must be >= 0 and shorter than half the carrier period "
                f"({half_period:g} s at {sample_rate:g} Hz), got {dead_time:g} s; write e.g. "
                "dead_time = \"1 us\" (0 for none).")
    if not (math.isfinite(device_drop) and 0.0 <= device_drop < 0.5 * v_dc):
        return ("device_drop", device_drop, "V", f"must be >= 0 and below half the DC link ({0.5 * v_dc:g} V), got "
                f"{device_drop:g} V; write e.g. device_drop = \"0.7 V\" (0 for none).")
    return None


@dataclasses.dataclass(frozen=True)
class Inverter:
    """The bench's inverter as ``drivecal simulate`` runs it (a plan file's ``[inverter]`` table).

    The computation delay is the motor file's ``delay_samples``; the fit and the
    design do not read this table.

    Attributes:
        model: ``"averaged"`` (the commanded dq voltage held over each sample
            period, on the Jaxonomy engine; dead time as the motor's ``v_dead``) or
            ``"switching"`` (center-aligned carrier-comparison PWM with dead time
            per edge, device drops and sampling at the carrier peak:
            ``drivecal.bench.pwm_bench``).
        modulation: ``"svpwm"`` (min-max zero-sequence injection) or ``"sine"``
            (sine-triangle); used by the switching model.
        dead_time: dead time per switching edge (s), >= 0; switching model only.
        device_drop: forward drop of a conducting switch or diode (V), >= 0;
            switching model only.
    """

    model: str = "averaged"
    modulation: str = "svpwm"
    dead_time: float = 0.0
    device_drop: float = 0.0

    @property
    def is_default(self) -> bool:
        """The averaged, ideal inverter: plan files leave the table out."""
        return self == Inverter()

    def check(self) -> Inverter:
        """Raise :class:`PlanError` naming the first bad field and the fix; return self otherwise."""
        if self.model not in INVERTER_MODELS:
            raise PlanError(f"inverter model must be \"averaged\" or \"switching\", got {self.model!r}; "
                            "choose one of them.")
        if self.modulation not in INVERTER_MODULATIONS:
            raise PlanError(f"inverter modulation must be \"svpwm\" or \"sine\", got {self.modulation!r}; "
                            "choose one of them.")
        for key, value, unit, example in (("dead_time", self.dead_time, "s", "1 us"),
                                          ("device_drop", self.device_drop, "V", "0.7 V")):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise PlanError(f"inverter {key} must be a number of {unit} >= 0, got {value!r}; write e.g. "
                                f"{key} = \"{example}\" (0 for none).")
        return self


@dataclasses.dataclass(frozen=True)
class Plan:
    """A bench experiment: segments run in order at one sample rate.

    Attributes:
        segments: the segments, each starting from rest or continuing the previous one.
        sample_rate: current sampling (and voltage update) rate (Hz).
        v_dc: DC-link voltage (V); the inverter reaches ``|v_dq| <= v_dc / sqrt(3)``.
        current_limit: the bench's peak phase-current limit (A).
        max_speed: highest mechanical speed the bench allows on free segments
            (rad/s), or None for no stated limit.
        max_torque: the rotor clamp's torque limit (N*m): the largest electrical
            torque a locked segment may put on it, or None for no stated limit.
        inverter: the inverter ``drivecal simulate`` runs the plan on
            (:class:`Inverter`; by default the averaged, ideal one).
        current_noise: the current sensor's noise standard deviation (A) the
            plan was designed for, or None when not recorded: ``drivecal design``
            predicts its intervals at it and ``drivecal simulate`` adds it
            unless told otherwise.
    """

    segments: tuple[Segment, ...]
    sample_rate: float = 20_000.0
    v_dc: float = 48.0
    current_limit: float = 30.0
    max_speed: float | None = None
    inverter: Inverter = Inverter()
    max_torque: float | None = None
    current_noise: float | None = None

    @property
    def sample_period(self) -> float:
        """``1 / sample_rate`` (s)."""
        return 1.0 / self.sample_rate

    @property
    def voltage_limit(self) -> float:
        """Largest reachable ``|v_dq|`` with space-vector PWM, ``v_dc / sqrt(3)`` (V)."""
        return self.v_dc / math.sqrt(3.0)

    @property
    def num_samples(self) -> int:
        """Samples over all segments."""
        return sum(s.num_samples(self.sample_rate) for s in self.segments)

    def check_feasible(self) -> Plan:
        """Raise :class:`PlanError` naming the first infeasible segment; return self otherwise.

        Checks: positive sample rate and V_dc (and current noise, where recorded), at least one segment, unique names,
        at least two samples per segment, finite voltages, every commanded
        ``|v_dq|`` inside the voltage circle ``v_dc / sqrt(3)``, a first segment
        that does not continue another, inverter-off segments that continue
        a segment of the same rotor condition, with no voltage commanded, and
        the :class:`Inverter`'s fields.
        """
        if not (self.sample_rate > 0 and math.isfinite(self.sample_rate)):
            raise PlanError(f"sample_rate must be a positive number of Hz, got {self.sample_rate!r}.")
        if not (self.v_dc > 0 and math.isfinite(self.v_dc)):
            raise PlanError(f"v_dc must be a positive number of volts, got {self.v_dc!r}.")
        if self.max_torque is not None and not (self.max_torque > 0 and math.isfinite(self.max_torque)):
            raise PlanError(f"max_torque must be a positive number of N*m, got {self.max_torque!r}.")
        if self.current_noise is not None and not (self.current_noise > 0 and math.isfinite(self.current_noise)):
            raise PlanError(f"current_noise must be a positive number of amperes, got {self.current_noise!r}.")
        if not self.segments:
            raise PlanError("the plan has no segments; add at least one.")
        self.inverter.check()
        names = [s.name for s in self.segments]
        if len(set(names)) != len(names):
            raise PlanError(f"segment names must be unique, got {names}.")
        limit = self.voltage_limit
        for k, seg in enumerate(self.segments):
            _check_sequence(seg, self.segments[k - 1] if k else None)
            n = seg.num_samples(self.sample_rate)
            if n < 2:
                raise PlanError(
                    f"segment '{seg.name}': {seg.duration} s at {self.sample_rate:g} Hz is {n} sample(s); "
                    "make it at least two sample periods long."
                )
            v = seg.voltages(self.sample_rate)
            if not np.all(np.isfinite(v)):
                raise PlanError(f"segment '{seg.name}': voltages must be finite numbers.")
            magnitude = np.hypot(v[:, 0], v[:, 1])
            k = int(np.argmax(magnitude))
            if magnitude[k] > limit * (1.0 + 1e-12):
                raise PlanError(
                    f"segment '{seg.name}': |v_dq| reaches {magnitude[k]:.2f} V at t = {k / self.sample_rate:g} s, "
                    f"outside the voltage circle v_dc/sqrt(3) = {limit:.2f} V; lower the amplitude or raise v_dc."
                )
        return self


def _check_sequence(seg: Segment, previous: Segment | None) -> None:
    """A continuing or inverter-off segment where one can be: refused naming the segment and the fix."""
    if seg.inverter not in ("on", "off"):
        raise PlanError(f"segment '{seg.name}': inverter must be \"on\" or \"off\", got {seg.inverter!r}.")
    if seg.continues and previous is None:
        raise PlanError(f"segment '{seg.name}': the first segment cannot continue another; remove continue = true.")
    if seg.continues and seg.locked != previous.locked:
        raise PlanError(f"segment '{seg.name}' continues '{previous.name}' but one is locked and the other free; "
                        "a rotor cannot be clamped or released without stopping: start it from rest "
                        "(continue = false).")
    if seg.inverter == "off":
        if not seg.continues or seg.locked:
            raise PlanError(f"segment '{seg.name}': with the inverter off nothing moves unless the segment continues "
                            "a free one (a coast-down): set locked = false and continue = true after a spin-up.")
        if np.any(np.asarray(seg.v_d) != 0) or np.any(np.asarray(seg.v_q) != 0):
            raise PlanError(f"segment '{seg.name}': the inverter is off, so no voltage is applied; remove v_d and v_q "
                            "(or set inverter = \"on\" and v_d = v_q = 0 for short-circuit braking).")


def default_plan() -> Plan:
    """The standard three-segment calibration at 20 kHz.

    Locked d-step (8 V, 10 ms) for R and Ld, locked q-step (8 V, 10 ms) for Lq,
    free spin-up (v_q 12 V, 50 ms) for lambda_m.
    """
    return Plan(
        segments=(
            Segment("locked d-step", 0.010, locked=True, v_d=8.0, v_q=0.0),
            Segment("locked q-step", 0.010, locked=True, v_d=0.0, v_q=8.0),
            Segment("free spin-up", 0.050, locked=False, v_d=0.0, v_q=12.0),
        )
    )


def locked_q_step_plan() -> Plan:
    """A poor design: one locked q-step (8 V, 10 ms) and nothing else.

    No d-axis voltage leaves Ld invisible; a locked rotor leaves lambda_m
    invisible. Only R and Lq can be identified.
    """
    return Plan(segments=(Segment("locked q-step", 0.010, locked=True, v_d=0.0, v_q=8.0),))


def plan_to_dict(plan: Plan) -> dict[str, Any]:
    """A plan as JSON: sample rate (Hz), V_dc (V), current limit (A), segments; the current noise it was designed
    for (A) when recorded; the inverter when it is not the averaged, ideal one (dead time in s, device drop in V)."""
    segments = []
    for seg in plan.segments:
        entry = {"name": seg.name, "duration": seg.duration, "locked": seg.locked}
        if seg.temperature is not None:
            entry["temperature"] = float(seg.temperature)
        if seg.continues:
            entry["continue"] = True
        if seg.inverter != "on":
            entry["inverter"] = seg.inverter
        for axis in ("v_d", "v_q"):
            value = getattr(seg, axis)
            entry[axis] = float(value) if not hasattr(value, "__len__") else [float(v) for v in value]
        segments.append(entry)
    out = {
        "sample_rate": plan.sample_rate,
        "v_dc": plan.v_dc,
        "current_limit": plan.current_limit,
        "segments": segments,
    }
    if plan.max_speed is not None:
        out["max_speed"] = float(plan.max_speed)
    if plan.max_torque is not None:
        out["max_torque"] = float(plan.max_torque)
    if plan.current_noise is not None:
        out["current_noise"] = float(plan.current_noise)
    if not plan.inverter.is_default:
        out["inverter"] = dataclasses.asdict(plan.inverter)
    return out
