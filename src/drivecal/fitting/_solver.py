"""The Levenberg-Marquardt solve behind a fit: optimistix extensions, residuals, tiling and batching.

One ``jax.jit``-compiled function per plan shape solves a fit (or a batch of
fits under ``vmap``, in tiles of ``SOLVE_TILE``), and returns the estimate,
the Jacobian's covariance and how the solve ended; :mod:`._fit` turns it into
a :class:`drivecal.results.Calibration`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..model import Experiment, cached_call, current_parts, join_current_parts, predict_current_parts
from ..physics import MotorParams, from_search, to_search
from ..results import solver_code
from ._initial import start_from_data
from ._options import FitOptions


class _Solved(eqx.Module):
    """Raw per-fit arrays out of the compiled solve (leading batch axis)."""

    theta: jnp.ndarray  # (n,) fitted parameters, their units
    covariance: jnp.ndarray  # (n, n)
    sigma_hat: jnp.ndarray  # () A
    rss: jnp.ndarray  # () A^2
    iterations: jnp.ndarray  # ()
    result_code: jnp.ndarray  # () optimistix RESULTS index
    converged: jnp.ndarray  # () bool
    accepted: jnp.ndarray | None = None  # (max_steps, n) z after each LM step (recorded solves only)
    initial: jnp.ndarray | None = None  # (len(names),) where the search started, SI units
    residuals: jnp.ndarray | None = None  # (M, 2) A, model minus measured at the last linearisation


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


class _RecordingState(eqx.Module):
    inner: Any
    accepted: jnp.ndarray

    @property
    def f_info(self):
        return self.inner.f_info

    @property
    def descent_state(self):
        return self.inner.descent_state


class _Recording(optx.AbstractLeastSquaresSolver):
    """A least-squares solver that also keeps ``y`` after every step (its last accepted iterate).

    The iterates live in the solver state, inside the compiled graph: a host
    callback would do the same but keeps the executable out of JAX's
    persistent compilation cache (a ~3 s compile in every new process).
    """

    inner: optx.AbstractLeastSquaresSolver
    steps: int = eqx.field(static=True)

    @property
    def rtol(self):
        return self.inner.rtol

    @property
    def atol(self):
        return self.inner.atol

    @property
    def norm(self):
        return self.inner.norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        state = self.inner.init(fn, y, args, options, f_struct, aux_struct, tags)
        return _RecordingState(state, jnp.zeros((self.steps,) + jnp.shape(y), jnp.result_type(y)))

    def step(self, fn, y, args, options, state, tags):
        y, inner, aux = self.inner.step(fn, y, args, options, state.inner, tags)
        accepted = state.accepted.at[inner.num_steps - 1].set(y)
        return y, _RecordingState(inner, accepted), aux

    def terminate(self, fn, y, args, options, state, tags):
        return self.inner.terminate(fn, y, args, options, state.inner, tags)

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.inner.postprocess(fn, y, aux, args, options, state.inner, tags, result)


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


def _solve_one(currents, z0, prior, experiment, names, options, record) -> _Solved:
    residual = _residual_fn(prior, experiment, names, currents)
    solver = _LevenbergMarquardt(rtol=options.rtol, atol=options.atol, step_se=options.step_se)
    if record:
        solver = _Recording(solver, options.max_steps)
    sol = optx.least_squares(residual, solver, z0, max_steps=options.max_steps, throw=False)
    # The solver's last accepted linearisation is at sol.value: its residual and
    # J^T J in z (relative units, or per additive step: better conditioned to
    # invert than the physical J^T J, ohms vs henries) are reused rather than
    # recomputed. Bit-identical to jacfwd at sol.value.
    state = sol.state.descent_state
    m, rss = _size_and_sum_of_squares(sol.state.f_info.residual)
    n = sol.value.shape[0]
    s2 = rss / (m - n)
    # The last Gauss-Newton step, taken when it is within step_se standard errors (it then
    # lands ~step_se * 1e-4 SE from the optimum): the statistical stop needs no confirming step.
    step, size = _gauss_newton_step(state, s2)
    z = jnp.where(size <= options.step_se, sol.value - step, sol.value)
    theta = from_search(prior, names, z)[0]
    dtheta_dz = from_search(prior, names, sol.value)[1]
    cov = s2 * jnp.linalg.inv(state.gram) * jnp.outer(dtheta_dz, dtheta_dz)
    ok = (
        (sol.result == optx.RESULTS.successful)
        & jnp.all(jnp.isfinite(theta))
        & jnp.all(jnp.isfinite(cov))
        & jnp.all(jnp.diag(cov) > 0)
    )
    return _Solved(
        theta=theta,
        covariance=cov,
        sigma_hat=jnp.sqrt(s2),
        rss=rss,
        iterations=sol.stats["num_steps"],
        result_code=solver_code(sol.result),
        converged=ok,
        accepted=sol.state.accepted if record else None,
        residuals=join_current_parts(experiment, sol.state.f_info.residual),
    )


#: Largest batch whose Jacobian sweeps use ``Experiment.linearised_tangents`` (measured crossover: ~4).
LINEARISED_TANGENTS_MAX_BATCH = 2

#: Fits per tile of a batched solve (batches of a multiple of it are solved tile by tile).
SOLVE_TILE = 32


#: Step (search units, ~relative) of the finite differences that give a tile's shared Jacobian.
SHARED_JACOBIAN_PROBE = 1e-6


def _shared_jacobian_steps(currents, z0, prior, experiment, exp_axis, names, steps: int):
    """``FitOptions.shared_jacobian_steps`` for one tile: starts (T, n) in search units, moved.

    ``currents`` (T, M, 2) A; ``experiment`` one per fit (``exp_axis`` 0) or shared (None).
    The shared Jacobian is the first fit's, by forward differences, from n more rollouts of
    that fit in the same vmapped call as the tile's own: one rollout's code serves the whole
    loop (a Jacobian sweep of its own made the compiled solve twice as slow to load).
    """
    tile, n = z0.shape
    probes = SHARED_JACOBIAN_PROBE * jnp.eye(n, dtype=z0.dtype)
    cur = jnp.concatenate([currents, jnp.broadcast_to(currents[0], (n,) + currents.shape[1:])])
    exp = experiment if exp_axis is None else jax.tree_util.tree_map(
        lambda a: jnp.concatenate([a, jnp.broadcast_to(a[0], (n,) + a.shape[1:])]), experiment)

    def flat_residual(c, z, e):
        parts = _residual_fn(prior, e, names, c)(z, None)
        return jnp.concatenate([jnp.ravel(p) for p in parts])

    residuals = jax.vmap(flat_residual, in_axes=(0, 0, exp_axis))

    def step(k, carry):
        z, start_rss, keep = carry
        r = residuals(cur, jnp.concatenate([z, z[0] + probes]), exp)  # (T + n, m)
        jac = ((r[tile:] - r[0]) / SHARED_JACOBIAN_PROBE).T  # (m, n): the first fit's, at its current point
        rss = jnp.sum(r[:tile] ** 2, axis=1)
        # A fit the first step did not improve (a motor unlike the tile's first) keeps its data start.
        keep = jnp.where(k == 1, rss < start_rss, keep)
        start_rss = jnp.where(k == 0, rss, start_rss)
        return z - jnp.linalg.solve(jac.T @ jac, jac.T @ r[:tile].T).T, start_rss, keep

    z, _, keep = jax.lax.fori_loop(0, steps, step, (z0, jnp.zeros(tile, z0.dtype), jnp.ones(tile, bool)))
    keep = keep & jnp.all(jnp.isfinite(z), axis=1)
    return jnp.where(keep[:, None], z, z0)


@functools.partial(jax.jit, static_argnames=("names", "fit_names", "options", "record"))
def _solve_compiled(currents, start, prior, experiment, names, fit_names, options, record=False) -> _Solved:
    from_data = start is None  # static: the start comes from the data, computed in the same compiled call
    if from_data:
        start = start_from_data(experiment, currents, prior, names)
    z0 = to_search(prior, fit_names, start[:, [names.index(n) for n in fit_names]], jnp)
    per_dataset = experiment.voltages.ndim == 3  # static: shapes are known at trace time
    batch = currents.shape[0]
    if batch > SOLVE_TILE and batch % SOLVE_TILE == 0:
        # Tile by tile, each tile's LM loop vmapped: its working set (Jacobians, states) stays in cache
        # and a tile stops when its own fits have (~15 % faster a motor in a fleet's batch of 256).
        exp_axis = 0 if per_dataset else None

        def tile(args):
            cur, z, exp = args if per_dataset else (*args, experiment)
            if from_data and options.shared_jacobian_steps > 0:
                z = _shared_jacobian_steps(cur, z, prior, exp, exp_axis, fit_names, options.shared_jacobian_steps)
            return jax.vmap(_solve_one, in_axes=(0, 0, None, exp_axis, None, None, None))(
                cur, z, prior, exp, fit_names, options, record)

        tiles = jax.tree_util.tree_map(lambda a: a.reshape((batch // SOLVE_TILE, SOLVE_TILE) + a.shape[1:]),
                                       (currents, z0, experiment) if per_dataset else (currents, z0))
        solved = jax.tree_util.tree_map(lambda a: a.reshape((batch,) + a.shape[2:]), jax.lax.map(tile, tiles))
    else:
        solved = jax.vmap(_solve_one, in_axes=(0, 0, None, 0 if per_dataset else None, None, None, None))(
            currents, z0, prior, experiment, fit_names, options, record
        )
    return dataclasses.replace(solved, initial=start)


def _solve_fields(currents, start, prior, experiment, names, fit_names, options, record):
    solved = _solve_compiled(currents, start, prior, experiment, names, fit_names, options, record)
    return tuple(getattr(solved, f.name) for f in dataclasses.fields(_Solved))


def _solve_batch(currents, start, prior, experiment, names, fit_names, options, record=False) -> _Solved:
    """Fit ``fit_names`` (of ``names``) to a batch: currents (B, M, 2) A. One compiled call.

    ``start`` (B, len(names)) SI units is where each search starts, or None:
    from the data (``initial.start_from_data``, inside the same call). The
    experiment is shared (arrays of M samples) or one per dataset (a leading
    B axis on every array, e.g. a fleet whose benches each measured their own
    voltages and speed). With ``record`` (single fits) ``accepted`` holds the
    iterate after each LM step (for convergence plots).
    """
    # Jacobian sweeps from the linearised steps are several times faster for one or two fits; from a
    # few fits up, forward mode through the scans wins (less memory traffic).
    linearised = currents.shape[0] <= LINEARISED_TANGENTS_MAX_BATCH
    if experiment.linearised_tangents != linearised:  # replace() rebuilds the module: ~0.1 ms of a 5 ms fit
        experiment = dataclasses.replace(experiment, linearised_tangents=linearised)
    fields = cached_call(_solve_fields, "solve_batch", currents, start, prior, experiment, names=names,
                         fit_names=fit_names, options=options, record=record)
    return _Solved(*fields)


def _straggler_bucket(n: int, total: int) -> int:
    """Batch size to re-solve n stragglers of a batch of ``total``: a power of 4, so few shapes compile."""
    size = 4
    while size < n:
        size *= 4
    return min(size, total)


def _solve_staged(currents, start, prior, experiment, names, fit_names, options: FitOptions) -> _Solved:
    """``_solve_batch`` of a batch in two passes (see ``FitOptions.first_pass_steps``); numpy results.

    ``start`` as in ``_solve_batch`` (None: from the data, and ``"auto"`` then takes a short first pass).
    """
    first = options.first_pass_steps
    if first == "auto":
        first = 3 if start is None else 16
    b = currents.shape[0]
    if first is None or first >= options.max_steps or b < 2:
        one = dataclasses.replace(options, first_pass_steps=None)
        return jax.device_get(_solve_batch(currents, start, prior, experiment, names, fit_names, one))
    quick = dataclasses.replace(options, max_steps=first, first_pass_steps=None)
    solved = jax.device_get(_solve_batch(currents, start, prior, experiment, names, fit_names, quick))
    again = np.flatnonzero(solved.result_code == solver_code(optx.RESULTS.nonlinear_max_steps_reached))
    if again.size == 0:
        return solved
    size = _straggler_bucket(again.size, b)
    index = np.concatenate([again, np.full(size - again.size, again[0])])
    per_dataset = experiment.voltages.ndim == 3
    sub_experiment = jax.tree_util.tree_map(lambda a: a[index], experiment) if per_dataset else experiment
    full = dataclasses.replace(options, first_pass_steps=None)
    redone = jax.device_get(_solve_batch(currents[index], solved.initial[index], prior, sub_experiment, names,
                                         fit_names, full))

    def merge(a, r):
        a = np.array(a)
        a[again] = np.asarray(r)[: again.size]
        return a

    return jax.tree_util.tree_map(merge, solved, redone)
