"""The Levenberg-Marquardt solve behind a batch of fits: one fit's solve, tiling and batching.

One ``jax.jit``-compiled function per plan shape solves a batch of fits
(under ``vmap``, in tiles of ``SOLVE_TILE``), and returns the estimate, the
Jacobian's covariance and how the solve ended; :mod:`._fit` turns it into a
:class:`drivecal.results.Calibration`. A single fit takes the same steps from
the host (:mod:`._host_lm`), with no solve program of its own. The residuals
and the optimistix solver are in :mod:`._lm`, imported where a solve is
traced: a solve loaded from the disk cache needs no optimistix.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass
from ..model import LEGACY_EMITTERS, cached_call, join_current_parts, run_once_options
from ..physics import from_search, to_search
from ..results import solver_code
from ._initial import start_from_data
from ._options import FitOptions


@pytree_dataclass
class _Solved:
    """Raw per-fit arrays out of the compiled solve (leading batch axis)."""

    theta: jnp.ndarray  # (n,) fitted parameters, their units
    covariance: jnp.ndarray  # (n, n)
    sigma_hat: jnp.ndarray  # () A
    rss: jnp.ndarray  # () A^2
    iterations: jnp.ndarray  # ()
    result_code: jnp.ndarray  # () optimistix RESULTS index
    converged: jnp.ndarray  # () bool
    accepted: jnp.ndarray | None = None  # (max_steps, n) z after each LM step (a single fit's, from _host_lm)
    initial: jnp.ndarray | None = None  # (len(names),) where the search started, SI units
    residuals: jnp.ndarray | None = None  # (M, 2) A, model minus measured at the last linearisation


def _solve_one(currents, z0, prior, experiment, names, options) -> _Solved:
    import optimistix as optx

    from ._lm import _LevenbergMarquardt, _gauss_newton_step, _residual_fn, _size_and_sum_of_squares

    residual = _residual_fn(prior, experiment, names, currents)
    solver = _LevenbergMarquardt(rtol=options.rtol, atol=options.atol, step_se=options.step_se)
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
    from ._lm import _residual_fn

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


def _first(tree):
    """The first entry of every array of ``tree`` (a batch's leading axis dropped)."""
    return jax.tree_util.tree_map(lambda a: a[0], tree)


@functools.partial(jax.jit, static_argnames=("names", "fit_names", "options"))
def _solve_compiled(currents, start, prior, experiment, names, fit_names, options) -> _Solved:
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
            return jax.vmap(_solve_one, in_axes=(0, 0, None, exp_axis, None, None))(
                cur, z, prior, exp, fit_names, options)

        tiles = jax.tree_util.tree_map(lambda a: a.reshape((batch // SOLVE_TILE, SOLVE_TILE) + a.shape[1:]),
                                       (currents, z0, experiment) if per_dataset else (currents, z0))
        solved = jax.tree_util.tree_map(lambda a: a.reshape((batch,) + a.shape[2:]), jax.lax.map(tile, tiles))
    elif batch == 1:
        # A batch of one (a fleet's lone motor of its plan shape) traced as one fit: under vmap every loop
        # body of the solve is traced again by the batching rules (trace and lower 2.7 -> 1.3 s, compile
        # 2.0 -> 1.8 s on examples/bench.csv, the same bits there).
        one = _solve_one(currents[0], z0[0], prior, _first(experiment) if per_dataset else experiment,
                         fit_names, options)
        solved = jax.tree_util.tree_map(lambda a: a[None], one)
    else:
        solved = jax.vmap(_solve_one, in_axes=(0, 0, None, 0 if per_dataset else None, None, None))(
            currents, z0, prior, experiment, fit_names, options
        )
    return dataclasses.replace(solved, initial=start)


def _solve_fields(currents, start, prior, experiment, names, fit_names, options):
    solved = _solve_compiled(currents, start, prior, experiment, names, fit_names, options)
    return tuple(getattr(solved, f.name) for f in dataclasses.fields(_Solved))


def _solve_batch(currents, start, prior, experiment, names, fit_names, options) -> _Solved:
    """Fit ``fit_names`` (of ``names``) to a batch: currents (B, M, 2) A. One compiled call.

    ``start`` (B, len(names)) SI units is where each search starts, or None:
    from the data (``initial.start_from_data``, inside the same call). The
    experiment is shared (arrays of M samples) or one per dataset (a leading
    B axis on every array, e.g. a fleet whose benches each measured their own
    voltages and speed).
    """
    # Jacobian sweeps from the linearised steps are several times faster for one or two fits; from a
    # few fits up, forward mode through the scans wins (less memory traffic).
    linearised = currents.shape[0] <= LINEARISED_TANGENTS_MAX_BATCH
    # The saturating law's steps as loops (model_experiment) compile several times faster, and one or two fits
    # run as fast; a vmap-ped batch ran them slower (Hinkkanen's SyRM, 16 fits: 6.0 s against 5.1 s unrolled,
    # compiled in 17 s against 46 s), so a batch unrolls them. The dead time's stay loops in any batch.
    rolled = experiment.rolled and (linearised or experiment.dead_time)
    if (experiment.linearised_tangents, experiment.rolled) != (linearised, rolled):  # replace(): ~0.1 ms of a fit
        experiment = dataclasses.replace(experiment, linearised_tangents=linearised, rolled=rolled)
    # A batch's solve with XLA's legacy emitters: 235 object files against 401 for a fleet's chunk of 256 (a
    # kernel of more than _setup.MAX_CACHED_OBJECTS is not kept, and every batch process compiled it again).
    # A batch of one's as a program that runs once (model.run_once_options).
    single = run_once_options(experiment.dead_time)
    fields = cached_call(_solve_fields, "solve_batch", currents, start, prior, experiment, names=names,
                         fit_names=fit_names, options=options,
                         compiler_options=LEGACY_EMITTERS if currents.shape[0] > 1 else single)
    return _Solved(*fields)


def _straggler_bucket(n: int, total: int) -> int:
    """Batch size to re-solve n stragglers of a batch of ``total``: a power of 4, so few shapes compile."""
    size = 4
    while size < n:
        size *= 4
    return min(size, total)


def _max_steps_reached(solved: _Solved) -> np.ndarray:
    """The fits of ``solved`` (numpy) that stopped at their step limit; optimistix, which numbers that
    ending, is imported only when some fit did not converge."""
    if np.all(solved.converged):
        return np.empty(0, dtype=np.intp)
    import optimistix as optx

    return np.flatnonzero(solved.result_code == solver_code(optx.RESULTS.nonlinear_max_steps_reached))


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
    again = _max_steps_reached(solved)
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
