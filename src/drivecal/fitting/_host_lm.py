"""One fit's Levenberg-Marquardt stepped from the host: each step one call of the fit's sensitivity kernel.

A single fit needs no solve program of its own. What an LM step asks of the model, the predicted
outputs and their Jacobian at a point, is what ``identify.jacobian_and_outputs`` computes in one
compiled call, the kernel the identifiability check has just compiled or loaded for the same
experiment and parameters. The rest of a step is algebra on n x n matrices (n, the fitted
parameters, is a handful), done here in numpy.

The steps are those of ``_lm._LevenbergMarquardt`` inside a batch's compiled solve, taken in the same
order: optimistix's Levenberg-Marquardt loop (``optx.least_squares``: the classical trust region's
accept, reject and step-size rules, the Cauchy termination, the step limit), the damped step through
the normal equations (``_lm._NormalEquationsDescent``), the statistical stop and the last Gauss-Newton
step (``FitOptions.step_se``). Only the order of the floating-point sums differs (numpy's against
XLA's). Measured against the compiled solve on every single fit of ``drivecal fit`` on both examples,
the demo, a saturating SyRM and PM-SyRM (fits of 2 to 31 steps, with and without the dead time): the
same steps and endings, the estimates within 5e-12 of a standard error; tests/fitting/test_host_lm.py
checks it on fits of the default plan.

What it saves: the solve program, traced and compiled by a first fit for each set of fitted parameters
(examples/bench.csv: ~1 s of tracing, ~1.3 s of compiling) and loaded by every later one (~0.2 s).
Its steps call the sensitivity kernel as often as the compiled solve evaluated the model, and run as
fast. A batch keeps the compiled solve: its fits step together, vmapped, in one program.
"""

from __future__ import annotations

import jax
import numpy as np

from ..identify import jacobian_and_outputs
from ..model import Experiment, current_parts
from ..physics import MotorParams, from_search, to_search
from ._initial import start_on_host
from ._options import FitOptions

#: optimistix's ``RESULTS`` indices of the endings this loop can have (tests check them against optimistix,
#: which a fit loaded from the cache does not import: ~0.35 s).
SUCCESSFUL, SINGULAR, MAX_STEPS_REACHED, NONFINITE = 0, 2, 7, 9

#: optimistix's ``ClassicalTrustRegion``: a step is accepted where the loss fell by at least LOW_CUTOFF of the
#: predicted fall, the step size then grows by HIGH_CONSTANT where it fell by HIGH_CUTOFF of it; a rejected step
#: shrinks it by LOW_CONSTANT.
LOW_CUTOFF, HIGH_CUTOFF, LOW_CONSTANT, HIGH_CONSTANT = 0.01, 0.99, 0.25, 3.5


