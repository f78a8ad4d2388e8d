"""The forward model of a saturating machine: the flux linkages as states, the currents from the law.

Where the motor saturates (``Experiment.saturating``), the rollout integrates ``(psi_d, psi_q, w_m,
theta_m)`` with ``physics.flux_derivatives`` and reports the currents ``physics.currents_of_flux``
gives at each sample instant. One sequential scan over all samples, as ``_rollout_sequential``: the
segments' resets and carried states, a locked or free rotor, a measured speed as input, R at the
winding's temperature, the inverter's delay (the two sub-intervals of a fractional one), its dead
time and its off segments are handled alike. A segment starts from the flux of its initial currents
(``physics.flux_of_currents``; at rest ``(lambda_m, 0)``). With every saturation coefficient zero it
is the linear machine, to the rounding of its arithmetic (tests/model/test_flux_model.py).
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np

from ._experiment import Experiment, chain_starts
from ._scans import seeded
from ._steps import _quadratic, _rk4, _substeps, _with_delay
from ..physics import (MotorParams, bridge_error, currents_of_flux, flux_derivatives, flux_of_currents,
                       magnet_point, stable_dead_width)
from ..physics import resistance_at


def rollout_flux(motor: MotorParams, experiment: Experiment, keep: int, conducting: np.ndarray) -> jnp.ndarray:
    """The first ``keep`` of ``(i_d, i_q, w_m, theta_m)`` (A, A, rad/s, rad) at every sample, shape (M, keep).

    ``conducting``: 1.0 where the inverter conducts, 0.0 in its off segments, shape (M,) (host array).
    """
    dt = experiment.sample_period
    experiment, before = _with_delay(motor, experiment)
    v_before, fraction = before if before is not None else (experiment.voltages, 0.0)
    # The whole law only where it has an iron bridge or terms about zero flux; its correction at the magnet's
    # flux once, outside the scan.
    law = magnet_point(motor) if experiment.bridge else False
    psi_d0, psi_q0 = flux_of_currents(experiment.initial_state[:, 0], experiment.initial_state[:, 1], motor,
                                      bridge=law, loop=experiment.rolled)
    start_flux = jnp.stack([psi_d0, psi_q0, experiment.initial_state[:, 2], experiment.initial_state[:, 3]], axis=1)
    substeps = experiment.dead_time_substeps if experiment.dead_time else 1
    pieces_per_sample = 1 if before is None else 2
    if before is not None:
        substeps = max(1, substeps // 2)

    def step(x, sample):
        v_dq, v_earlier, locked, start, x0, speed, speed_input, temperature, theta_e_start, on = sample
        x = tuple(jnp.where(start, x0[i], x[i]) for i in range(4))
        # Inverter off: no current flows, so the flux sits at the magnet's (lambda_m, 0).
        x = (jnp.where(on > 0, x[0], motor.lambda_m), on * x[1], x[2], x[3])
        r = resistance_at(motor, temperature) if experiment.thermal else None

        def f_with(v, width):
            def f(state, w_measured):
                state = (state[0], state[1], jnp.where(speed_input > 0, w_measured, state[2]), state[3])
                applied = v
                if experiment.dead_time:
                    i_d, i_q = currents_of_flux(state[0], state[1], motor, bridge=law)
                    e_d, e_q = bridge_error(v[0], v[1], i_d, i_q, theta_e_start + motor.pole_pairs * state[3],
                                            motor.Ld, motor.Lq, dt, motor.v_dead, motor.i_dead, width)
                    applied = (v[0] + e_d, v[1] + e_q)
                d, _ = flux_derivatives(state, applied, motor, locked, resistance=r, bridge=law)
                return on * d[0], on * d[1], (1.0 - speed_input) * d[2], d[3]
            return f

        pieces = ((v_dq, 0.0, 1.0),) if before is None else ((v_earlier, 0.0, fraction), (v_dq, fraction, 1.0))
        def advance(x, v, a, b):
            stages = tuple(_quadratic(speed, u) for u in (a, 0.5 * (a + b), b))
            width = stable_dead_width(motor.i_dead, motor.v_dead, motor.Ld, motor.Lq, (b - a) * dt)
            return _rk4(f_with((v[0], v[1]), width), x, (b - a) * dt, stages, experiment.rolled)

        x_next = _substeps(advance, x, pieces[:pieces_per_sample], substeps)
        x_next = (x_next[0], x_next[1], jnp.where(speed_input > 0, speed[2], x_next[2]), x_next[3])
        i_d, i_q = currents_of_flux(x[0], x[1], motor, bridge=law)
        return x_next, jnp.stack((on * i_d, on * i_q, x[2], x[3])[:keep])

    inputs = (experiment.voltages, v_before, experiment.locked, chain_starts(experiment), start_flux,
              experiment.speed, experiment.speed_input, experiment.temperature, experiment.theta_e_start,
              jnp.asarray(conducting))
    x_init = seeded(tuple(start_flux[0, i] for i in range(4)), motor)
    _, states = jax.lax.scan(step, x_init, inputs)
    return states

