"""The least-squares problem of a fit and drivecal's optimistix Levenberg-Marquardt solver for it.

Loaded only when a solve is traced (inside :func:`._solver._solve_one`): a fit whose
lowered program comes from the disk cache (``model.cached_call``) runs without
importing optimistix (~0.35 s of a process's start).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ..model import Experiment, current_parts, predict_current_parts
from ..physics import MotorParams, from_search


def _silent(**kwargs) -> None:
    """optimistix's verbose hook, quiet."""


class _NormalEquationsState(eqx.Module):
    gram: jnp.ndarray  # (n, n) J^T J at the last accepted point
    gradient: jnp.ndarray  # (n,) J^T r there


class _NormalEquationsDescent(optx.AbstractDescent):
    """optimistix's damped Newton (LM) descent, solved through the n x n normal equations.

    ``(J^T J + lambda I) dz = -J^T r`` is the same step as optimistix's
    ``DampedNewtonDescent``, which QR-factors the (m + n) x n matrix
    ``[J; sqrt(lambda) I]`` at every trial step. Here ``J^T J`` and ``J^T r``
    are formed once per accepted point (``query``) and every trial step is a
    4 x 4 Cholesky solve: in a ``vmap``-ped batch the QR of 2800 x 4 matrices
    cost ~40 % of each LM step. In ``z`` (relative units) ``J^T J`` is well
    conditioned (the covariance already inverts it), so nothing is lost in float64.
    """

    def init(self, y, f_info_struct):
        n = y.shape[-1]
        return _NormalEquationsState(jnp.zeros((n, n), y.dtype), jnp.zeros((n,), y.dtype))

    def query(self, y, f_info, state):
        del state
        # J's rows (n, N) per residual part, straight from the linearisation (as_matrix would join the parts).
        rows = jax.tree_util.tree_leaves(jax.vmap(f_info.jac.mv)(jnp.eye(y.shape[-1], dtype=y.dtype)))
        residual = jax.tree_util.tree_leaves(f_info.residual)
        return _NormalEquationsState(sum(r @ r.T for r in rows), sum(r @ e for r, e in zip(rows, residual)))

    def step(self, step_size, state):
        # lambda = 1 / step_size, as optimistix's damped_newton_step (a step size of ~0 is "no step").
        tiny = step_size <= jnp.finfo(step_size.dtype).eps
        damping = jnp.where(tiny, jnp.finfo(step_size.dtype).max, 1.0 / jnp.where(tiny, 1.0, step_size))
        n = state.gradient.shape[0]
        factor = jax.scipy.linalg.cho_factor(state.gram + damping * jnp.eye(n, dtype=state.gram.dtype))
        dz = -jax.scipy.linalg.cho_solve(factor, state.gradient)
        ok = jnp.all(jnp.isfinite(dz))
        return jnp.where(ok, dz, 0.0), optx.RESULTS.where(ok, optx.RESULTS.successful,
                                                          optx.RESULTS.singular)


class _LevenbergMarquardt(optx.AbstractGaussNewton):
    """optimistix's Levenberg-Marquardt (classical trust region, the same damping and
    termination) with the damped step solved by :class:`_NormalEquationsDescent`,
    and a statistical stop (``FitOptions.step_se``)."""

    rtol: float
    atol: float
    step_se: float = 0.0
    norm: Any = optx.max_norm
    descent: _NormalEquationsDescent = _NormalEquationsDescent()
    search: optx.ClassicalTrustRegion = optx.ClassicalTrustRegion()
    verbose: Any = _silent

    def terminate(self, fn, y, args, options, state, tags):
        done, result = super().terminate(fn, y, args, options, state, tags)
        if not self.step_se:
            return done, result
        m, rss = _size_and_sum_of_squares(state.f_info.residual)
        s2 = rss / (m - y.shape[0])
        close = (state.num_accepted_steps > 0) & (_gauss_newton_step(state.descent_state, s2)[1] <= self.step_se)
        return done | close, result


def _size_and_sum_of_squares(residual) -> tuple[int, jnp.ndarray]:
    """Number of residuals and their sum of squares, over the residual's parts."""
    parts = jax.tree_util.tree_leaves(residual)
    return sum(p.size for p in parts), sum(p @ p for p in parts)


def _gauss_newton_step(state: _NormalEquationsState, s2) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The undamped Gauss-Newton step ``(J^T J)^-1 J^T r`` (to subtract from z) and its size in
    standard errors, ``sqrt(step^T J^T J step / s2)`` (``s2`` = sigma_hat^2; inf where not finite)."""
    step = jnp.linalg.solve(state.gram, state.gradient)
    size = jnp.sqrt(step @ state.gram @ step / s2)
    return step, jnp.where(jnp.isfinite(size), size, jnp.inf)


def _jacobian_in_one_pass(f):
    """``f`` (to a pytree of 1-D arrays) with a JVP rule that builds the whole Jacobian in one forward sweep.

    optimistix linearises the residual at every LM step and then applies the
    linearisation once per parameter; through a 1000-step scan that replay is
    the dominant cost. With this rule linearising costs one ``jacfwd``-style
    sweep (primal computed once, n tangents together) and applying it is a
    small matrix product.
    """

    @jax.custom_jvp
    def g(x):
        return f(x)

    @g.defjvp
    def g_jvp(primals, tangents):
        (x,), (dx,) = primals, tangents
        basis = jnp.eye(x.shape[-1], dtype=x.dtype)
        # Jacobian rows per parameter (n, m): the layout the sweep produces (a parameter-last
        # layout costs a transposing copy of the whole Jacobian per LM step in a batch).
        y, rows = jax.vmap(lambda t: jax.jvp(f, (x,), (t,)), out_axes=(None, 0))(basis)
        return y, jax.tree_util.tree_map(lambda r: dx @ r, rows)

    return g


def _residual_fn(prior: MotorParams, experiment: Experiment, names: tuple[str, ...], currents: jnp.ndarray):
    # The residuals stay in parts (i_d and i_q of each segment; see model.predict_current_parts).
    measured = current_parts(experiment, currents)

    @_jacobian_in_one_pass
    def predicted(z):
        motor = prior.with_vector(names, from_search(prior, names, z)[0])
        return predict_current_parts(motor, experiment)

    def residual(z, _args):
        return tuple(p - y for p, y in zip(predicted(z), measured))

    return residual