def solve_on_host(currents: np.ndarray, start: np.ndarray | None, prior: MotorParams, experiment: Experiment,
                  names: tuple[str, ...], fit_names: tuple[str, ...], options: FitOptions) -> dict[str, np.ndarray]:
    """One fit of ``fit_names`` (of ``names``) to ``currents`` (1, M, 2) A; the fields of ``_solver._Solved``.

    ``start`` (1, len(names)) SI units, or None: from the data (``_initial.start_on_host``). Every field has
    the leading axis of one fit, as the compiled solve returns them; ``accepted`` holds the iterate after
    each step (``options.max_steps`` rows).
    """
    if start is None:
        start = start_on_host(experiment, currents, prior, names)
    fit_idx = [names.index(n) for n in fit_names]
    z = to_search(prior, fit_names, start[0, fit_idx])
    on_host = jax.tree_util.tree_map(np.asarray, experiment)  # no JAX operation dispatched (each would compile)
    parts = current_parts(on_host, currents[0])  # the measured speed's parts (where an output) come last
    speed = parts[len(parts) - len(experiment.speed_outputs):]
    measured = np.concatenate([np.ravel(currents[0])] + [np.asarray(p, dtype=float) for p in speed])

    def linearise(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (m,) and their Jacobian in search units (m, n) at ``y``."""
        theta, dtheta_dz = from_search(prior, fit_names, y, np)
        jac, out = jacobian_and_outputs(prior.with_vector(fit_names, theta), experiment, fit_names)
        return np.asarray(out) - measured, np.asarray(jac) * dtheta_dz

    n = z.shape[0]
    with np.errstate(all="ignore"):  # a diverging trial point's residuals are inf or NaN: rejected, as in JAX
        y, result, steps, accepted, last = _iterate(linearise, z, n, options)
        residual, gram, gradient = last
        residual = np.full(measured.shape, np.nan) if residual is None else residual  # no step taken
        m, rss = residual.shape[0], float(residual @ residual)
        s2 = rss / (m - n)
        step, size = _gauss_newton_step(gram, gradient, s2)
        z_final = y - step if size <= options.step_se else y
        theta = from_search(prior, fit_names, z_final, np)[0]
        dtheta_dz = from_search(prior, fit_names, y, np)[1]
        cov = s2 * _inverse(gram) * np.outer(dtheta_dz, dtheta_dz)
    converged = (result == SUCCESSFUL and bool(np.all(np.isfinite(theta))) and bool(np.all(np.isfinite(cov)))
                 and bool(np.all(np.diag(cov) > 0)))
    return {"theta": theta[None], "covariance": cov[None], "sigma_hat": np.sqrt([s2]), "rss": np.array([rss]),
            "iterations": np.array([steps]), "result_code": np.array([result]), "converged": np.array([converged]),
            "accepted": accepted[None], "initial": np.asarray(start, dtype=float),
            "residuals": residual[: 2 * experiment.num_samples].reshape(1, -1, 2)}


def _iterate(linearise, y: np.ndarray, n: int, options: FitOptions) -> tuple:
    """optimistix's least-squares loop with ``_lm._LevenbergMarquardt``: the last accepted point, the ending
    (a RESULTS index), the steps taken, the accepted point after each step and the last accepted point's
    ``(residual, J^T J, J^T r)``."""
    y_eval, step_size, first = y, 1.0, True
    residual, jac = None, None  # the last accepted point's (optimistix starts from zeros: the first step is taken)
    gram, gradient = np.zeros((n, n)), np.zeros(n)
    accepted = np.zeros((options.max_steps, n))
    result, terminate, steps, taken = SUCCESSFUL, False, 0, 0
    if not np.all(np.isfinite(y)):  # as optimistix checks the start
        result = NONFINITE
    while not terminate and result == SUCCESSFUL and steps < options.max_steps:
        y_before = y
        r_eval, j_eval = linearise(y_eval)
        if first:
            accept, good = True, False
        else:
            y_diff = y_eval - y
            predicted = 0.5 * (_sum_squares(jac @ y_diff + residual) - _sum_squares(residual))
            fell = 0.5 * _sum_squares(r_eval) - 0.5 * _sum_squares(residual)
            accept = bool(fell <= LOW_CUTOFF * predicted)
            good = bool(fell < HIGH_CUTOFF * predicted) and bool(predicted < 0)
        step_size *= (HIGH_CONSTANT if good else 1.0) if accept else LOW_CONSTANT
        steps, taken = steps + 1, taken + accept
        converged = False
        if accept:
            gram, gradient = j_eval.T @ j_eval, j_eval.T @ r_eval
            f_diff = r_eval - (residual if residual is not None else 0.0)
            converged = (_max_norm(np.abs(y_eval - y) / (options.atol + options.rtol * np.abs(y_eval))) < 1
                         and _max_norm(np.abs(f_diff) / (options.atol + options.rtol * np.abs(r_eval))) < 1)
            y, residual, jac = y_eval, r_eval, j_eval
        dz, ok = _damped_step(step_size, gram, gradient)
        y_eval, first = y + dz, False
        result = SUCCESSFUL if ok else SINGULAR
        accepted[steps - 1] = y
        terminate = converged
        if options.step_se and taken > 0:
            s2 = _sum_squares(residual) / (residual.shape[0] - n)
            terminate = terminate or _gauss_newton_step(gram, gradient, s2)[1] <= options.step_se
        if result == SUCCESSFUL and not np.all(np.isfinite(y_before)):  # optimistix checks the point it stepped from
            result = NONFINITE
    if result == SUCCESSFUL and not terminate:
        result = MAX_STEPS_REACHED
    return y, result, steps, accepted, (residual, gram, gradient)


def _damped_step(step_size: float, gram: np.ndarray, gradient: np.ndarray) -> tuple[np.ndarray, bool]:
    """``_lm._NormalEquationsDescent.step``: ``(J^T J + I / step_size) dz = -J^T r`` by Cholesky (zero and
    False where it has no finite solution)."""
    eps, big = np.finfo(float).eps, np.finfo(float).max
    damping = big if step_size <= eps else 1.0 / step_size
    try:
        lower = np.linalg.cholesky(gram + damping * np.eye(gram.shape[0]))
        dz = -np.linalg.solve(lower.T, np.linalg.solve(lower, gradient))
    except np.linalg.LinAlgError:
        return np.zeros_like(gradient), False
    ok = bool(np.all(np.isfinite(dz)))
    return (dz if ok else np.zeros_like(dz)), ok


def _gauss_newton_step(gram: np.ndarray, gradient: np.ndarray, s2: float) -> tuple[np.ndarray, float]:
    """``_lm._gauss_newton_step`` on the host: ``(J^T J)^-1 J^T r`` and its size in standard errors (inf
    where not finite)."""
    try:
        step = np.linalg.solve(gram, gradient)
    except np.linalg.LinAlgError:
        return np.full_like(gradient, np.nan), float("inf")
    size = float(np.sqrt(step @ gram @ step / s2))
    return step, size if np.isfinite(size) else float("inf")


def _inverse(gram: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.inv(gram)
    except np.linalg.LinAlgError:
        return np.full_like(gram, np.nan)


def _sum_squares(x: np.ndarray) -> float:
    return float(x @ x)


def _max_norm(x: np.ndarray) -> float:
    """optimistix's ``max_norm`` (0 for an empty array)."""
    return float(np.max(x)) if x.size else 0.0
