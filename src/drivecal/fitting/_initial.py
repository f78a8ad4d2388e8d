"""A starting point for the fit from the data itself (equation error).

Levenberg-Marquardt pays one rollout of the whole bench run per step, and
from a datasheet guess 30-50 % off it needs ~12 steps; from within ~1 % it
needs 4-5. This module gets within ~1 % without any rollout, by regressions
that read the recorded currents as regressors ("equation error"), all
vectorised over the samples:

- Locked rotor: the forward model's RK4 step of ``L di/dt = v - R i`` is
  exactly ``i[k+1] = a i[k] + b v[k]`` with ``a = P4(-R h / L)`` (P4 the
  4th-order Taylor polynomial of exp) and ``b = (1 - a) / R``. ``a, b`` per
  axis come from a least-squares fit with ``i[k-1]`` as the instrument for
  the noisy regressor ``i[k]`` (plain least squares would bias ``a`` towards
  zero by the sensor noise), giving R and Ld, Lq.
- Free rotor: the q equation over one sample,
  ``v_q - R i_q - Lq di_q/dt = p w (Ld i_d + lambda_m)``, with the speed
  measured, or integrated from the recorded currents through the mechanical
  equation (then ``w`` is affine in lambda_m), fitted for lambda_m by a few
  scalar Gauss-Newton steps.

Each estimate falls back to the prior where its data does not determine it
(no excitation on that axis, no free segment) or where it comes out
non-finite or more than a factor ``SPAN`` from the prior. It is only a start:
the fit (``fitting._fit``) is what the calibration reports.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..model import cached_call
from ..model import Experiment
from ..physics import MotorParams

#: An estimate further than this factor from the prior is not trusted as a start.
SPAN = 4.0


#: Datasets per tile of a batched :func:`start_from_data`.
START_TILE = 32


def _rk4_factor(s):
    """RK4's growth factor ``1 + s + s^2/2 + s^3/6 + s^4/24`` of ``x' = (s/h) x`` over one step."""
    return 1.0 + s * (1.0 + s * (0.5 + s * (1.0 / 6.0 + s / 24.0)))


def _rate_from_factor(a, xp=jnp):
    """``s = -R h / L`` with ``_rk4_factor(s) == a`` (0 < a < 1): log(a), polished by Newton."""
    s = xp.log(xp.clip(a, 1e-12, 1.0 - 1e-15))
    for _ in range(3):
        ds = 1.0 + s * (1.0 + s * (0.5 + s / 6.0))
        s = s - (_rk4_factor(s) - a) / ds
    return s


def _instrumented_lsq(z1, z2, x1, x2, y, w, xp=jnp):
    """Solve ``sum w z (x . theta - y) = 0`` for theta (2,): instrumental-variable least squares."""
    a11, a12 = xp.sum(w * z1 * x1), xp.sum(w * z1 * x2)
    a21, a22 = xp.sum(w * z2 * x1), xp.sum(w * z2 * x2)
    c1, c2 = xp.sum(w * z1 * y), xp.sum(w * z2 * y)
    det = a11 * a22 - a12 * a21
    return (a22 * c1 - a12 * c2) / det, (a11 * c2 - a21 * c1) / det


def _affine_prefix(a, b, xp=jnp):
    """``s[k] = a[k] * s[k-1] + b[k]`` from ``s[-1] = 0`` for all k: at once in JAX (log-depth scan), sample by
    sample in numpy (``xp`` numpy)."""
    def combine(first, second):
        return second[0] * first[0], second[0] * first[1] + second[1]

    if xp is jnp:
        return jax.lax.associative_scan(combine, (a, b))[1]
    s, out = 0.0, np.empty(len(a))  # on the host: sample by sample (~1 ms for 1 400 samples)
    for k, (a_k, b_k) in enumerate(zip(a.tolist(), b.tolist())):
        s = a_k * s + b_k
        out[k] = s
    return out


def _start_one(experiment: Experiment, currents, prior: MotorParams, xp=jnp):
    """R, Ld, Lq, lambda_m (SI) from one dataset; NaN where the data does not tell."""
    h = experiment.sample_period
    i_d, i_q = currents[:, 0], currents[:, 1]
    v_d, v_q = experiment.voltages[:, 0], experiment.voltages[:, 1]
    start = experiment.segment_start
    # Sample pairs (k, k+1) inside one segment, and triples (k-1, k, k+1) for the instrument.
    pair = xp.concatenate([~start[1:], xp.array([False])])
    triple = pair & ~start
    locked = experiment.locked > 0.5

    def shift(x, by):
        return xp.roll(x, -by)

    # Locked rotor, one axis at a time: i[k+1] = a i[k] + b v[k].
    # The per-sample R follows the winding temperature; the regression sees its mean.
    warm = 1.0 + prior.alpha_R * xp.where(xp.isnan(experiment.temperature), 0.0,
                                           experiment.temperature - prior.T_ref)
    axes = []
    for i, v in ((i_d, v_d), (i_q, v_q)):
        w = (triple & locked).astype(float)
        a, b = _instrumented_lsq(shift(i, -1), v, i, v, shift(i, 1), w, xp)
        r_eff = (1.0 - a) / b
        weight = xp.sum(w * v**2)
        r_axis = r_eff / (xp.sum(w * v**2 * warm) / weight)
        inductance = -r_eff * h / _rate_from_factor(a, xp)
        ok = (weight > 0) & (a > 0) & (a < 1) & (b > 0)
        axes.append((xp.where(ok, r_axis, xp.nan), xp.where(ok, inductance, xp.nan), xp.where(ok, weight, 0.0)))
    (r_d, l_d, w_d), (r_q, l_q, w_q) = axes
    R = (xp.nan_to_num(r_d) * w_d + xp.nan_to_num(r_q) * w_q) / (w_d + w_q)
    R = xp.where(w_d + w_q > 0, R, xp.nan)
    R_use, Ld_use, Lq_use = (xp.where(xp.isfinite(x), x, p) for x, p in ((R, prior.R), (l_d, prior.Ld),
                                                                             (l_q, prior.Lq)))

    # Free rotor: the q equation over each sample, trapezoidal in the currents.
    free = pair & ~locked
    i_d_mid, i_q_mid = 0.5 * (i_d + shift(i_d, 1)), 0.5 * (i_q + shift(i_q, 1))
    y = v_q - R_use * warm * i_q_mid - Lq_use * (shift(i_q, 1) - i_q) / h
    # Speed: measured (w = c), or from the mechanical equation driven by the recorded
    # currents, w = lambda_m * u + c, integrated sample by sample from the segment's start.
    p = prior.pole_pairs
    decay = xp.exp(-h * prior.B / prior.J)
    reset = xp.where(start, 0.0, decay)
    drive_u = 1.5 * p * i_q_mid * h / prior.J
    drive_c = (1.5 * p * (Ld_use - Lq_use) * i_d_mid * i_q_mid - prior.T_load) * h / prior.J
    measured = experiment.speed_input > 0.5
    if experiment.segments is None or any(kind == "free" for _, _, kind in experiment.segments):
        u = _affine_prefix(reset, xp.where(start, 0.0, xp.roll(drive_u, 1)), xp)
        c = _affine_prefix(reset, xp.where(start, experiment.initial_state[:, 2], xp.roll(drive_c, 1)), xp)
    else:  # static: every free segment measured its speed, so nothing is integrated (a fleet's 0.1 ms a motor)
        u = c = xp.zeros_like(drive_u)
    u_mid = xp.where(measured, 0.0, 0.5 * (u + shift(u, 1)))
    c_mid = xp.where(measured, experiment.speed[:, 1], 0.5 * (c + shift(c, 1)))
    wf = free.astype(float)

    # The residual y - p (lam u + c)(Ld i_d + lam) is a0 + a1 lam + a2 lam^2 per sample, so the
    # Gauss-Newton sums over the samples are polynomials in lam: five moments, one pass over
    # the data, then the iterations on scalars.
    a0 = y - p * c_mid * Ld_use * i_d_mid
    a1 = -p * (u_mid * Ld_use * i_d_mid + c_mid)
    a2 = -p * u_mid
    m10, m11, m20, m12, m22 = (xp.sum(wf * x * z) for x, z in ((a1, a0), (a1, a1), (a2, a0), (a1, a2), (a2, a2)))
    lam = xp.asarray(prior.lambda_m, dtype=float)
    for _ in range(8):
        # sum(slope * r) and sum(slope^2) with slope = a1 + 2 a2 lam.
        slope_r = m10 + lam * (m11 + 2.0 * m20) + lam**2 * 3.0 * m12 + lam**3 * 2.0 * m22
        slope_2 = m11 + 4.0 * lam * m12 + 4.0 * lam**2 * m22
        lam = lam - slope_r / slope_2
    lam = xp.where(xp.sum(wf) > 0, lam, xp.nan)
    return {"R": R, "Ld": l_d, "Lq": l_q, "lambda_m": lam}


def equation_error_start(experiment: Experiment, currents, prior: MotorParams, names: tuple[str, ...]):
    """A start for the fit of ``names`` from the data, shape (B, len(names)) (SI units).

    Args:
        experiment: the experiment (M samples), shared or with a leading batch axis B.
        currents: measured ``[i_d, i_q]`` (A), shape (B, M, 2).
        prior: the nominal motor; names other than R, Ld, Lq, lambda_m start there.
        names: the parameters the fit searches.

    Returns:
        Per dataset and name, the equation-error estimate, or the prior where
        the data does not determine it or it lies more than ``SPAN`` from it.
    """
    return cached_call(_start_compiled, "equation_error_start", experiment, currents, prior, names=tuple(names))


def start_from_data(experiment: Experiment, currents, prior: MotorParams, names: tuple[str, ...]):
    """:func:`equation_error_start` as a traceable function (for use inside a compiled fit)."""
    # In tiles of START_TILE datasets: each tile's sums then stream its samples from cache, not from
    # memory (3x faster in a fleet's batch of 256).
    if experiment.voltages.ndim == 3:  # one experiment per dataset
        found = jax.lax.map(lambda pair: _start_one(*pair, prior), (experiment, currents), batch_size=START_TILE)
    else:
        found = jax.lax.map(lambda cur: _start_one(experiment, cur, prior), currents, batch_size=START_TILE)
    return _trusted(found, prior, names, currents.shape[:1], jnp)


def start_on_host(experiment: Experiment, currents: np.ndarray, prior: MotorParams,
                  names: tuple[str, ...]) -> np.ndarray:
    """:func:`equation_error_start` of one dataset in numpy, shape (1, len(names)) (SI units): no compiled call.

    The same equations; the sums and the speed's running integral add up in another order (equal to
    float64 rounding). ``currents`` (1, M, 2) A; ``experiment`` shared (no batch axis).
    """
    to_host = functools.partial(jax.tree_util.tree_map, np.asarray)
    with np.errstate(all="ignore"):  # an axis without excitation: 0/0, then the prior (as in JAX)
        found = {k: np.asarray(v)[None] for k, v in _start_one(to_host(experiment), np.asarray(currents[0]),
                                                                to_host(prior), np).items()}
        return _trusted(found, to_host(prior), names, (1,), np)


def _trusted(found: dict, prior: MotorParams, names: tuple[str, ...], batch: tuple[int, ...], xp) -> Any:
    """Per dataset and name, the estimate ``found`` where it is finite and within ``SPAN`` of the prior, else the
    prior; (B, len(names))."""
    columns = []
    for n in names:
        p = xp.asarray(getattr(prior, n), dtype=float)
        if n not in found:
            columns.append(xp.broadcast_to(p, batch))
            continue
        x = found[n]
        trusted = xp.isfinite(x) & (x > p / SPAN) & (x < p * SPAN)
        columns.append(xp.where(trusted, x, p))
    return xp.stack(columns, axis=-1)


_start_compiled = jax.jit(start_from_data, static_argnames=("names",))
