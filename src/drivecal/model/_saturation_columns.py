"""The sensitivities of the predicted currents to the saturation coefficients, at every candidate exponent.

The score tests of ``fit --magnetics auto`` (``diagnose``) need, per term of the saturating law and per
candidate exponent, the column ``d(currents)/d(coefficient)``: central differences of the flux-state
rollout, all in one compiled, batched program.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._experiment import Experiment
from ._lowered_cache import call as cached_call, run_once_options
from ._rollout import predict_currents
from ..physics import EXPONENT_CANDIDATES, MAGNETIC, MotorParams


#: Step of the central differences of :func:`start_saturation_columns` (the coefficients are per unit: the
#: currents move by ~1e-4 of the tested current; truncation ~1e-8, rounding ~1e-11 relative).
SATURATION_STEP = 1e-4


def start_saturation_columns(motor: MotorParams, experiment: Experiment) -> Callable[[], np.ndarray]:
    """The sensitivity of the predicted currents to each saturation coefficient at each candidate exponent,
    its program dispatched now (XLA runs it while the caller goes on); the function returned waits for it.

    That function gives ``d[i_d, i_q]/d sat`` (A per unit), shape (3, K, M, 2): per term of ``physics.MAGNETIC``
    (``sat_d``, ``sat_q``, ``sat_dq``) and per candidate ``j`` of its exponents
    (``physics.EXPONENT_CANDIDATES``), at ``motor`` with that term's exponents set to candidate ``j``.
    Central differences of the flux-state rollout, all ``2 * 3 * K`` rollouts in one compiled, batched
    call: the score tests of ``--magnetics auto`` then cost one forward program, not a Jacobian per
    candidate (``diagnose``). ``experiment`` must have ``saturating`` set.
    """
    rows = []
    for name in MAGNETIC:
        exponents, values = EXPONENT_CANDIDATES[name]
        for candidate in values:
            for sign in (1.0, -1.0):
                changes = dict(zip(exponents, candidate))
                changes[name] = float(getattr(motor, name)) + sign * SATURATION_STEP
                rows.append(motor.replace(**changes))
    # Stacked on the host (NumPy): one device array per leaf, not one per leaf and row (~0.3 s of a warm fit).
    batch = jax.tree_util.tree_map(lambda *xs: np.stack([np.asarray(x, dtype=np.float64) for x in xs]), *rows)
    # The model's steps as loops (Experiment.rolled): the same columns from a program half the size. XLA's
    # legacy emitters, and without the dead time's rollout LLVM's level 0 too (model.RUN_ONCE): on
    # examples/bench.csv the program compiles in 0.2 s against 0.6 s and runs in ~0.1 s against ~0.04 s
    # (the score tests' other work goes on meanwhile, as the call is dispatched before it: diagnose), a
    # cold fit 5.2 -> 4.7 s (median of 5). The columns move in the ~12th digit; no printed one.
    out = cached_call(_batched_currents, "saturation_columns", batch, dataclasses.replace(experiment, rolled=True),
                      compiler_options=run_once_options(experiment.dead_time))

    def columns() -> np.ndarray:
        count = len(EXPONENT_CANDIDATES[MAGNETIC[0]][1])
        found = np.asarray(out)
        found = found.reshape(len(MAGNETIC), count, 2, *found.shape[1:])
        return (found[:, :, 0] - found[:, :, 1]) / (2.0 * SATURATION_STEP)

    return columns


@jax.jit  # compiled with its options by cached_call, cache or no cache
def _batched_currents(motors: MotorParams, experiment: Experiment) -> jnp.ndarray:
    return jax.vmap(predict_currents, in_axes=(0, None))(motors, experiment)
