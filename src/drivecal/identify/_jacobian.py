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
import numpy as np

from ..model import (RUN_ONCE, Experiment, cached_call, join_current_parts, predict_current_parts,
                     predict_currents, run_once_options)
from ..physics import ESTIMATED, MotorParams


#: Parameters the model adds to the predicted currents and to nothing else (the dq current sensors' offsets,
#: ``physics.with_dq_offsets``, added last): each one's column is 1 on its axis's current rows and 0 on the
#: others, exactly what forward mode gives. Written down, not compiled: a fit's kernel with the offsets is the
#: kernel without them (examples/inverter_bench.csv, whose selection adds them to a model with the dead time:
#: two kernels fewer, its offsets' score test and the fit with them; a cold fit 13.4 -> 11.8 s, warm 3.71 ->
#: 3.53 s, examples/bench.csv's 3.85 -> 3.59 s and 1.10 -> 1.04 s, A/B medians; fit --json bit for bit).
ADDITIVE: dict[str, int] = {"offset_d": 0, "offset_q": 1}


def sensitivity_jacobian(motor: MotorParams, experiment: Experiment, names: tuple[str, ...] = ESTIMATED, *,
                         probing: bool = False) -> np.ndarray | jnp.ndarray:
    """``d(i_d, i_q at every sample)/d(theta)``, shape (2M, len(names)), A per unit of theta.

    Rows alternate i_d, i_q sample by sample (the flattening of (M, 2)). With the measured speed
    as an output (``Experiment.speed_outputs``) the weighted speed's rows follow (K more rows, in
    the currents' units: ``speed_weight`` A per rad/s). ``probing``: a score test's columns (a bench
    effect's probes), compiled with :data:`PROBE_COMPILER_OPTIONS`. Only :data:`ADDITIVE` names: no program.
    """
    names = tuple(names)
    if names and all(n in ADDITIVE for n in names):
        speed_rows = sum(experiment.segments[s][1] - experiment.segments[s][0] for s in experiment.speed_outputs)
        return _with_additive(np.zeros((2 * experiment.num_samples + speed_rows, 0)), (), names, experiment)
    return jacobian_and_outputs(motor, experiment, names, probing=probing)[0]


def jacobian_and_outputs(motor: MotorParams, experiment: Experiment, names: tuple[str, ...] = ESTIMATED, *,
                         probing: bool = False) -> tuple[np.ndarray | jnp.ndarray, jnp.ndarray]:
    """:func:`sensitivity_jacobian` and the predicted outputs it is the derivative of (2M or 2M + K rows), in one pass.

    The columns of :data:`ADDITIVE` names are written down beside the others' program (a numpy array then)."""
    names = tuple(names)
    traced = tuple(n for n in names if n not in ADDITIVE)
    if traced == names or not traced or _inside_trace(motor, experiment):  # inside a trace: one program anyway
        return _compiled(motor, experiment, names, probing)
    jac, outputs = _compiled(motor, experiment, traced, probing)
    return _with_additive(np.asarray(jac), traced, names, experiment), outputs


def _inside_trace(*trees) -> bool:
    """Whether any leaf of ``trees`` is a JAX tracer (asked only where the offsets' columns would be split off)."""
    return any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))


def _with_additive(jac: np.ndarray, traced: tuple[str, ...], names: tuple[str, ...],
                   experiment: Experiment) -> np.ndarray:
    """``jac`` (the columns of ``traced``) with those of the :data:`ADDITIVE` names, in the order of ``names``."""
    columns = dict(zip(traced, jac.T))
    for n in names:
        if n in ADDITIVE:
            column = np.zeros(jac.shape[0])
            column[ADDITIVE[n]:2 * experiment.num_samples:2] = 1.0
            columns[n] = column
    return np.stack([columns[n] for n in names], axis=1)


def _compiled(motor: MotorParams, experiment: Experiment, names: tuple[str, ...],
              probing: bool) -> tuple[jnp.ndarray, jnp.ndarray]:
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
