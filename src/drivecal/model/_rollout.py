"""The differentiable forward model: predicted i_d, i_q at the sample instants.

All segments of an experiment are laid end to end in one sample axis of length
M, with a flag marking where each segment starts (the state is reset there to
the segment's initial state). The rollout follows the segment layout (static,
``Experiment.segments``), one ``jax.lax.scan`` per segment over its own
samples: where the rotor speed is known (locked rotor, or a measured speed as
input) only the two currents are integrated, and a free spin-up with
simulated speed integrates currents and speed (the angle only when asked for).
The parameter-only arithmetic is done once, outside the loops
(``motor.dq_coefficients``). Derivatives come either from forward mode
through the scans or, for a single motor, from the linearised steps
(``Experiment.linearised_tangents``). Without a layout (or with dead time,
which couples the currents to the angle) one scan covers the whole sample
axis. Everything ``jit``s, ``vmap``s and differentiates (``jax.jacfwd``).

Integration: classical RK4 with one step per sample period, the input held
between samples exactly as the inverter holds it. At 20 kHz and millisecond
electrical time constants its error is ~1e-9 A (see tests/model/test_forward.py).
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._experiment import Experiment, chain_starts, in_rotor_frame
from ._flux import rollout_flux
from ._lowered_cache import call as cached_call, run_once_options
from ._scans import _scan_affine_constant, _scan_linearised_tangents, _scan_states, seeded
from ._steps import _held, _quadratic, _rk4, _substeps, _with_delay
from ..physics import (DqCoefficients, MotorParams, bridge_error, dq_coefficients, dq_derivatives_from,
                       stable_dead_width)
from ..physics import encoder_frame, resistance_at, sensor_offsets, with_dq_offsets


# A jitted function: inside a trace, JAX traces it once per argument shape and statics, and every later call
# (the next sub-step's, the next kernel's in the same process) reuses that program. The dead-time model's
# kernels of examples/inverter_bench.csv (its solves, selection fits and score tests) call it in each: a
# cold fit 36.7 -> 33.8 s, the same bits. (The segments' steps and the dq equations jitted alike saved
# ~1 s of a cold fit of examples/bench.csv, bit for bit, but moved the D-optimal search of `design
# --optimize` along its flat valley: taken back.)
@functools.partial(jax.jit, static_argnames=("dead_time", "rolled"))
def rk4_step(
    state: tuple,
    v_dq: Any,
    motor: MotorParams,
    locked: Any,
    dt: Any,
    speed: Any = None,
    speed_input: Any = 0.0,
    *,
    theta_e_start: Any = 0.0,
    dead_time: bool = False,
    coefficients: DqCoefficients | None = None,
    conducting: Any = 1.0,
    period: Any = None,
    rolled: bool = False,
) -> tuple:
    """One classical Runge-Kutta step of length ``dt`` (s) with the input held.

    ``state`` is the tuple ``(i_d, i_q, w_m, theta_m)``; so is the result.
    Where ``speed_input`` is 1, the speed is not integrated but read from the
    measurement ``speed = (w_m(t), w_m(t + dt/2), w_m(t + dt))`` (rad/s) at
    the RK4 stages; J and B then drop out. With ``dead_time`` (static) the
    inverter's voltage error at the stage's currents and electrical angle
    ``theta_e_start + pole_pairs * theta_m`` (rad) is added to ``v_dq``.
    ``coefficients`` are ``dq_coefficients(motor)`` when already at hand.
    ``period`` (s): the PWM carrier period, for the dead-time error's ripple (``physics.bridge_error``).
    Where ``conducting`` is 0 the inverter is off: the currents are held at zero
    and only the rotor moves (a coast-down). ``rolled`` (static): RK4's stages as a loop (``_steps._rk4``).
    """
    c = dq_coefficients(motor) if coefficients is None else coefficients
    if speed is None:
        speed = (state[2], state[2], state[2])

    def f(x, w_measured):
        x = (conducting * x[0], conducting * x[1], jnp.where(speed_input > 0, w_measured, x[2]), x[3])
        v = v_dq
        if dead_time:
            e_d, e_q = bridge_error(v_dq[0], v_dq[1], x[0], x[1], theta_e_start + motor.pole_pairs * x[3], motor.Ld,
                                    motor.Lq, period, motor.v_dead, motor.i_dead,
                                    stable_dead_width(motor.i_dead, motor.v_dead, motor.Ld, motor.Lq, dt))
            v = (v_dq[0] + e_d, v_dq[1] + e_q)
        d = dq_derivatives_from(c, x, v, locked)
        return conducting * d[0], conducting * d[1], (1.0 - speed_input) * d[2], d[3]

    out = _rk4(f, tuple(state), dt, tuple(speed), rolled)
    return (conducting * out[0], conducting * out[1], jnp.where(speed_input > 0, speed[2], out[2]), out[3])


def simulate_states(motor: MotorParams, experiment: Experiment, keep: int = 4) -> jnp.ndarray:
    """Predicted state at every sample instant, shape (M, keep): the first ``keep`` of (A, A, rad/s, rad).

    ``keep=2`` gives the currents only, ``keep=3`` currents and speed. In the rotor frame: a phase
    file's encoder offset (``Experiment.encoder_offset``) is taken out of the inputs first.
    """
    return _rollout(motor, in_rotor_frame(motor, experiment), keep)


def _rollout(motor: MotorParams, experiment: Experiment, keep: int) -> jnp.ndarray:
    """The first ``keep`` state components at every sample instant, shape (M, keep).

    Segment by segment along ``experiment.segments`` (see the module
    docstring); one sequential scan over all samples where there is no layout
    or the dead-time model couples the currents to the rotor angle; the flux
    linkages as states where the motor saturates (``_flux``).
    """
    if experiment.saturating:
        return rollout_flux(motor, experiment, keep, _conducting(experiment))
    if experiment.segments is None or experiment.dead_time:
        return _rollout_sequential(motor, experiment, keep)
    parts = [jnp.stack(columns, axis=1) for columns in _segment_states(motor, experiment, keep)]
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts, axis=0)


def _segment_states(motor: MotorParams, experiment: Experiment, keep: int) -> list[tuple]:
    """Per segment of ``experiment.segments``, its first ``keep`` state components, arrays of shape (N_s,).

    A segment that the next one continues (``experiment.carried``) is rolled out one sample further:
    the state it arrives at is where the next one starts (currents, speed, angle).
    """
    experiment, before = _with_delay(motor, experiment)
    kinds = {"free": _free_segment, "coast": _coast_segment}
    out, carry = [], None
    for s, (start, stop, kind) in enumerate(experiment.segments):
        extend = s + 1 in experiment.carried
        x0 = carry if s in experiment.carried else None
        states = kinds.get(kind, _linear_segment)(motor, experiment, start, stop, 4 if extend else keep, before,
                                                  x0=x0, extend=extend)
        if extend:
            carry = tuple(x[-1] for x in states) + tuple(experiment.initial_state[start, len(states):])
            states = tuple(x[:-1] for x in states)
        out.append(tuple(states[:keep]))
    return out


def _start(experiment: Experiment, start: int, x0: tuple | None) -> tuple:
    """The state ``(i_d, i_q, w_m, theta_m)`` a segment starts from: carried over, or its ``initial_state``."""
    return tuple(experiment.initial_state[start, i] for i in range(4)) if x0 is None else tuple(x0)


def _coast_segment(motor: MotorParams, experiment: Experiment, start: int, stop: int, keep: int,
                   before: Any = None, x0: tuple | None = None, extend: bool = False) -> tuple:
    """States over an inverter-off segment (switches open: no current): ``keep`` arrays (N,), N + 1 with ``extend``.

    The currents are zero; the speed coasts on the friction alone (``J dw_m/dt = -B w_m - T_coulomb
    tanh(w_m / w_coulomb) - T_load``, RK4 per sample), or follows the measured speed where that is an input.
    """
    end = stop + 1 if extend else stop
    i_d, i_q, w0, theta0 = _start(experiment, start, x0)
    c = dq_coefficients(motor)

    def f(x, _):
        return dq_derivatives_from(c, (0.0, 0.0, x[0]), (0.0, 0.0), experiment.locked[start])[2:]

    def body(x, _):
        return _rk4(f, x, experiment.sample_period, (None, None, None), experiment.rolled), x

    w, theta = jax.lax.scan(body, seeded((w0, theta0), motor), None, length=end - start)[1]
    w = jnp.where(experiment.speed_input[start:end] > 0, experiment.speed[start:end, 0], w)
    zeros = jnp.zeros_like(w) + 0.0 * (i_d + i_q)
    return (zeros, zeros, w, theta)[:keep]


def _segment_coefficients(motor: MotorParams, experiment: Experiment, start: int, stop: int) -> DqCoefficients:
    """``dq_coefficients`` over samples ``start:stop``: R/Ld and R/Lq per sample, shape (N,), when thermal."""
    if experiment.thermal:
        motor = motor.replace(R=resistance_at(motor, experiment.temperature[start:stop]))
    return dq_coefficients(motor)


def _split_coefficients(c: DqCoefficients, thermal: bool) -> tuple[DqCoefficients, tuple]:
    """Loop-invariant coefficients and per-sample inputs: ``(R/Ld, R/Lq)`` (N,) each when thermal, else ()."""
    if not thermal:
        return c, ()
    return c._replace(r_ld=0.0, r_lq=0.0), (c.r_ld, c.r_lq)


def _linear_segment(motor: MotorParams, experiment: Experiment, start: int, stop: int, keep: int,
                    before: Any = None, x0: tuple | None = None, extend: bool = False) -> tuple:
    """States over a segment of known speed (locked rotor, or measured speed): ``keep`` arrays of shape (N,).

    Only the currents are integrated: the speed at the RK4 stages is an
    input, so one step is affine in the currents, and the angle is the RK4
    quadrature of the speed (a cumulative sum). ``x0``: the state carried over
    from the previous segment (else ``initial_state``); ``extend``: one sample
    more (where the next segment starts), shape (N + 1,).
    """
    x0 = jnp.stack(_start(experiment, start, x0))
    end = stop + 1 if extend else stop
    speed_input = experiment.speed_input[start:end] > 0
    # The speed at the three RK4 stages: measured, or the locked rotor's (constant) one.
    stages = tuple(jnp.where(speed_input, experiment.speed[start:end, j], x0[2]) for j in range(3))
    free = 1.0 - experiment.locked[start:end - 1]
    w = jnp.concatenate([x0[2:3], stages[2][:-1]])
    increments = (experiment.sample_period / 6.0) * (free * stages[0][:-1] + 2.0 * (free * stages[1][:-1])
                                                     + 2.0 * (free * stages[1][:-1]) + free * stages[2][:-1])
    theta = jnp.concatenate([x0[3:4], x0[3] + jnp.cumsum(increments)])
    c, per_sample = _split_coefficients(_segment_coefficients(motor, experiment, start, end), experiment.thermal)
    volts, params = _voltage_inputs(experiment, start, end, before, c)
    inputs = volts + stages + per_sample
    if experiment.linearised_tangents:
        scan = _scan_linearised_tangents
    elif _constant_linear_part(experiment, start, stop):
        scan = functools.partial(_scan_affine_constant, varying=len(volts))
    else:
        scan = _scan_states
    step = functools.partial(_linear_step, experiment.sample_period, experiment.thermal, before is not None,
                             experiment.rolled)
    i_d, i_q = scan(step, params, (x0[0], x0[1]), inputs)
    return (i_d, i_q, w, theta)[:keep]


def _voltage_inputs(experiment: Experiment, start: int, stop: int, before: Any, c: DqCoefficients
                    ) -> tuple[tuple, Any]:
    """The voltage inputs of a segment's scan, ``(v_d, v_q[, v_d_before, v_q_before])`` (N,) each, and its
    parameters: ``c``, or ``(c, fraction)`` with a fractional delay (see :func:`_held`)."""
    volts = (experiment.voltages[start:stop, 0], experiment.voltages[start:stop, 1])
    if before is None:
        return volts, c
    return volts + (before[0][start:stop, 0], before[0][start:stop, 1]), (c, before[1])


def _constant_linear_part(experiment: Experiment, start: int, stop: int) -> bool:
    """Whether every RK4 step of segment ``start:stop`` has the same linear part in the currents (static).

    So on a locked rotor (the speed at every stage is the segment's constant
    initial one) with R constant (no thermal model); a measured speed changes
    the step's coupling terms from sample to sample.
    """
    return not experiment.thermal and (start, stop, "locked") in (experiment.segments or ())


def _linear_step(dt: Any, thermal: bool, fractional: bool, loop: bool, params: Any, x: tuple, u: tuple) -> tuple:
    """One sample period of the currents ``x = (i_d, i_q)`` with the speed at the stages given (:func:`_held`).

    ``u = (v_d, v_q[, v_d_before, v_q_before], w_m(t), w_m(t + dt/2), w_m(t + dt)[, R/Ld, R/Lq])``;
    ``params`` as :func:`_voltage_inputs` gives them; ``loop``: RK4's stages as a loop (``_steps._rk4``).
    """
    c, before, u = _step_parts(params, u, fractional)
    if thermal:
        c = c._replace(r_ld=u[5], r_lq=u[6])

    def f_with(v):
        return lambda i, w_stage: dq_derivatives_from(c, (i[0], i[1], w_stage), v, True)[:2]

    return _held(f_with, x, dt, (u[0], u[1]), before, (u[2], u[3], u[4]), loop)


def _step_parts(params: Any, u: tuple, fractional: bool) -> tuple[DqCoefficients, Any, tuple]:
    """``(coefficients, before, u)`` of a step: ``before = ((v_d, v_q) before, fraction)`` or None, and
    ``u`` without the earlier voltages."""
    if not fractional:
        return params, None, u
    c, fraction = params
    return c, ((u[2], u[3]), fraction), u[:2] + u[4:]


def _free_segment(motor: MotorParams, experiment: Experiment, start: int, stop: int, keep: int,
                  before: Any = None, x0: tuple | None = None, extend: bool = False) -> tuple:
    """States over a free segment with simulated speed (w_m * i products: nonlinear): ``keep`` arrays (N,).

    The rotor angle is integrated only when it is kept (nothing else reads it
    without dead time). ``x0``, ``extend`` as :func:`_linear_segment`.
    """
    dims = 4 if keep == 4 else 3
    end = stop + 1 if extend else stop
    c, per_sample = _split_coefficients(_segment_coefficients(motor, experiment, start, end), experiment.thermal)
    volts, params = _voltage_inputs(experiment, start, end, before, c)
    x0 = _start(experiment, start, x0)[:dims]
    scan = _scan_linearised_tangents if experiment.linearised_tangents else _scan_states
    step = functools.partial(_free_step, experiment.sample_period, experiment.thermal, before is not None,
                             experiment.rolled)
    states = scan(step, params, x0, volts + per_sample)
    return tuple(states[:keep])


def _free_step(dt: Any, thermal: bool, fractional: bool, loop: bool, params: Any, x: tuple, u: tuple) -> tuple:
    """One sample period of ``x = (i_d, i_q, w_m[, theta_m])``; ``u = (v_d, v_q[, v_d_before, v_q_before][, R/Ld, R/Lq])``."""
    c, before, u = _step_parts(params, u, fractional)
    if thermal:
        c = c._replace(r_ld=u[2], r_lq=u[3])

    def f_with(v):
        return lambda state, _: dq_derivatives_from(c, state, v, False)[: len(x)]

    return _held(f_with, x, dt, (u[0], u[1]), before, (None, None, None), loop)


def _rollout_sequential(motor: MotorParams, experiment: Experiment, keep: int) -> jnp.ndarray:
    """``_rollout`` as one sequential scan over all M samples, resetting at segment starts.

    Any experiment (no layout needed) and any model (dead time included).
    Only what is kept is written out per step: for the currents alone
    (``keep=2``) a batched Jacobian sweep stores half the tangents.
    """
    dt = experiment.sample_period
    coefficients = dq_coefficients(motor)
    experiment, before = _with_delay(motor, experiment)
    v_before, fraction = before if before is not None else (experiment.voltages, 0.0)

    def step(x, sample):
        v_dq, v_earlier, locked, start, x0, speed, speed_input, temperature, theta_e_start, conducting = sample
        x = tuple(jnp.where(start, x0[i], x[i]) for i in range(4))
        x = (conducting * x[0], conducting * x[1], x[2], x[3])
        # R follows the winding temperature sample by sample (NaN: not recorded).
        warm = motor.replace(R=resistance_at(motor, temperature)) if experiment.thermal else motor
        c = dq_coefficients(warm) if experiment.thermal else coefficients
        # The dead time's smooth sign turns within a fraction of a sample where a current crosses
        # zero; sub-steps keep RK4 within 1e-6 A of the engine there (3e-5 A with one step).
        substeps = experiment.dead_time_substeps if experiment.dead_time else 1
        # With a fractional delay the earlier command acts for the first part of the period (see _held),
        # each part with half the sub-steps: the same RK4 work per sample (and a program XLA:CPU runs well:
        # 2 x 4 sub-steps with the dead time compiled in 54 s and then ran out of memory under forward mode).
        pieces = ((v_dq, 0.0, 1.0),) if before is None else ((v_earlier, 0.0, fraction), (v_dq, fraction, 1.0))
        if before is not None:
            substeps = max(1, substeps // 2)

        def advance(x, v, a, b):
            stages = tuple(_quadratic(speed, u) for u in (a, 0.5 * (a + b), b))
            return rk4_step(x, v, warm, locked, (b - a) * dt, stages, speed_input, theta_e_start=theta_e_start,
                            dead_time=experiment.dead_time, coefficients=c, conducting=conducting, period=dt,
                            rolled=experiment.rolled)

        return _substeps(advance, x, pieces, substeps), jnp.stack(x[:keep])

    inputs = (
        experiment.voltages,
        v_before,
        experiment.locked,
        chain_starts(experiment),  # a continuing segment carries the state on
        experiment.initial_state,
        experiment.speed,
        experiment.speed_input,
        experiment.temperature,
        experiment.theta_e_start,
        jnp.asarray(_conducting(experiment)),
    )
    x_init = seeded(tuple(experiment.initial_state[0, i] for i in range(4)), motor)
    _, states = jax.lax.scan(step, x_init, inputs)
    return states


def _conducting(experiment: Experiment) -> np.ndarray:
    """1.0 where the inverter conducts, 0.0 in its inverter-off ("coast") segments, shape (M,) (static)."""
    on = np.ones(experiment.num_samples)
    for start, stop, kind in experiment.segments or ():
        if kind == "coast":
            on[start:stop] = 0.0
    return on


def predict_currents(motor: MotorParams, experiment: Experiment) -> jnp.ndarray:
    """Predicted measured ``[i_d, i_q]`` (A) at every sample instant, shape (M, 2).

    The motor's currents plus what the current sensors add: the dq offsets,
    and the phase offsets rotated into dq by the electrical angle (measured
    where the bench file has one, else simulated). With a phase file's encoder
    offset (``Experiment.encoder_offset``) the rollout runs in the rotor frame
    and its currents are turned into the file's frame.
    """
    # The rotor angle (state 3) is written out only when phase offsets need it.
    states = _rollout(motor, in_rotor_frame(motor, experiment), 4 if experiment.phase_offsets else 2)
    return measured_currents(states, motor, experiment)


def _segmented(experiment: Experiment) -> bool:
    """Whether :func:`predict_current_parts` splits by segment (else one part over all samples; static)."""
    return (experiment.segments is not None and not experiment.dead_time and not experiment.phase_offsets
            and not experiment.saturating            and not experiment.encoder_offset)


def predict_current_parts(motor: MotorParams, experiment: Experiment) -> tuple:
    """:func:`predict_currents` as ``(i_d, i_q)`` per segment, flattened: 2 x segments arrays of shape (N_s,) (A).

    The same numbers, not laid end to end: in a ``vmap``-ped batch the
    segments' rollouts come out time-major, and joining them into (M, 2) per
    motor costs a transposing copy of every Jacobian sweep. One part pair
    over all M samples where the rollout is one scan or the phase offsets
    need the angle. :func:`current_parts` splits measured currents alike.
    With the measured speed as an output (``Experiment.speed_outputs``) the
    predicted speed of each such segment follows, times ``speed_weight``
    (A per rad/s): the residuals of currents and speed then share one scale.
    """
    if not _segmented(experiment):
        if not experiment.speed_outputs:
            predicted = predict_currents(motor, experiment)
            return predicted[:, 0], predicted[:, 1]
        states = _rollout(motor, in_rotor_frame(motor, experiment), 4)
        predicted = measured_currents(states, motor, experiment)
        return (predicted[:, 0], predicted[:, 1]) + _speed_parts(experiment, states[:, 2])
    keep = 3 if experiment.speed_outputs else 2
    states = _segment_states(motor, experiment, keep)
    currents = tuple(x for state in states for x in with_dq_offsets(state[0], state[1], motor))
    return currents + tuple(experiment.speed_weight * states[s][2] for s in experiment.speed_outputs)


def _speed_parts(experiment: Experiment, speed: Any) -> tuple:
    """The speed (rad/s, shape (M,)) of each segment whose measured speed is an output, times ``speed_weight``."""
    return tuple(experiment.speed_weight * speed[experiment.segments[s][0]:experiment.segments[s][1]]
                 for s in experiment.speed_outputs)


def current_parts(experiment: Experiment, currents: Any) -> tuple:
    """Measured ``[i_d, i_q]`` (A), shape (M, 2), split as :func:`predict_current_parts` splits its prediction
    (and the measured speed of the segments where it is an output, weighted alike)."""
    speed = _speed_parts(experiment, experiment.speed[:, 0])
    if not _segmented(experiment):
        return (currents[:, 0], currents[:, 1]) + speed
    return tuple(currents[start:stop, j] for start, stop, _ in experiment.segments for j in (0, 1)) + speed


def join_current_parts(experiment: Experiment, parts: tuple) -> Any:
    """Parts as :func:`current_parts` splits them, laid end to end again: shape (M, 2) (A); the speed parts
    (measured speed as an output) are left out."""
    if not _segmented(experiment):
        return jnp.stack(parts[:2], axis=1)
    pairs = [jnp.stack(parts[2 * s : 2 * s + 2], axis=1) for s in range(len(experiment.segments))]
    return pairs[0] if len(pairs) == 1 else jnp.concatenate(pairs, axis=0)


def predicted_currents(motor: MotorParams, experiment: Experiment) -> np.ndarray:
    """:func:`predict_currents` compiled, for host code: a numpy array, shape (M, 2) (A).

    Called outside ``jit``, ``predict_currents`` runs op by op and compiles its
    scans afresh on every call (~1 s each); this is one compiled call whose
    trace is kept on disk (``cached_call``).
    """
    return np.asarray(cached_call(_predict_compiled, "predict_currents", motor, experiment,
                                  compiler_options=run_once_options(experiment.dead_time)))


_predict_compiled = jax.jit(predict_currents)


def simulated_states(motor: MotorParams, experiment: Experiment) -> np.ndarray:
    """:func:`simulate_states` compiled, for host code: all four states at every sample, a numpy array (M, 4).

    One compiled call whose trace is kept on disk (``cached_call``), compiled with JAX's defaults (the numbers
    of ``jax.jit(simulate_states)``): a warm ``drivecal plan`` traced and lowered each plan it judged again.
    """
    return np.asarray(cached_call(_states_compiled, "simulate_states", motor, experiment))


_states_compiled = jax.jit(simulate_states)


def measured_currents(states: jnp.ndarray, motor: MotorParams, experiment: Experiment) -> jnp.ndarray:
    """``[i_d, i_q]`` (A) the sensors report for simulated ``states``: the currents plus offsets, (M, 2).

    ``states`` has shape (M, 4), or (M, 2) (currents only) when the experiment
    does not model phase offsets. They are in the rotor frame; with a phase file's
    encoder offset (``Experiment.encoder_offset``) the currents are turned into the
    file's frame (``physics.encoder_frame``) before the offsets, which the sensors
    add there, are added (the phase offsets at the file's own angle).
    """
    i_d, i_q = states[:, 0], states[:, 1]
    if experiment.encoder_offset:
        i_d, i_q = encoder_frame(i_d, i_q, motor.encoder_offset)
    if not experiment.phase_offsets:
        return jnp.stack(with_dq_offsets(i_d, i_q, motor), axis=-1)
    theta = jnp.where(jnp.isnan(experiment.theta_e), experiment.theta_e_start + motor.pole_pairs * states[:, 3],
                      experiment.theta_e)
    d_offset, q_offset = sensor_offsets(theta, motor)
    return jnp.stack([i_d + d_offset, i_q + q_offset], axis=-1)
