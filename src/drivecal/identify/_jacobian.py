"""The sensitivity Jacobian ``d(predicted currents)/d(theta)``, in one compiled pass with the currents.

Forward mode (a few parameters, thousands of outputs), kept on disk by ``model.cached_call``. The score tests'
Jacobian (``probing=True``: a bench effect's columns, the effect switched on) is the same function compiled
with other XLA options (:data:`PROBE_COMPILER_OPTIONS`) and each RK4 step's stages as a loop
(``Experiment.rolled``).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ..model import (RUN_ONCE, Experiment, cached_call, join_current_parts, predict_current_parts,
                     predict_currents, run_once_options)
from ..physics import ESTIMATED, MotorParams


def sensitivity_jacobian(motor: MotorParams, experiment: Experiment, names: tuple[str, ...] = ESTIMATED, *,
                         probing: bool = False) -> jnp.ndarray:
    """``d(i_d, i_q at every sample)/d(theta)``, shape (2M, len(names)), A per unit of theta.

    Rows alternate i_d, i_q sample by sample (the flattening of (M, 2)). With the measured speed
    as an output (``Experiment.speed_outputs``) the weighted speed's rows follow (K more rows, in
    the currents' units: ``speed_weight`` A per rad/s). ``probing``: a score test's columns (a bench
    effect's probes), compiled with :data:`PROBE_COMPILER_OPTIONS`.
    """
    return jacobian_and_outputs(motor, experiment, names, probing=probing)[0]


def jacobian_and_outputs(motor: MotorParams, experiment: Experiment, names: tuple[str, ...] = ESTIMATED, *,
                         probing: bool = False) -> tuple[jnp.ndarray, jnp.ndarray]:
    """:func:`sensitivity_jacobian` and the predicted outputs it is the derivative of (2M or 2M + K rows), in one pass."""
    if probing:  # RK4's stages as a loop: the dead time's program a fifth of the size (Experiment.rolled)
        experiment = dataclasses.replace(experiment, rolled=True)
        return cached_call(_sensitivity_jacobian, "probe_jacobian", motor, experiment, names=tuple(names),
                           compiler_options=PROBE_COMPILER_OPTIONS)
    return cached_call(_sensitivity_jacobian, "sensitivity_jacobian", motor, experiment, names=tuple(names),
                       compiler_options=run_once_options(experiment.dead_time))


def _jacobian(motor: MotorParams, experiment: Experiment, names: tuple[str, ...]) -> tuple[jnp.ndarray, jnp.ndarray]:
    theta = motor.vector(names)

    def currents(th):
        if not experiment.speed_outputs:
            return predict_currents(motor.with_vector(names, th), experiment).reshape(-1)
        # One rollout for both: the currents' parts laid end to end, then the weighted speed's.
        parts = predict_current_parts(motor.with_vector(names, th), experiment)
        speed = parts[len(parts) - len(experiment.speed_outputs):]
        return jnp.concatenate([join_current_parts(experiment, parts).reshape(-1), *speed])

    def with_value(th):
        out = currents(th)
        return out, out

    return jax.jacfwd(with_value, has_aux=True)(theta)


#: XLA:CPU options of the score tests' Jacobians (``probing=True``): a bench effect's columns, the effect
#: switched on in the rollout (``diagnose.effect_signatures``), compiled as a program that runs once
#: (``model.RUN_ONCE``: LLVM's level 0 and the legacy fusion emitters) with the dead time's rollout too. With
#: the legacy emitters, on examples/bench.csv, the delay's kernel compiled in 1.9 s against 3.7 s with the
#: default emitters, the dead time's in 3.3 s against 5.3 s (the same sizes, 1.3 and 3.9 MB); level 0 took a
#: cold fit of examples/bench.csv 10.4 -> 9.5 s (median of 2), a warm one as fast (each kernel runs once),
#: its score statistics moved in the 15th digit.
PROBE_COMPILER_OPTIONS = RUN_ONCE

#: Both Jacobians' function; ``cached_call`` compiles the score tests' with their options, cache or no cache.
_sensitivity_jacobian = jax.jit(_jacobian, static_argnames=("names",))
