"""Firmware hand-off of a current-loop design: feed-forward, voltage limits, per-unit and fixed-point gains, C header.

Decoupling feed-forward (rotor dq frame, amplitude-invariant, electrical speed
``w_e`` in rad/s; the cross terms of :mod:`drivecal.physics`' dq equations)::

    v_d_ff = -w_e * Lq * i_q          v_q_ff = w_e * (Ld * i_d + lambda_m)

Added to the PI outputs, it cancels the speed voltages, so each axis is the
``1/(L s + R)`` plant the gains were designed for.

Voltage limit (anti-windup): a space-vector modulator in its linear range
makes any dq voltage of magnitude up to ``V_max = V_dc / sqrt(3)``. The output
is limited to that circle, d axis first (``|v_d| <= V_max``,
``|v_q| <= sqrt(V_max^2 - v_d^2)``); the integrator holds while its axis is in
the limit and the error pushes further into it (conditional integration), and
its state is clamped to ``+-V_max``.

Per unit, for a base current ``I_b`` (A), voltage ``V_b`` (V) and, for the
feed-forward, electrical angular frequency ``w_b = 2 pi f_b`` (rad/s)::

    Kp_pu = Kp I_b / V_b      (Ki Ts)_pu = Ki Ts I_b / V_b      V_max_pu = V_max / V_b
    L_pu = L w_b I_b / V_b    lambda_pu = lambda_m w_b / V_b     (w_e_pu = w_e / w_b)

Fixed point: each per-unit constant ``x`` is an integer ``q`` and a shift
``s`` with ``x ~= q / 2^s`` and ``|q| <= 2^n - 1`` (``n`` = 15 for Q15: an
int16); ``s`` is the largest that fits, so the error is at most half an LSB
``2^-s``. On Qn signals: ``y_qn = ((int32) q * x_qn) >> s``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from ..errors import DrivecalError
from ..results import Calibration
from ._gains import CurrentLoopDesign

#: sqrt(3): the voltage circle of a linear space-vector modulator has radius V_dc / sqrt(3).
SQRT3 = math.sqrt(3.0)
#: Accepted fixed-point widths (bits after the sign): Q7 (int8) to Q31 (int32).
Q_BITS_RANGE = (7, 31)


def to_fixed(value: float, bits: int = 15) -> tuple[int, int]:
    """``(q, shift)`` with ``value ~= q / 2**shift``, ``|q| <= 2**bits - 1`` and the largest such shift.

    The error is at most half an LSB (``2**-shift / 2``). Zero gives ``(0, bits)``.
    """
    top = 2**bits - 1
    if value == 0:
        return 0, bits
    if not math.isfinite(value):
        raise ValueError(f"cannot represent {value!r} in fixed point")
    shift = math.floor(math.log2(top / abs(value)))
    while abs(round(value * 2.0**shift)) > top:
        shift -= 1
    return int(round(value * 2.0**shift)), shift


@dataclasses.dataclass(frozen=True)
class FirmwareConstant:
    """One firmware constant: SI value and uncertainty, per-unit value, fixed-point representation.

    Attributes:
        name: C name stem, e.g. ``KP_D``.
        value, se: SI value and its first-order standard deviation (NaN: unknown), unit ``unit``.
        unit: SI unit.
        meaning: one line.
        pu_factor: per-unit value = SI value times this (None: no per-unit form).
        bits: fixed-point width (None: no fixed point).
    """

    name: str
    value: float
    se: float
    unit: str
    meaning: str
    pu_factor: float | None = None
    bits: int | None = None

    @property
    def pu(self) -> float | None:
        return None if self.pu_factor is None else self.value * self.pu_factor

    @property
    def fixed(self) -> tuple[int, int] | None:
        return None if self.pu is None or self.bits is None else to_fixed(self.pu, self.bits)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"value": self.value, "se": self.se if math.isfinite(self.se) else None,
                               "unit": self.unit, "meaning": self.meaning}
        if self.pu is not None:
            out["pu"] = self.pu
            out["pu_se"] = self.se * self.pu_factor if math.isfinite(self.se) else None
        if self.fixed is not None:
            q, shift = self.fixed
            out["fixed"] = {"q": q, "shift": shift, "value": q / 2.0**shift, "lsb": 2.0**-shift}
        return out


@dataclasses.dataclass(frozen=True)
class FirmwareGains:
    """What a firmware engineer pastes: the gains, feed-forward, limits, per-unit and fixed-point forms.

    Attributes:
        design: the current-loop design (gains and their uncertainty).
        constants: every constant, in header order.
        v_dc, v_dc_source: DC-link voltage (V) and where it came from; None: no voltage limit.
        base_current, base_voltage, base_frequency_hz: the per-unit base (A, V, Hz electrical), or None.
        q_bits: fixed-point width (bits after the sign), or None.
    """

    design: CurrentLoopDesign
    constants: tuple[FirmwareConstant, ...]
    v_dc: float | None
    v_dc_source: str
    base_current: float | None
    base_voltage: float | None
    base_frequency_hz: float | None
    q_bits: int | None

    def constant(self, name: str) -> FirmwareConstant:
        return next(c for c in self.constants if c.name == name)

    def to_dict(self) -> dict[str, Any]:
        """The ``firmware`` section of the gains JSON (SI; per-unit and fixed point where a base is given)."""
        v_max = None if self.v_dc is None else self.v_dc / SQRT3
        return {
            "feed_forward": {"v_d": "-w_e * Lq * i_q", "v_q": "w_e * (Ld * i_d + lambda_m)",
                             "w_e": "electrical angular speed, rad/s"},
            "voltage_limit": {"v_dc": self.v_dc, "v_dc_source": self.v_dc_source, "v_max": v_max,
                              "rule": "|v_dq| <= V_dc/sqrt(3), d axis first; integrator clamped to +-v_max and held "
                                      "while its axis is limited"},
            "per_unit": None if self.base_current is None else {
                "base_current": self.base_current, "base_voltage": self.base_voltage,
                "base_frequency_hz": self.base_frequency_hz},
            "fixed_point": None if self.q_bits is None else {
                "format": f"Q{self.q_bits}", "bits": self.q_bits, "max_q": 2**self.q_bits - 1,
                "rule": "pu ~= q / 2^shift; on Qn signals y = (q * x) >> shift"},
            "constants": {c.name: c.to_dict() for c in self.constants},
        }


def _plain(cal: Calibration, name: str) -> tuple[float, float]:
    """A parameter's estimate and standard error (NaN when not fitted), falling back to the prior."""
    if name in cal.names:
        i = cal.names.index(name)
        value, se = float(cal.estimate[i]), float(cal.se[i])
        if math.isfinite(value):
            return value, se if name in cal.fit_names else math.nan
    return float(getattr(cal.prior, name)), math.nan


