"""drivecal's Levenberg-Marquardt (``fitting._lm``) takes optimistix LM's steps, through the 4 x 4 normal
equations instead of a QR of [J; sqrt(lambda) I] at every trial step."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

import drivecal as dc
from conftest import NOISE
from drivecal.fitting import _lm  # this file tests the solver itself
from drivecal.fitting import equation_error_start
from drivecal.model import model_experiment
from drivecal.physics import to_search


def test_normal_equations_take_optimistix_lm_steps(clean_default, guess):
    """From the same start, both solvers visit the same points: same steps, same end (to rounding)."""
    names = dc.ESTIMATED
    rng = np.random.default_rng(11)  # test_solver.py's noisy batch, its first four datasets
    noisy = clean_default.currents[None] + rng.normal(0.0, NOISE, (4,) + clean_default.currents.shape)
    experiment = model_experiment(clean_default.experiment(), guess, names)
    start = np.asarray(equation_error_start(experiment, jnp.asarray(noisy), guess, names))
    z0 = jnp.asarray(to_search(guess, names, start))

    def solve(solver):
        def one(currents, z):
            residual = _lm._residual_fn(guess, experiment, names, jnp.asarray(currents))
            sol = optx.least_squares(residual, solver, z, max_steps=100, throw=False)
            return sol.value, sol.stats["num_steps"], sol.result._value

        return jax.jit(jax.vmap(one))(jnp.asarray(noisy), z0)

    # At the default tolerance both take the same number of steps to the same point; at 1e-10
    # rounding decides which noise-level trial steps are accepted, but not where they end.
    for tol, steps_equal, atol in ((1e-5, True, 1e-10), (1e-10, False, 1e-9)):
        ours = solve(_lm._LevenbergMarquardt(rtol=tol, atol=tol))
        theirs = solve(optx.LevenbergMarquardt(rtol=tol, atol=tol))
        assert np.all(np.asarray(ours[2]) == 0) and np.all(np.asarray(theirs[2]) == 0)
        if steps_equal:
            np.testing.assert_array_equal(ours[1], theirs[1])
        # z is relative: 1e-9 is ~1e-5 standard errors here.
        np.testing.assert_allclose(ours[0], theirs[0], rtol=0, atol=atol)
