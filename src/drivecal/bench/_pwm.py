"""An independent switching-level PMSM bench: carrier-comparison PWM, dead time, device drops, sampling.

A plain-numpy/Python plant for tests and for users without hardware (issue 17,
item 6): ``drivecal simulate --inverter switching`` runs it. It shares no code
with drivecal's forward model or rollout, nor with the Jaxonomy engine bench:
it integrates the dq equations of DESIGN.md itself (fixed-step RK4 on a grid
that contains every switching instant), and takes from ``drivecal.physics``
only ``MotorParams`` and the one Clarke/Park pair. ``tests/bench/test_pwm.py``
ties its derivative to ``drivecal.physics.dq_derivatives`` and its averaged
mode to ``engine_bench``.

The inverter, per carrier period ``[t_k, t_k + T)``, ``T = 1 / sample_rate``
(one symmetric triangular carrier period per control sample):

* Computation delay: the period applies the command of sample
  ``k - delay_samples`` (0 V before the first one: each segment starts from rest).
  A half-sample delay (0.5, 1.5, ...: the duty register is loaded at the
  carrier valley, mid-period) applies the command of ``k - floor(delay) - 1``
  up to the valley and that of ``k - floor(delay)`` after it: the rising
  edges follow the one, the falling edges the other.
* Modulation: the command is taken to phase references at the rotor's
  electrical angle at mid-period, ``p * (theta_m(t_k) + w_m(t_k) * T / 2)``
  (a drive with an encoder does this), then to duty cycles ``d_x`` by sine-
  triangle (``d = 1/2 + v_x / V_dc``) or SVPWM (min-max zero-sequence injection:
  ``v_x - (max + min) / 2``), clipped to [0, 1].
* Center-aligned carrier comparison: the carrier ``c(tau) = |2 tau / T - 1|``
  is at its peak at the sample instants ``t_k``; leg x's gate is high while
  ``d_x > c``, i.e. on ``[(1 - d_x) T/2, (1 + d_x) T/2]`` of the period. The
  currents are sampled synchronously at the carrier peak (the instants
  ``t_k = k / sample_rate``, the middle of the zero vector), where the PWM
  ripple crosses the average current.
* Dead time ``t_dead`` (s) per switching edge: the incoming switch turns on
  ``t_dead`` after the outgoing one turns off; in between the leg's pole voltage
  follows its freewheeling diode, i.e. the phase current's sign:
  ``-V_dc/2`` for ``i_x > 0``, ``+V_dc/2`` for ``i_x < 0`` (relative to the DC
  mid-point), 0 for ``i_x == 0`` (no current, no defined diode: the mid-point).
  A dead interval running past the period's end is cut there (only for
  ``d_x > 1 - 2 t_dead / T``).
* Device forward drop ``v_f`` (V), switch or diode alike: the pole voltage
  loses ``v_f * sign(i_x)`` whenever the leg conducts.
* Phase-to-neutral voltages (wye winding, isolated neutral): the pole voltages
  minus their mean; then Clarke/Park at the instantaneous rotor angle.

With ``switching=False`` the inverter is the ideal averaged one of drivecal's
engine bench: the (delayed) commanded ``(v_d, v_q)`` held in the rotor frame over
each sample period; dead time and drops must then be zero.

All quantities are SI: s, V, A, rad, rad/s, ohm, H.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..data import BenchData, SegmentData
from ..errors import PlanError
from ..physics import MotorParams, abc_to_dq, dq_to_abc
from ..plan import INVERTER_MODULATIONS, Plan, Segment, inverter_setting_error

MODULATIONS = INVERTER_MODULATIONS  # the plan file's names


class SegmentRun(NamedTuple):
    """One segment on the switching plant, N samples.

    Attributes:
        t: sample instants from the segment start (s), shape (N,).
        states: ``[i_d, i_q, w_m, theta_m]`` at each sample instant (A, A, rad/s, rad), shape (N, 4).
        commands: commanded ``[v_d, v_q]`` of each sample (V), shape (N, 2) (what a drive logs).
        duty: duty cycles of legs a, b, c in period k (-), shape (N, 3); NaN for
            the last sample (no period follows it) and in the averaged mode.
        pole_error: per-period average pole voltage minus the ideal
            ``(d_x - 1/2) * V_dc`` (V), shape (N, 3); NaN where ``duty`` is.
        phase_error: per-period average phase-to-neutral voltage minus the phase
            reference of the command (V), shape (N, 3); NaN where ``duty`` is.
        i_abc: phase currents at the sample instants (A), shape (N, 3).
    """

    t: np.ndarray
    states: np.ndarray
    commands: np.ndarray
    duty: np.ndarray
    pole_error: np.ndarray
    phase_error: np.ndarray
    i_abc: np.ndarray


def plant_derivatives(state, v_dq, motor: MotorParams, locked: bool) -> tuple[float, float, float, float]:
    """The PMSM's dq equations (DESIGN.md) written out here, independently of ``drivecal.physics``.

    Args:
        state: ``(i_d, i_q, w_m, theta_m)`` (A, A, rad/s, rad), scalars or equal-shape arrays.
        v_dq: ``(v_d, v_q)`` applied (V).
        motor: the machine (R, Ld, Lq, lambda_m, pole_pairs, J, B, T_load used).
        locked: rotor clamped (speed and angle derivatives zero).

    Returns:
        ``(di_d/dt, di_q/dt, dw_m/dt, dtheta_m/dt)`` (A/s, A/s, rad/s^2, rad/s).
    """
    i_d, i_q, w_m, _ = state
    v_d, v_q = v_dq
    r, ld, lq, lam, p = float(motor.R), float(motor.Ld), float(motor.Lq), float(motor.lambda_m), float(motor.pole_pairs)
    w_e = p * w_m
    di_d = (v_d - r * i_d + w_e * lq * i_q) / ld
    di_q = (v_q - r * i_q - w_e * (ld * i_d + lam)) / lq
    if locked:
        return di_d, di_q, 0.0 * w_m, 0.0 * w_m
    torque = 1.5 * p * (lam * i_q + (ld - lq) * i_d * i_q)
    dw = (torque - float(motor.B) * w_m - float(motor.T_load)) / float(motor.J)
    return di_d, di_q, dw, w_m


def duty_cycles(v_abc: np.ndarray, v_dc: float, modulation: str = "svpwm") -> np.ndarray:
    """Leg duty cycles (-) of phase reference voltages ``v_abc`` (V), shape (..., 3) -> (..., 3).

    ``sine``: ``d = 1/2 + v_x / V_dc``; ``svpwm``: the same after adding the
    min-max zero sequence ``-(max + min) / 2``. Clipped to [0, 1].
    """
    v = np.asarray(v_abc, dtype=float)
    if modulation == "svpwm":
        v = v - 0.5 * (v.max(axis=-1, keepdims=True) + v.min(axis=-1, keepdims=True))
    elif modulation != "sine":
        raise PlanError(f"modulation must be one of {', '.join(MODULATIONS)}, got {modulation!r}; choose one of them.")
    return np.clip(0.5 + v / v_dc, 0.0, 1.0)


def switching_instants(duty: np.ndarray, period: float, t_dead: float, duty_fall: np.ndarray | None = None
                       ) -> np.ndarray:
    """Edges of each leg within the period (s from its start), shape (..., 3) -> (..., 3, 4).

    ``[a, a + t_dead, b, b + t_dead]`` with the gate high on ``[a, b]``,
    ``a = (1 - d) T/2``, ``b = (1 + d_fall) T/2`` (``d_fall = d`` unless the
    duty is reloaded at the valley), all clipped to ``[0, T]``.
    """
    d = np.asarray(duty, dtype=float)
    a = (1.0 - d) * period / 2.0
    b = (1.0 + (d if duty_fall is None else np.asarray(duty_fall, dtype=float))) * period / 2.0
    return np.clip(np.stack([a, a + t_dead, b, b + t_dead], axis=-1), 0.0, period)


def leg_modes(tau: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """State of each leg at period times ``tau`` (s), shape (M,) -> (M, 3): +1 high, -1 low, 0 dead.

    Args:
        tau: instants within the period (s), shape (M,).
        edges: :func:`switching_instants` of one period, shape (3, 4).
    """
    a, a_on, b, b_on = (edges[None, :, j] for j in range(4))
    t = np.asarray(tau, dtype=float)[:, None]
    high = (t >= a_on) & (t < b)
    low = (t < a) | (t >= b_on)
    return np.where(high, 1, np.where(low, -1, 0))


def pole_voltages(modes, i_abc, v_dc: float, v_f: float) -> list[float]:
    """Pole voltages (V, relative to the DC mid-point) of the three legs in ``modes`` carrying ``i_abc`` (A)."""
    out = []
    for m, i in zip(modes, i_abc):
        s = (i > 0.0) - (i < 0.0)
        v = 0.5 * v_dc * (m if m != 0 else -s)
        out.append(v - v_f * s)
    return out


def period_average_pole_error(duty: np.ndarray, i_abc: np.ndarray, v_dc: float, t_dead: float, v_f: float,
                              sample_rate: float) -> np.ndarray:
    """Per-period average pole-voltage error (V) of legs with ``duty`` carrying constant ``i_abc`` (A).

    Exact for currents that keep their sign over the period: ``-(V_dc * t_dead *
    f_pwm + v_f) * sign(i)`` for duties away from 0 and 1. Shapes (..., 3).
    """
    d = np.asarray(duty, dtype=float)
    period = 1.0 / sample_rate
    edges = switching_instants(d, period, t_dead)
    a, a_on, b, b_on = (edges[..., j] for j in range(4))
    s = np.sign(np.asarray(i_abc, dtype=float))
    high = np.maximum(b - a_on, 0.0)
    dead = (period - high) - (a + np.maximum(period - b_on, 0.0))
    mean = 0.5 * v_dc * (high - (period - high - dead) - s * dead) / period - v_f * s
    return mean - (d - 0.5) * v_dc


def _rk4(f, x, h):
    k1 = f(x)
    k2 = f([xi + 0.5 * h * ki for xi, ki in zip(x, k1[0])])
    k3 = f([xi + 0.5 * h * ki for xi, ki in zip(x, k2[0])])
    k4 = f([xi + h * ki for xi, ki in zip(x, k3[0])])
    new = [xi + h / 6.0 * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1[0], k2[0], k3[0], k4[0])]
    # The voltages as the integrator saw them, weighted like the state: their integral over the step.
    volts = [h / 6.0 * (a + 2.0 * b + 2.0 * c + d) for a, b, c, d in zip(k1[1], k2[1], k3[1], k4[1])]
    return new, volts


def check_inverter(sample_rate: float, v_dc: float, *, switching: bool = True, modulation: str = "svpwm",
                   delay_samples: float = 1, t_dead: float = 0.0, v_f: float = 0.0, substeps: int = 64) -> None:
    """Refuse inverter settings the plant cannot run, in one sentence naming the setting and the fix.

    Raises:
        PlanError: an unknown modulation; a delay that is not a multiple of half a
            sample; a dead time outside ``[0, T/2)`` or a device drop outside
            ``[0, V_dc/2)``; dead time or drops on the averaged inverter; fewer than
            one sub-step.
    """
    if modulation not in MODULATIONS:
        raise PlanError(f"modulation must be one of {', '.join(MODULATIONS)}, got {modulation!r}; choose one of them.")
    d = float(delay_samples)
    if not (math.isfinite(d) and d >= 0 and 2 * d == int(2 * d)):
        raise PlanError(f"delay_samples = {delay_samples!r}: the switching plant loads its duty cycles at the "
                        "carrier peak or valley, so the computation delay must be a multiple of 0.5 samples >= 0; "
                        "set delay_samples in the motor file to 0, 0.5, 1, 1.5, ...")
    bad = inverter_setting_error(t_dead, v_f, sample_rate, v_dc)
    if bad is not None:
        key, value, unit, reason = bad
        raise PlanError(f"{key} = {value:g} {unit}: {reason}")
    if not switching and (t_dead != 0.0 or v_f != 0.0):
        raise PlanError(f"the averaged inverter has no dead time or device drop (dead_time = {t_dead:g} s, "
                        f"device_drop = {v_f:g} V); choose the switching inverter, or set both to 0.")
    if int(substeps) != substeps or substeps < 1:
        raise PlanError(f"substeps = {substeps!r}: give a whole number of RK4 steps per carrier period >= 1 "
                        "(16 is accurate to 1e-13 A on the default motor).")


#: Motor fields the plant does not model, with what to do instead: (names, why, fix).
_UNMODELLED = (
    (("v_dead",), "is an averaged dead-time voltage, but on the switching plant the dead time is physical",
     "set v_dead = 0 and give the inverter's dead_time instead"),
    (("offset_d", "offset_q", "offset_a", "offset_b", "encoder_offset"),
     "is a sensor offset, and the switching plant's sensors are ideal", "set it to 0 or run the averaged inverter"),
    (("T_coulomb", "sat_d", "sat_q", "sat_dq"),
     "is a Coulomb friction or saturation term, and the switching plant's motor is linear with viscous friction",
     "set it to 0 or run the averaged inverter"),
)


def check_motor(plan: Plan, motor: MotorParams) -> None:
    """Refuse what the plant does not model, naming the motor field or the segment and the fix.

    The plant takes R at each segment's temperature (``alpha_R``, ``T_ref``); it
    runs every segment from rest with the inverter on; the motor's dead-time
    voltage, sensor offsets, Coulomb friction and saturation are not part of it.

    Raises:
        PlanError: a motor field or a segment the plant cannot run.
    """
    for names, why, fix in _UNMODELLED:
        for name in names:
            value = float(getattr(motor, name))
            if value != 0.0:
                raise PlanError(f"the motor sets {name} = {value:g}, which {why}; {fix}.")
    for seg in plan.segments:
        if seg.continues or seg.inverter != "on":
            raise PlanError(f"segment '{seg.name}': the switching plant runs each segment from rest with the "
                            "inverter on; remove continue and inverter = \"off\", or run the averaged inverter.")


def simulate_segment(segment: Segment, motor: MotorParams, sample_rate: float, v_dc: float, *,
                     switching: bool = True, modulation: str = "svpwm", delay_samples: float = 1,
                     t_dead: float = 0.0, v_f: float = 0.0, substeps: int = 64) -> SegmentRun:
    """Run one segment from rest on the switching plant (see the module docstring).

    Args:
        segment: the plan segment (duration, locked, per-sample or constant v_d, v_q).
        motor: the machine; its bench-effect fields (v_dead, offsets, alpha_R) are ignored here
            (:func:`pwm_bench` refuses them, and takes R at the segment's temperature).
        sample_rate: control/sampling rate = carrier frequency (Hz).
        v_dc: DC-link voltage (V).
        switching: carrier-comparison PWM (True) or the ideal averaged inverter (False).
        modulation: ``"svpwm"`` or ``"sine"``.
        delay_samples: computation delay (samples, a multiple of 0.5 >= 0).
        t_dead: dead time per switching edge (s).
        v_f: device forward drop (V).
        substeps: RK4 steps per carrier period on a uniform grid, to which every
            switching instant is added (so no step straddles an edge).
    """
    check_inverter(sample_rate, v_dc, switching=switching, modulation=modulation, delay_samples=delay_samples,
                   t_dead=t_dead, v_f=v_f, substeps=substeps)
    commands = segment.voltages(sample_rate)
    n = commands.shape[0]
    d = int(delay_samples)
    half = delay_samples != d  # the duty is reloaded at the valley
    applied = np.concatenate([np.zeros((d, 2)), commands])[:n]
    earlier = np.concatenate([np.zeros((d + 1, 2)), commands])[:n] if half else applied
    period = 1.0 / sample_rate
    p = float(motor.pole_pairs)
    locked = bool(segment.locked)
    grid = np.unique(np.append(np.linspace(0.0, period, int(substeps) + 1), period / 2.0))

    states = np.zeros((n, 4))
    duty = np.full((n, 3), np.nan)
    pole_err = np.full((n, 3), np.nan)
    phase_err = np.full((n, 3), np.nan)
    x = [0.0, 0.0, 0.0, 0.0]
    for k in range(n - 1):
        states[k] = x
        v_d, v_q = float(applied[k, 0]), float(applied[k, 1])
        if not switching:
            for t0, h in zip(grid[:-1].tolist(), np.diff(grid).tolist()):
                v = earlier[k] if t0 < period / 2.0 else applied[k]

                def f(s, v=(float(v[0]), float(v[1]))):
                    return plant_derivatives(s, v, motor, locked), (0.0,) * 6

                x, _ = _rk4(f, x, h)
            continue
        theta_mid = p * (x[3] + x[2] * period / 2.0)
        ref = np.array(dq_to_abc(v_d, v_q, theta_mid, xp=math))
        duty[k] = duty_cycles(ref, v_dc, modulation)
        rise = duty[k]
        if half:  # each half period's average is its own command's
            ref_before = np.array(dq_to_abc(float(earlier[k, 0]), float(earlier[k, 1]), theta_mid, xp=math))
            rise = duty_cycles(ref_before, v_dc, modulation)
            ref = 0.5 * (ref + ref_before)
        edges = switching_instants(rise, period, t_dead, duty_fall=duty[k])
        tau = np.unique(np.concatenate([grid, edges.ravel()]))
        tau = tau[np.concatenate([[True], np.diff(tau) > 1e-12 * period])]
        tau[-1] = period
        modes = leg_modes(0.5 * (tau[:-1] + tau[1:]), edges).tolist()
        integral = np.zeros(6)  # phase-to-neutral a, b, c and pole a, b, c volt-seconds over the period
        for h, mode in zip(np.diff(tau).tolist(), modes):
            def f(s, mode=mode):
                th = p * s[3]
                i_abc = dq_to_abc(s[0], s[1], th, xp=math)
                pole = pole_voltages(mode, i_abc, v_dc, v_f)
                common = (pole[0] + pole[1] + pole[2]) / 3.0
                phase = [v - common for v in pole]
                v_dq = abc_to_dq(phase[0], phase[1], phase[2], th, xp=math)
                return plant_derivatives(s, v_dq, motor, locked), (*phase, *pole)

            x, volts = _rk4(f, x, h)
            integral += volts
        pole_err[k] = integral[3:] / period - (0.5 * (rise + duty[k]) - 0.5) * v_dc
        phase_err[k] = integral[:3] / period - ref
    states[n - 1] = x
    i_abc = np.stack(dq_to_abc(states[:, 0], states[:, 1], p * states[:, 3], xp=np), axis=1)
    return SegmentRun(np.arange(n) * period, states, commands, duty, pole_err, phase_err, i_abc)


def pwm_bench(plan: Plan, motor: MotorParams, *, switching: bool = True, modulation: str = "svpwm",
              delay_samples: float = 1, t_dead: float = 0.0, v_f: float = 0.0, substeps: int = 64,
              noise: float = 0.0, seed: int = 1, record_speed: bool = False) -> BenchData:
    """The plan on the switching plant, as bench data (built as ``drivecal.bench.engine_bench`` builds it).

    Each segment starts from rest; the file records the COMMANDED ``v_d, v_q``
    of each sample and the currents sampled at the carrier peak, plus seeded
    Gaussian sensor noise of ``noise`` (A) when positive (``BenchData.add_noise``).
    Arguments as :func:`simulate_segment`; ``record_speed`` also records ``w_m``
    (rad/s) and ``theta_e`` (rad). R follows a segment's ``temperature``
    (``alpha_R``, ``T_ref``), which is recorded as ``engine_bench`` records it.

    Raises:
        PlanError: an infeasible plan, inverter settings the plant cannot run
            (:func:`check_inverter`), or motor fields and segments it does not
            model (:func:`check_motor`).
    """
    plan.check_feasible()
    check_inverter(plan.sample_rate, plan.v_dc, switching=switching, modulation=modulation,
                   delay_samples=delay_samples, t_dead=t_dead, v_f=v_f, substeps=substeps)
    check_motor(plan, motor)
    segments = []
    for seg in plan.segments:
        warm = motor
        if seg.temperature is not None:
            rise = float(seg.temperature) - float(motor.T_ref)
            warm = motor.replace(R=float(motor.R) * (1.0 + float(motor.alpha_R) * rise))
        run = simulate_segment(seg, warm, plan.sample_rate, plan.v_dc, switching=switching,
                               modulation=modulation, delay_samples=delay_samples, t_dead=t_dead, v_f=v_f,
                               substeps=substeps)
        theta_e = float(motor.pole_pairs) * run.states[:, 3]
        segments.append(SegmentData(
            name=seg.name, locked=seg.locked, t=run.t, voltages=run.commands,
            currents=run.states[:, :2].copy(),
            w_m=run.states[:, 2].copy() if record_speed else None,
            theta_e=theta_e if record_speed else None,
            temperature=None if seg.temperature is None else np.full(run.t.shape[0], float(seg.temperature)),
        ))
    data = BenchData(segments=tuple(segments), sample_rate=plan.sample_rate, source="switching PWM plant")
    return data.add_noise(noise, seed) if noise > 0.0 else data


__all__ = ["MODULATIONS", "SegmentRun", "check_inverter", "check_motor", "duty_cycles", "leg_modes",
           "period_average_pole_error", "plant_derivatives", "pole_voltages", "pwm_bench", "simulate_segment",
           "switching_instants"]