def firmware_gains(design: CurrentLoopDesign, cal: Calibration, *, v_dc: float | None = None,
                   v_dc_source: str = "--vdc", base_current: float | None = None, base_voltage: float | None = None,
                   base_frequency_hz: float | None = None, q_bits: int | None = None) -> FirmwareGains:
    """The firmware constants of a discrete design.

    Args:
        design: a design with a sample rate.
        cal: the calibration it was made from (Ld, Lq, lambda_m for the feed-forward).
        v_dc: DC-link voltage (V), for the voltage limit; None: no limit.
        v_dc_source: where ``v_dc`` came from, in words.
        base_current, base_voltage: per-unit base (A, V), both or neither.
        base_frequency_hz: electrical base frequency (Hz) of the per-unit feed-forward; None: SI only.
        q_bits: fixed-point width (7 to 31; 15 for Q15); needs the per-unit base. None: 15 with a base.

    Raises:
        DrivecalError: no sample rate, a base current without a base voltage (or the reverse), a
            fixed point or base frequency without a base, a width out of range, a non-positive number.
    """
    if design.sample_rate_hz is None:
        raise DrivecalError("firmware constants need --sample-rate (the integrator step Ki*Ts).")
    for option, x in (("--vdc", v_dc), ("--base-current", base_current), ("--base-voltage", base_voltage),
                      ("--base-frequency", base_frequency_hz)):
        if x is not None and not (x > 0 and math.isfinite(x)):
            raise DrivecalError(f"{option} {x}: must be a positive number.")
    if (base_current is None) != (base_voltage is None):
        raise DrivecalError("per-unit gains need both --base-current and --base-voltage; give both or neither.")
    if base_current is None and (q_bits is not None or base_frequency_hz is not None):
        option = "--q-format" if q_bits is not None else "--base-frequency"
        raise DrivecalError(f"{option} needs the per-unit base: give --base-current and --base-voltage too.")
    if base_current is not None and q_bits is None:
        q_bits = 15
    if q_bits is not None and not Q_BITS_RANGE[0] <= q_bits <= Q_BITS_RANGE[1]:
        raise DrivecalError(f"--q-format Q{q_bits}: choose Q{Q_BITS_RANGE[0]} to Q{Q_BITS_RANGE[1]}, e.g. Q15.")
    ts = 1.0 / design.sample_rate_hz
    gain_pu = None if base_current is None else base_current / base_voltage
    volt_pu = None if base_voltage is None else 1.0 / base_voltage
    w_b = None if base_frequency_hz is None else 2.0 * math.pi * base_frequency_hz
    ff_pu = {"H": None if w_b is None else w_b * gain_pu, "Wb": None if w_b is None else w_b * volt_pu}
    out = []
    for ax in design.axes:
        a = ax.axis.upper()
        out += [FirmwareConstant(f"KP_{a}", ax.kp, ax.kp_se, "V/A", f"{ax.axis}-axis proportional gain", gain_pu,
                                 q_bits),
                FirmwareConstant(f"KI_{a}", ax.ki, ax.ki_se, "V/(A*s)", f"{ax.axis}-axis integral gain"),
                FirmwareConstant(f"KI_TS_{a}", ax.ki * ts, ax.ki_se * ts, "V/A",
                         f"{ax.axis}-axis integrator step Ki*Ts per sample", gain_pu, q_bits)]
    for name, pname, unit, meaning in (("LD", "Ld", "H", "d-axis inductance (feed-forward)"),
                                       ("LQ", "Lq", "H", "q-axis inductance (feed-forward)"),
                                       ("LAMBDA_M", "lambda_m", "Wb", "magnet flux linkage (feed-forward)")):
        value, se = _plain(cal, pname)
        out.append(FirmwareConstant(name, value, se, unit, meaning, ff_pu[unit], q_bits if w_b is not None else None))
    if v_dc is not None:
        out.append(FirmwareConstant("V_MAX", v_dc / SQRT3, math.nan, "V",
                            "voltage-circle radius V_dc/sqrt(3): output and integrator limit", volt_pu, q_bits))
    return FirmwareGains(design, tuple(out), v_dc, v_dc_source if v_dc is not None else "not given (no limit)",
                         base_current, base_voltage, base_frequency_hz, q_bits)
