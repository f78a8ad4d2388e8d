"""The solver's shortcuts change the cost, not the answer (its LM steps: test_lm.py).

- The statistical stop (``FitOptions.step_se``) skips the confirming step without moving the estimate.
- The start from the data, computed inside the compiled solve, is ``initial.equation_error_start``.
- Host-side experiments (a fleet's) are the device ones.
"""

from __future__ import annotations


import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.model import model_experiment, stack_experiments
from drivecal.fitting import equation_error_start
from drivecal.physics import to_search

from drivecal.fitting import _solver as fit_module  # noqa: E402  (this file tests the solve itself)

SEEDS = 24


@pytest.fixture(scope="module")
def noisy_batch(clean_default):
    rng = np.random.default_rng(11)
    return clean_default.currents[None] + rng.normal(0.0, NOISE, (SEEDS,) + clean_default.currents.shape)


@pytest.fixture(scope="module")
def tight_batch(clean_default, noisy_batch, guess):
    """The batch solved to 1e-10 without the statistical stop: the reference optimum."""
    options = dc.FitOptions(rtol=1e-10, atol=1e-10, step_se=0.0, first_pass_steps=None)
    return dc.fit_currents(clean_default.experiment(), noisy_batch, guess, options=options)


def test_statistical_stop_saves_steps_not_accuracy(clean_default, noisy_batch, guess, tight_batch):
    cal = dc.fit_currents(clean_default.experiment(), noisy_batch, guess)
    assert np.all(cal.converged)
    # Within a thousandth of a standard error of the tight solve (measured: ~1e-6), same uncertainty.
    assert np.max(np.abs(cal.estimate - tight_batch.estimate) / tight_batch.se) < 1e-3
    np.testing.assert_allclose(cal.se, tight_batch.se, rtol=1e-6)
    # sigma_hat is that of the accepted point, at most 0.01 SE away: rss higher by <= 0.01^2 sigma^2.
    np.testing.assert_allclose(cal.sigma_hat, tight_batch.sigma_hat, rtol=0.5 * 0.01**2 / cal.dof)
    assert np.median(cal.iterations) < np.median(tight_batch.iterations)
    # Switched off, the stop is optimistix's own (Cauchy) termination: more steps.
    plain = dc.fit_currents(clean_default.experiment(), noisy_batch, guess, options=dc.FitOptions(step_se=0.0))
    assert np.median(cal.iterations) < np.median(plain.iterations)


def test_start_inside_the_solve_is_the_equation_error_start(clean_default, noisy_batch, guess):
    experiment = clean_default.experiment()
    cal = dc.fit_currents(experiment, noisy_batch[:3], guess)
    expected = equation_error_start(model_experiment(experiment, guess, dc.ESTIMATED), jnp.asarray(noisy_batch[:3]),
                                    guess, dc.ESTIMATED)
    np.testing.assert_allclose(cal.initial, np.asarray(expected), rtol=1e-12)


def test_host_experiments_equal_device_ones(clean_default):
    device = clean_default.experiment()
    host = clean_default.experiment(host=True)
    assert isinstance(host.voltages, np.ndarray) and isinstance(device.voltages, jax.Array)
    for a, b in zip(jax.tree_util.tree_leaves(device), jax.tree_util.tree_leaves(host)):
        np.testing.assert_array_equal(np.asarray(a), b)
    stacked_host, stacked_device = stack_experiments([host, host]), stack_experiments([device, device])
    assert stacked_host.segments == stacked_device.segments == device.segments
    for a, b in zip(jax.tree_util.tree_leaves(stacked_device), jax.tree_util.tree_leaves(stacked_host)):
        assert isinstance(b, jax.Array)
        np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def tiled_batch(clean_default):
    """Two tiles of fits (``fit.SOLVE_TILE``): the batched path a fleet's chunks take."""
    rng = np.random.default_rng(12)
    size = 2 * fit_module.SOLVE_TILE
    return clean_default.currents[None] + rng.normal(0.0, NOISE, (size,) + clean_default.currents.shape)


def test_shared_jacobian_steps_save_a_sweep_not_accuracy(clean_default, tiled_batch, guess):
    """Steps from the data start with one Jacobian per tile: LM then stops a sweep earlier, at the same estimates."""
    experiment = clean_default.experiment()
    shared = dc.fit_currents(experiment, tiled_batch, guess)
    plain = dc.fit_currents(experiment, tiled_batch, guess, options=dc.FitOptions(shared_jacobian_steps=0))
    assert np.all(shared.converged) and np.all(plain.converged)
    assert np.median(shared.iterations) < np.median(plain.iterations)
    np.testing.assert_array_equal(shared.initial, plain.initial)  # the reported start is the data's
    # Both end within step_se = 0.01 SE of the optimum and then take the final Gauss-Newton step
    # (~1e-4 of that from it): a thousandth of an SE apart at most (measured on a fleet: ~1e-6); the
    # covariances are those of points ~0.01 SE apart (measured: ~1e-6 relative).
    assert np.max(np.abs(shared.estimate - plain.estimate) / plain.se) < 1e-3
    np.testing.assert_allclose(shared.se, plain.se, rtol=1e-5)


def test_a_fit_the_shared_step_does_not_improve_keeps_its_start(clean_default, tiled_batch, guess):
    """Fits started at their own optimum: the tile's Jacobian (another fit's) can only move them uphill."""
    names = dc.ESTIMATED
    tight = dc.fit_currents(clean_default.experiment(), tiled_batch, guess,
                            options=dc.FitOptions(rtol=1e-10, atol=1e-10, step_se=0.0, first_pass_steps=None))
    experiment = model_experiment(clean_default.experiment(), guess, names)
    tile = slice(0, fit_module.SOLVE_TILE)
    z_far = jnp.asarray(to_search(guess, names, tight.initial[tile]))  # the data starts
    z_opt = jnp.asarray(to_search(guess, names, tight.estimate[tile]))
    # The tile's first fit starts from its data start (its Jacobian is taken there), the others at their optimum.
    z0 = z_opt.at[0].set(z_far[0])
    currents = jnp.asarray(tiled_batch[tile])
    moved = np.asarray(jax.jit(fit_module._shared_jacobian_steps, static_argnums=(4, 5, 6))(
        currents, z0, guess, experiment, None, names, 2))
    np.testing.assert_array_equal(moved[1:], np.asarray(z0[1:]))
    assert not np.array_equal(moved[0], np.asarray(z0[0]))  # the first improved: it moved
