"""The fit: Levenberg-Marquardt on the currents, then honest intervals.

Unknowns are searched as ``z = ln(theta / theta_prior)`` so every parameter
stays positive and every direction has the same scale (a raw ``ln(theta)``
lets the first trust-region step jump to stiff, absurd motors). Bench effects
that may be zero or negative (sensor offsets, dead-time voltage) are searched
additively, ``theta = theta_prior + step * z`` (``motor.search_scale``). The whole
solve — optimistix LM, the Jacobian at the optimum, the covariance — is one
``jax.jit``-compiled function, ``vmap``-ped over datasets and starting points.

Uncertainty: ``Cov = sigma_hat^2 (J^T J)^-1`` with ``sigma_hat^2 = ||r||^2 / (m - n)``,
standard errors from its diagonal and Student-t 95 % intervals with m - n
degrees of freedom (m current samples, n fitted parameters). Under vmap
nothing throws: each fit carries its own result code.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..model import cached_call
from ..data import BenchData
from .._stats import t_ppf
from ..errors import DrivecalError
from ..model import Experiment, current_parts, join_current_parts, model_experiment, predict_current_parts
from ..identify import Identifiability, assess_identifiability
from ._initial import start_from_data
from ..physics import (ADDITIVE_SCALE, ESTIMATED, FIXED, NUISANCE, UNITS, MotorParams, from_search, parameter_values,
                    to_search)


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """Solver settings.

    Attributes:
        rtol, atol: optimistix LM termination tolerances on ``z = ln(theta/prior)``
            and on the residuals. 1e-5 moves no estimate by more than ~3e-5
            standard errors from a solve at 1e-10 (128 noise seeds of the default
            plan, from the data, the prior and +-50 % random starts), and spares
            the steps a tighter tolerance spends on rejected noise-level trials.
        max_steps: LM steps before giving up (reported, not raised).
        first_pass_steps: batches only: under ``vmap`` every fit of a batch runs
            until its slowest member stops, so the batch is first solved with at
            most this many steps, and only the fits that hit it are solved again
            from their start with ``max_steps`` (in a small batch of their own).
            The results are those of one solve with ``max_steps``. None: one
            pass; ``"auto"``: 3 from a start found in the data (~97 % of fits
            stop after 3 with the statistical stop), else 16.
        start: where the search starts when no ``initial`` is given: ``"data"``,
            an equation-error estimate from the recorded currents
            (``initial.start_from_data``; ~1 % from the optimum, so LM needs
            ~3 steps instead of ~12 from a datasheet guess), or ``"prior"``.
        step_se: also stop at an accepted point where the Gauss-Newton step
            from it, ``(J^T J)^-1 J^T r``, measures at most this many standard
            errors in the covariance's own metric (``sqrt(dz^T J^T J dz) /
            sigma_hat``, which bounds every parameter's move in its SE): the
            point is then that close to the optimum, and the step that
            optimistix's termination would still take to confirm it (one more
            rollout and Jacobian) is skipped. That last step is then applied
            (the estimate lands ~1e-4 of step_se from the optimum; sigma_hat and
            the covariance are those of the accepted point, step_se SE away).
            0 turns both off.
        shared_jacobian_steps: batches solved in tiles (``SOLVE_TILE``) from a
            start found in the data only: Gauss-Newton steps taken from that
            start before LM, every fit of a tile using the Jacobian of the
            tile's first fit at that fit's current point (forward differences).
            A step costs each fit one rollout of its model instead of a
            Jacobian sweep (the rollout and one tangent per parameter), and two
            take a fleet's starts from ~100 to ~0.3 standard errors from their
            optima (median over 256 motors, in the covariance's metric; at most
            ~8), so LM then stops after two sweeps instead of three. A fit whose
            residual the first step does not reduce keeps its data start. 0
            turns them off; the estimates agree either way to ~1e-6 SE.
    """

    rtol: float = 1e-5
    atol: float = 1e-5
    step_se: float = 1e-2
    max_steps: int = 200
    first_pass_steps: int | str | None = "auto"
    start: str = "data"
    shared_jacobian_steps: int = 2

    def __post_init__(self):
        if self.start not in ("data", "prior"):
            raise ValueError(f"FitOptions.start must be 'data' or 'prior', got {self.start!r}")


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
    # The residuals stay in parts (i_d and i_q of each segment; see forward.predict_current_parts).
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
        result_code=sol.result._value,
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
    again = np.flatnonzero(solved.result_code == optx.RESULTS.nonlinear_max_steps_reached._value)
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


def result_message(code: int, converged: bool) -> str:
    if converged:
        return "converged"
    message = optx.RESULTS._index_to_message[int(code)]
    return message or "the covariance is not finite: the data does not constrain the fitted parameters"


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A fitted motor: estimates, uncertainty and how the fit ended.

    Array fields may carry a leading batch axis (a batch of fits is the same
    object; index it to get one). Parameters the experiment cannot identify
    keep their prior value, have ``identifiable`` False and NaN uncertainty.

    Attributes:
        names: estimated parameter names (R, Ld, Lq, lambda_m by default).
        estimate: (..., len(names)) estimates, SI units.
        se: (..., len(names)) standard errors, NaN where not identifiable.
        ci95: (..., len(names), 2) Student-t 95 % intervals [low, high].
        identifiable: per name, whether it was fitted.
        fit_names: the fitted names: the axes of ``covariance``.
        covariance: (..., n, n) covariance of the fitted names, SI units.
        sigma_hat: (...,) residual standard deviation (A).
        rss: (...,) residual sum of squares (A^2).
        iterations: (...,) LM steps taken.
        converged: (...,) whether the solve ended successfully.
        result_code: (...,) optimistix result index (0 = successful).
        initial: (..., len(names)) starting point of the search.
        prior: the nominal motor (also holds the fixed parameters).
        identifiability: the pre-fit identifiability verdict.
        num_residuals: m, current samples fitted (i_d and i_q).
        t_factor: Student-t 97.5 % quantile with m - n degrees of freedom.
        source: where the data came from.
        history: (K, n) accepted LM iterates of ``fit_names`` (SI), the start
            first and the estimate last; single fits only, else None.
        delay_samples: the inverter delay (samples) the fit assumed.
        residuals: (..., M, 2) model minus measured ``[i_d, i_q]`` (A) at the
            solver's last linearisation (the estimate is at most a final
            Gauss-Newton step of ``FitOptions.step_se`` SE from it), or None.
    """

    names: tuple[str, ...]
    estimate: np.ndarray
    se: np.ndarray
    ci95: np.ndarray
    identifiable: tuple[bool, ...]
    fit_names: tuple[str, ...]
    covariance: np.ndarray
    sigma_hat: np.ndarray
    rss: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    result_code: np.ndarray
    initial: np.ndarray
    prior: MotorParams
    identifiability: Identifiability
    num_residuals: int
    t_factor: float
    source: str = "synthetic bench"
    history: np.ndarray | None = None
    delay_samples: int = 0
    residuals: np.ndarray | None = None

    # --- batch handling --------------------------------------------------

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """() for one fit, (B,) for a batch."""
        return tuple(self.sigma_hat.shape)

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError("a single Calibration has no len(); it is not a batch")
        return self.batch_shape[0]

    def __getitem__(self, i: int) -> Calibration:
        """The i-th fit of a batch."""
        if not self.batch_shape:
            raise TypeError("a single Calibration cannot be indexed; it is not a batch")
        fields = ("estimate", "se", "ci95", "covariance", "sigma_hat", "rss", "iterations", "converged",
                  "result_code", "initial") + (("residuals",) if self.residuals is not None else ())
        return dataclasses.replace(self, **{f: getattr(self, f)[i] for f in fields})

    # --- convenient views ------------------------------------------------

    @property
    def motor(self) -> MotorParams:
        """The calibrated motor: estimates, with the fixed parameters of the prior."""
        return self.prior.with_vector(self.names, jnp.asarray(self.estimate))

    @property
    def correlation(self) -> np.ndarray:
        """(..., n, n) correlation matrix of the fitted names."""
        sd = np.sqrt(np.diagonal(self.covariance, axis1=-2, axis2=-1))
        return self.covariance / (sd[..., :, None] * sd[..., None, :])

    @property
    def dof(self) -> int:
        """Residual degrees of freedom m - n."""
        return self.num_residuals - len(self.fit_names)

    @property
    def message(self) -> str:
        """How the fit ended, in words (single fits)."""
        return result_message(int(self.result_code), bool(self.converged))

    @property
    def fixed(self) -> dict[str, float]:
        """Parameters held fixed: the mechanical ones, and unidentifiable ones at their prior."""
        out = {n: float(getattr(self.prior, n)) for n in FIXED}
        # Bench effects the user set but did not ask to estimate are assumptions too.
        out.update({n: float(getattr(self.prior, n)) for n in NUISANCE
                    if n not in self.names and n in ADDITIVE_SCALE and float(getattr(self.prior, n)) != 0.0})
        for n, ok in zip(self.names, self.identifiable):
            if not ok:
                out[n] = float(getattr(self.prior, n))
        return out

    def to_dict(self) -> dict[str, Any]:
        """The result JSON of a single fit (SI units; null where undefined).

        Carries everything :meth:`from_dict` needs to rebuild this object:
        the full covariance with its names, the prior motor, the LM history.
        """
        if self.batch_shape:
            raise TypeError("to_dict() is for one fit; index the batch first")

        def num(x):
            x = float(x)
            return x if math.isfinite(x) else None

        params = {}
        for i, n in enumerate(self.names):
            ok = self.identifiable[i]
            params[n] = {
                "estimate": num(self.estimate[i]),
                "se": num(self.se[i]) if ok else None,
                "ci95": [num(self.ci95[i, 0]), num(self.ci95[i, 1])] if ok else None,
                "unit": UNITS[n],
                "identifiable": bool(ok),
                "initial": num(self.initial[i]),
                "prior": num(getattr(self.prior, n)),
            }
            if not ok:
                params[n]["reason"] = self.identifiability.reasons.get(n, "not identifiable")
        history = None
        if self.history is not None:
            history = {"names": list(self.fit_names), "values": [[num(v) for v in row] for row in self.history]}
        return {
            "parameters": params,
            "names": list(self.fit_names),
            "covariance": [[num(c) for c in row] for row in self.covariance],
            "correlation": [[num(c) for c in row] for row in self.correlation],
            "sigma_hat": num(self.sigma_hat),
            "rss": num(self.rss),
            "converged": bool(self.converged),
            "message": self.message,
            "result_code": int(self.result_code),
            "iterations": int(self.iterations),
            "num_residuals": self.num_residuals,
            "dof": self.dof,
            "t_factor": self.t_factor,
            "identifiability": self.identifiability.to_dict(),
            "fixed": self.fixed,
            "prior": self.prior.all_values(),
            "history": history,
            "source": self.source,
            "delay_samples": self.delay_samples,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Calibration:
        """Rebuild a single fit from :meth:`to_dict` output (e.g. a saved result JSON).

        ``null`` becomes NaN. Results saved before the ``prior`` section existed
        get their prior from ``parameters.<name>.prior`` and ``fixed``.
        """
        def arr(x):
            return np.array([[np.nan if v is None else float(v) for v in row] for row in x], dtype=float)

        def num(x):
            return np.nan if x is None else float(x)

        params = d["parameters"]
        names = tuple(params)
        fit_names = tuple(d["names"])
        ci = [params[n]["ci95"] or [None, None] for n in names]
        if "prior" in d:
            prior = MotorParams(**{k: float(v) for k, v in d["prior"].items()})
        else:
            prior = MotorParams(**{**{n: params[n]["prior"] for n in names},
                                   **{n: d["fixed"][n] for n in FIXED if n in d["fixed"]}})
        hist = d.get("history")
        m = int(d["num_residuals"])
        return cls(
            names=names,
            estimate=np.array([num(params[n]["estimate"]) for n in names]),
            se=np.array([num(params[n]["se"]) for n in names]),
            ci95=arr(ci),
            identifiable=tuple(bool(params[n]["identifiable"]) for n in names),
            fit_names=fit_names,
            covariance=arr(d["covariance"]) if fit_names else np.zeros((0, 0)),
            sigma_hat=np.float64(num(d["sigma_hat"])),
            rss=np.float64(num(d.get("rss"))),
            iterations=np.int64(d["iterations"]),
            converged=np.bool_(d["converged"]),
            result_code=np.int64(d.get("result_code", 0 if d["converged"] else -1)),
            initial=np.array([num(params[n].get("initial", params[n]["estimate"])) for n in names]),
            prior=prior,
            identifiability=Identifiability.from_dict(d["identifiability"]),
            num_residuals=m,
            t_factor=float(d.get("t_factor") or t_ppf(0.975, m - len(fit_names))),
            source=d.get("source", "synthetic bench"),
            history=None if hist is None else arr(hist["values"]),
            delay_samples=int(d.get("delay_samples", 0)),
        )

    def to_pandas(self):
        """One row per parameter: estimate, SE, 95 % CI, relative CI half-width (%), identifiable.

        Values in SI units, named in the ``unit`` column; index ``parameter``.
        """
        import pandas as pd

        if self.batch_shape:
            raise TypeError("to_pandas() is for one fit; index the batch first")
        half = self.t_factor * self.se
        return pd.DataFrame(
            {
                "unit": [UNITS[n] for n in self.names],
                "estimate": self.estimate,
                "se": self.se,
                "ci95_low": self.ci95[:, 0],
                "ci95_high": self.ci95[:, 1],
                "rel_ci95_percent": 100.0 * half / np.abs(self.estimate),
                "identifiable": list(self.identifiable),
                "prior": [float(getattr(self.prior, n)) for n in self.names],
                "initial": self.initial,
                "reason": [self.identifiability.reasons.get(n, "") for n in self.names],
            },
            index=pd.Index(self.names, name="parameter"),
        )

    def to_jaxonomy(self, *, locked: bool = False, initial_state: Any = None, name: str = "pmsm"):
        """A ``jaxonomy.library.drives.PMSM`` block configured with this calibration.

        Estimates for the identifiable parameters, the prior for the rest and
        for the fixed ones (pole_pairs, J, B, T_load).

        Args:
            locked: clamp the rotor (standstill bench), fixed when the block is built.
            initial_state: ``[i_d, i_q, w_m, theta_m]`` (A, A, rad/s, rad); default rest.
            name: block name in the diagram.
        """
        from ..bench import pmsm_block

        if self.batch_shape:
            raise TypeError("to_jaxonomy() is for one fit; index the batch first")
        return pmsm_block(self.motor, locked=locked, initial_state=initial_state, name=name)

    def warnings(self) -> list[str]:
        """Plain-language warnings: non-identifiable parameters, failed fit, strong correlations."""
        out = []
        if not bool(self.converged):
            out.append(f"the fit did not converge: {self.message}")
        for i, n in enumerate(self.names):
            if not self.identifiable[i]:
                why = self.identifiability.reasons.get(n, "not identifiable")
                out.append(f"{n} is not identifiable ({why}); held at its prior {self.estimate[i]:.6g} {UNITS[n]}, "
                           "not calibrated")
        for a, b, r in self.correlations(threshold=0.9):
            out.append(f"{a} and {b} are strongly correlated (r = {r:+.3f}): the data mostly fixes a combination")
        return out

    def correlations(self, threshold: float = 0.1) -> list[tuple[str, str, float]]:
        """Pairs of fitted parameters with ``|r| > threshold``, largest first."""
        corr = self.correlation
        pairs = [(self.fit_names[i], self.fit_names[j], float(corr[i, j]))
                 for i in range(len(self.fit_names)) for j in range(i + 1, len(self.fit_names))]
        return sorted([p for p in pairs if abs(p[2]) > threshold], key=lambda p: -abs(p[2]))

    def __str__(self) -> str:
        """An lmfit-style report: fit statistics, parameters, correlations, warnings."""
        if self.batch_shape:
            n_ok = int(np.sum(self.converged))
            return f"Calibration batch of {len(self)} fits, {n_ok} converged"
        ident = self.identifiability
        stat = [
            ("source", self.source),
            ("fit result", f"{self.message} after {int(self.iterations)} LM steps"),
            ("# data points", f"{self.num_residuals} (i_d and i_q samples)"),
            ("# variables", f"{len(self.fit_names)} ({', '.join(self.fit_names)})"),
            ("degrees of freedom", f"{self.dof}"),
            ("sigma_hat [A]", f"{float(self.sigma_hat):.6g}"),
            ("RSS [A^2]", f"{float(self.rss):.6g}"),
            ("identifiability", f"rank {ident.rank}/{len(ident.names)}, condition number {ident.condition_number:.3g}"),
        ]
        lines = ["[[Fit Statistics]]"] + [f"    {k:<19}= {v}" for k, v in stat]
        lines += ["[[Parameters]]",
                  f"    {'name':<9} {'unit':<4} {'estimate':>12} {'std err':>10} {'95% CI':>27} "
                  f"{'rel. CI':>12}  identifiable"]
        for i, n in enumerate(self.names):
            if self.identifiable[i]:
                ci = f"[{self.ci95[i, 0]:.6g}, {self.ci95[i, 1]:.6g}]"
                rel = f"{100.0 * self.t_factor * self.se[i] / abs(self.estimate[i]):.3g} %"
                lines.append(f"    {n:<9} {UNITS[n]:<4} {self.estimate[i]:>12.6g} {self.se[i]:>10.3g} {ci:>27} "
                             f"{'+/-' + rel:>12}  yes")
            else:
                lines.append(f"    {n:<9} {UNITS[n]:<4} {self.estimate[i]:>12.6g} {'-':>10} {'held at prior':>27} "
                             f"{'-':>12}  NO")
        pairs = self.correlations(threshold=0.1)
        lines.append("[[Correlations]] (unreported correlations are < 0.100)")
        lines += [f"    C({a}, {b}){'':<{max(0, 16 - len(a) - len(b))}} = {r:+.4f}" for a, b, r in pairs] or [
            "    none"]
        warnings = self.warnings()
        if warnings:
            lines.append("[[Warnings]]")
            lines += [f"    {w}" for w in warnings]
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """Jupyter: the summary table of the HTML report."""
        if self.batch_shape:
            return f"<p>{str(self)}</p>"
        from ..report import summary_html

        return summary_html(self.to_dict())


def _start_vector(initial: MotorParams | np.ndarray | None, prior: MotorParams, names: tuple[str, ...]) -> np.ndarray:
    if initial is None:
        return parameter_values(prior, names, np)
    if isinstance(initial, MotorParams):
        return parameter_values(initial, names, np)
    return np.asarray(initial, dtype=float)


def fit_currents(
    experiment: Experiment,
    currents: np.ndarray,
    prior: MotorParams,
    *,
    initial: MotorParams | np.ndarray | None = None,
    identifiability: Identifiability | None = None,
    names: tuple[str, ...] = ESTIMATED,
    options: FitOptions = FitOptions(),
    source: str = "synthetic bench",
    delay_samples: int = 0,
) -> Calibration:
    """Fit measured currents of a known experiment; batched if ``currents`` is.

    Args:
        experiment: the applied voltages and rotor conditions (M samples),
            shared by all datasets or, with a leading axis B on every array,
            one per dataset (then ``currents`` must be batched).
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2) or (B, M, 2).
        prior: nominal motor: scale of the search, value of anything not
            identifiable, and the fixed parameters.
        initial: starting point, shape (len(names),) or (B, len(names)) in SI
            units, or a MotorParams; default ``options.start`` (an estimate
            from the data, or the prior).
        identifiability: a verdict already computed for this experiment and
            prior (computed here if not given).
        names: parameters to estimate.
        options: solver settings.
        source: label of the data, for reports.
        delay_samples: the inverter delay already applied in ``experiment``
            (recorded in the result).

    Returns:
        A :class:`Calibration`, with a leading batch axis when ``currents`` has one.
    """
    currents = np.asarray(currents, dtype=float)
    batched = currents.ndim == 3
    if currents.shape[-2:] != (experiment.num_samples, 2):
        raise DrivecalError(
            f"{source}: currents have shape {currents.shape}, expected ({experiment.num_samples}, 2) "
            "to match the experiment."
        )
    if not np.all(np.isfinite(currents)):
        raise DrivecalError(f"{source}: currents contain NaN or Inf; remove or repair those samples.")
    per_dataset = experiment.voltages.ndim == 3
    if per_dataset and (not batched or experiment.voltages.shape[0] != currents.shape[0]):
        raise DrivecalError(f"{source}: a batch of {experiment.voltages.shape[0]} experiments needs currents of "
                            f"shape ({experiment.voltages.shape[0]}, M, 2), got {currents.shape}.")
    experiment = model_experiment(experiment, prior, names)
    # A batch of experiments shares one plan shape; judge it on the first (the structure is common).
    first = jax.tree_util.tree_map(lambda a: a[0], experiment) if per_dataset else experiment
    ident = identifiability or assess_identifiability(first, prior, names=names)
    fit_names = ident.fit_names
    if not fit_names:
        raise DrivecalError(
            f"{source}: this experiment identifies none of {', '.join(names)}; "
            "add locked d/q steps and a free spin-up."
        )
    cur = currents if batched else currents[None]
    fit_idx = [names.index(n) for n in fit_names]
    start = None  # from the data, inside the compiled solve
    if initial is not None or options.start != "data":
        start = np.broadcast_to(_start_vector(initial, prior, names), cur.shape[:1] + (len(names),))
        if not np.all(np.isfinite(to_search(prior, fit_names, start[:, fit_idx]))):
            raise DrivecalError(f"{source}: initial values of {', '.join(fit_names)} must be finite, and positive "
                                "where the parameter is (R, inductances, flux, alpha_R).")
    history = None
    if batched:
        solved = _solve_staged(cur, start, prior, experiment, tuple(names), fit_names, options)
    else:
        solved = jax.device_get(_solve_batch(cur, start, prior, experiment, tuple(names), fit_names,
                                             dataclasses.replace(options, first_pass_steps=None), record=True))
        z0 = to_search(prior, fit_names, solved.initial[:, fit_idx])
        steps = [z0[0]] + list(np.asarray(solved.accepted)[0, : int(solved.iterations[0])])
        steps = [steps[0]] + [b for a, b in zip(steps, steps[1:]) if not np.array_equal(a, b)]
        history = from_search(prior, fit_names, np.asarray(steps), np)[0]
        if not np.array_equal(history[-1], solved.theta[0]):  # the final Gauss-Newton step (FitOptions.step_se)
            history = np.concatenate([history, solved.theta[:1]])

    m = experiment.num_samples * 2
    t_factor = float(t_ppf(0.975, m - len(fit_names)))
    b = cur.shape[0]
    estimate = np.broadcast_to(parameter_values(prior, names, np), (b, len(names))).copy()
    se = np.full((b, len(names)), np.nan)
    estimate[:, fit_idx] = solved.theta
    se[:, fit_idx] = np.sqrt(np.diagonal(solved.covariance, axis1=-2, axis2=-1))
    ci95 = np.stack([estimate - t_factor * se, estimate + t_factor * se], axis=-1)
    calib = Calibration(
        names=tuple(names),
        estimate=estimate,
        se=se,
        ci95=ci95,
        identifiable=tuple(n in fit_names for n in names),
        fit_names=fit_names,
        covariance=np.asarray(solved.covariance),
        sigma_hat=np.asarray(solved.sigma_hat),
        rss=np.asarray(solved.rss),
        iterations=np.asarray(solved.iterations),
        converged=np.asarray(solved.converged),
        result_code=np.asarray(solved.result_code),
        initial=np.array(solved.initial),
        prior=prior,
        identifiability=ident,
        num_residuals=m,
        t_factor=t_factor,
        source=source,
        history=history,
        delay_samples=int(delay_samples),
        residuals=np.asarray(solved.residuals),
    )
    return calib if batched else calib[0]


def fit(
    bench: BenchData,
    prior: MotorParams,
    *,
    initial: MotorParams | np.ndarray | None = None,
    names: tuple[str, ...] = ESTIMATED,
    options: FitOptions = FitOptions(),
    measured_speed: bool = True,
    delay_samples: int = 0,
) -> Calibration:
    """Calibrate a motor from bench data.

    Identifiability is judged first at ``prior``; parameters the bench run
    cannot identify are held at their prior and reported as such.

    Args:
        bench: the recorded run.
        prior: nominal motor (datasheet values) and fixed parameters.
        initial: starting point (default: ``options.start``, an estimate from the data).
        names: parameters to estimate.
        options: solver settings.
        measured_speed: where free segments carry a measured ``w_m``, use it as
            an input so J and B play no part (see ``BenchData.experiment``).
        delay_samples: the inverter's PWM/computation delay (samples).
    """
    return fit_currents(
        bench.experiment(measured_speed=measured_speed, delay_samples=delay_samples),
        bench.currents,
        prior,
        initial=initial,
        names=names,
        options=options,
        source=bench.source,
        delay_samples=delay_samples,
    )
