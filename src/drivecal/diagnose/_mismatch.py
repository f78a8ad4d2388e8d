"""Which unmodelled bench effect do the residuals point to? Score tests.

After a fit, each bench effect the model left out (inverter dead time, current
sensor offsets, a PWM delay other than the one assumed) is tested with a Lagrange
multiplier (score) test: does the effect's signature — its sensitivity column
``d(predicted currents)/d(effect)`` at the fitted motor, made orthogonal to
the fitted parameters' columns — explain more of the residuals than noise
would? Under a correct model the statistic

    S = || P r ||^2 / sigma_hat^2,   P the projection onto that signature,

is chi-squared with as many degrees of freedom as the effect has parameters
(two-sided: an effect larger or smaller than modelled raises it alike; for the
delay the residual's sign along the signature says which, and the advice is
"raise" or "lower" accordingly).
An effect whose p-value falls below ``ALPHA`` (Bonferroni over the effects
tested) is named in the verdict with the fix: add it to ``estimate``.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._stats import chi2_sf
from ..model import Experiment, model_experiment, predicted_currents
from ..identify import sensitivity_jacobian
from ..physics import MotorParams

#: Family-wise false-alarm rate of the effect tests of one fit.
ALPHA = 1e-3

#: Effects tested when not in the model: name -> (parameters, plain-language signature).
EFFECTS: dict[str, tuple[tuple[str, ...], str]] = {
    "dead time": (("v_dead",), "inverter dead time (a voltage error against the current's sign)"),
    "sensor offsets": (("offset_d", "offset_q"), "current-sensor offsets (a constant shift of i_d, i_q)"),
}


def _orthogonal_part(columns: np.ndarray, basis: np.ndarray) -> np.ndarray:
    if basis.shape[1] == 0:
        return columns
    coef, *_ = np.linalg.lstsq(basis, columns, rcond=None)
    return columns - basis @ coef


def _score(residual: np.ndarray, signature: np.ndarray, fitted: np.ndarray,
           sigma_hat: float) -> tuple[float, int, float]:
    """Score statistic of ``signature`` (m, k) columns against the residual, its degrees of freedom, and the
    sign of the residual along the first column's part the fit cannot absorb (+1: the effect is larger than
    modelled, -1: smaller; the statistic itself is two-sided)."""
    e = _orthogonal_part(signature, fitted)
    u, s, _ = np.linalg.svd(e, full_matrices=False)
    keep = s > 1e-10 * max(float(s.max(initial=0.0)), 1e-300)
    if not keep.any():
        return float("nan"), 0, 0.0
    proj = u[:, keep].T @ residual
    return float(proj @ proj / sigma_hat**2), int(keep.sum()), float(np.sign(e[:, 0] @ residual))


def unmodelled_effects(
    motor: MotorParams,
    fit_names: tuple[str, ...],
    experiment: Experiment,
    currents: np.ndarray,
    sigma_hat: float,
    delay_samples: int,
    delayed_experiment: Experiment | None = None,
    predicted: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Score tests of the bench effects missing from a fit.

    Args:
        motor: the fitted motor (estimates in place).
        fit_names: the parameters the fit estimated.
        experiment: the experiment the fit used.
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2).
        sigma_hat: residual standard deviation of the fit (A).
        delay_samples: the delay the fit assumed (samples).
        delayed_experiment: the same run with one more sample of delay
            (``experiment.with_extra_delay(1)``), to test the delay; None
            skips that test.
        predicted: the fit's predicted ``[i_d, i_q]`` (A), shape (M, 2), when
            already computed (the report has them); else computed here.

    Returns:
        Per tested effect: ``effect``, ``parameters``, ``statistic``, ``dof``,
        ``p_value``, ``suspected`` and a ``message``.
    """
    base = model_experiment(experiment, motor, fit_names)
    y = np.asarray(currents, dtype=float).reshape(-1)
    if predicted is None:
        predicted = predicted_currents(motor, base)
    predicted = np.asarray(predicted, dtype=float).reshape(-1)
    residual = y - predicted

    candidates = {k: v for k, v in EFFECTS.items() if not set(v[0]) & set(fit_names)}
    probe_names = tuple(n for params, _ in candidates.values() for n in params)
    all_names = tuple(fit_names) + probe_names
    # Sensitivity columns at v_dead = 0 need no sub-steps (they resolve the sign's turn at v_dead != 0).
    probe = dataclasses.replace(model_experiment(base, motor, all_names), dead_time_substeps=1)

    jac = np.asarray(sensitivity_jacobian(motor, probe, all_names))
    fitted = jac[:, : len(fit_names)]
    tests: list[tuple[str, tuple[str, ...], str, np.ndarray]] = []
    for effect, (params, what) in candidates.items():
        idx = [all_names.index(n) for n in params]
        tests.append((effect, params, what, jac[:, idx]))
    if delayed_experiment is not None:
        later = model_experiment(delayed_experiment, motor, fit_names)
        column = (predicted_currents(motor, later).reshape(-1) - predicted)[:, None]
        tests.append(("delay", ("delay_samples",), f"a PWM/computation delay other than the {delay_samples} "
                      "sample(s) assumed", column))

    out = []
    threshold = ALPHA / max(len(tests), 1)
    for effect, params, what, signature in tests:
        statistic, dof, direction = _score(residual, signature, fitted, sigma_hat)
        p = float(chi2_sf(statistic, dof)) if dof else float("nan")
        suspected = bool(dof and p < threshold)
        fix = "add " + ", ".join(params) + " to 'estimate' (motor file) or --estimate"
        if effect == "delay":
            # Two-sided: the residual along the extra-delay signature says which way the delay is off.
            more = direction >= 0 or delay_samples == 0
            what = (f"{'more' if more else 'less'} PWM/computation delay than the {delay_samples} sample(s) "
                    "assumed")
            fix = f"{'raise' if more else 'lower'} 'delay_samples' (motor file) or --delay"
        out.append({
            "effect": effect,
            "parameters": list(params),
            "statistic": statistic,
            "dof": dof,
            "p_value": p,
            "p_threshold": threshold,
            "suspected": suspected,
            "message": f"the residuals carry the signature of {what} (score test p = {p:.2g}); {fix}"
            if suspected else f"no sign of {what} (score test p = {p:.2g})",
        })
    return out
