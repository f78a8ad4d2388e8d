"""A PM-assisted motor's iron bridge, tried where drivecal's law about the magnet cannot follow the iron.

The forward search (``_select``) tries the self- and cross-saturation terms about the magnet's flux
(``physics.MAGNETIC``). The iron bridges around a PM-assisted motor's magnets saturate asymmetrically in
i_d (Lelli, Hinkkanen and Giulii Capponi, ICEM 2024, doi 10.1109/ICEM60801.2024.10700403): on such a motor
the score tests find saturation and no fit of that law converges. There, with ``--magnetics auto`` or
``saturating`` and a magnet (``lambda_m > 0``), the selection tries the law with the bridge
(``physics.BRIDGE``, with the self- and cross-saturation terms about zero flux as published:
``sat_at_zero = 1``):

1. **Its shape, from the flux linkages.** On the locked steps (each from rest) the flux linkages follow
   from the voltages: ``psi(t) = (lambda_m, 0) + integral(v - R i) dt``, linear in R and lambda_m. The
   law's currents at those fluxes are fitted to the measured currents, all eleven coefficients at once
   (:func:`flux_law_fit`: a static regression, no rollout), from one start (:data:`SHAPE_START`, per
   unit at the data's largest current) per exponent candidate of :data:`EXPONENT_GRID` (Hinkkanen's S,
   T, U, V). One compilation serves them all: the exponents are values, not the program's shape.
2. **Everything, from the shapes.** From the :data:`FINALISTS` static fits of least RSS, every parameter
   the user asked for and the seven of the law are fitted on the whole bench (the flux-state rollout:
   the delay, the free segments and the bench effects as the model has them).
3. **The data choose.** The converged fit of least RSS is kept, its exponents with it.

A fit straight from a generic start does not find the bridge: its shape parameters trade off against
lambda_m and R along the rollout's long valleys (on Lelli's PM-SyRM, six exponent sets from one start
all stopped unconverged, the best at 1.4 times the noise). The static regression has no dynamics to
get lost in.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np

from ..diagnose import BRIDGE_EFFECTS, MAGNETIC_EFFECTS
from ..fitting import FitOptions, fit_currents
from ..model import Experiment
from ..physics import (BRIDGE, ESTIMATED, EXPONENTS, MAGNETIC, MotorParams, currents_of_flux, from_search,
                       has_bridge)
from ..results import Calibration
from ._choices import CANDIDATES, EffectChoice, fitted_estimate, names_with

#: The effect's name in the selection's choices.
BRIDGE_EFFECT = next(iter(BRIDGE_EFFECTS))

#: The start of the law's shape, per unit at the data's largest current (``i_ref``): every term saturating
#: the flux by a tenth to a third there, a bridge of Lelli's form (``k_q`` the q flux's weight in it, its
#: own saturation ``sat_bp`` moderate), ``psi_n`` (the magnet flux the bridge carries) above lambda_m.
SHAPE_START: dict[str, float] = {"sat_d": 0.1, "sat_q": 1.0, "sat_dq": 0.3, "sat_b": 0.3, "sat_bp": 0.2, "k_q": 0.1}
#: ``psi_n``'s start: this many times the nominal lambda_m (Wb/Wb).
PSI_N_START = 1.7
#: Hinkkanen's exponents (S, T, U, V) tried for the shape: the self terms' orders, cross terms linear or
#: absent (the published PM-SyRM's are (4, 6, 1, 1)).
EXPONENT_GRID: tuple[tuple[float, float, float, float], ...] = tuple(
    (s, t, u, u) for s in (2.0, 4.0, 6.0) for t in (2.0, 4.0, 6.0) for u in (1.0, 0.0))
#: How many of the best shapes are refitted with everything.
FINALISTS = 3


def bridge_wanted(prior: MotorParams, cal: Calibration, last: dict[str, dict[str, Any]], magnetics: str,
                  names: tuple[str, ...]) -> bool:
    """Whether the selection tries the bridge: saturation is a candidate (``magnetics`` not ``linear``), the
    motor has a magnet, the law without the bridge did not converge although a score test found saturation,
    and the user neither stated a bridge nor named one of its parameters."""
    flagged = any(t["suspected"] for e, t in last.items() if e in MAGNETIC_EFFECTS)
    return (magnetics != "linear" and float(prior.lambda_m) > 0.0 and not bool(cal.converged) and flagged
            and not has_bridge(prior) and not float(prior.sat_at_zero) and not set(BRIDGE) & set(names))


def fit_bridge(experiment: Experiment, currents: np.ndarray, prior: MotorParams, names: tuple[str, ...],
               options: FitOptions, source: str) -> tuple[Calibration | None, int, str]:
    """The law with the iron bridge fitted in the three steps of the module docstring.

    Args:
        experiment: the experiment.
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2).
        prior: the nominal motor, ``i_ref`` at the data's largest current (A).
        names: the parameters the user asked for (the law's are added).
        options: solver settings.
        source: label of the data.

    Returns:
        ``(calibration or None, fits run, why none)``: the kept fit, or None with the reason in words.
    """
    every = names_with(names, MAGNETIC + BRIDGE)
    static = tuple(n for n in ESTIMATED + MAGNETIC + BRIDGE if n in every)
    start = prior.replace(sat_at_zero=1.0, psi_n=PSI_N_START * float(prior.lambda_m), **SHAPE_START)
    shapes = []
    for exponents in EXPONENT_GRID:
        found = flux_law_fit(experiment, currents, start.replace(**dict(zip(EXPONENTS, exponents))), static)
        if found is not None:
            shapes.append(found)
    if not shapes:
        return None, 0, "the bench has no locked step from rest to read the law's shape from, or none could be fitted"
    best, fits = None, 0
    for shaped, _ in sorted(shapes, key=lambda s: s[1])[:FINALISTS]:
        cal = fit_currents(experiment, currents, shaped, names=every, initial=shaped, options=options, source=source)
        fits += 1
        if bool(cal.converged) and "sat_b" in cal.fit_names and (best is None or float(cal.rss) < float(best.rss)):
            best = cal
    if best is None:
        return None, fits, "no fit of the whole bridged law converged from its best shapes"
    # Reported against the user's nominal values (the prior column), not the static fit it started from; the
    # settings and anything held stay the fit's own, so the fitted motor is the same.
    return dataclasses.replace(best, prior=best.prior.replace(**{n: getattr(prior, n) for n in best.fit_names})), \
        fits, ""


def locked_flux_data(experiment: Experiment, currents: np.ndarray, points: int = 4000):
    """The locked steps' samples for :func:`flux_law_fit`: ``(volt_seconds, amp_seconds, start, measured)``.

    Each (N, 2), N at most about ``points`` (every k-th sample): per sample of a locked segment that starts from
    rest (not continuing another), the integral of the applied voltage since the segment's start (V*s), that of
    the measured current (A*s, trapezoids), the current at the segment's start (A) and the current measured
    there (A). None where the experiment has no such segment.
    """
    if experiment.segments is None:
        return None
    v = np.asarray(experiment.voltages, dtype=float)
    i = np.asarray(currents, dtype=float)
    h = float(np.asarray(experiment.sample_period).reshape(-1)[0])
    parts = []
    for k, (a, b, kind) in enumerate(experiment.segments):
        if kind != "locked" or k in experiment.carried or b - a < 3:
            continue
        volt = np.concatenate([np.zeros((1, 2)), np.cumsum(h * v[a:b - 1], axis=0)])
        amp = np.concatenate([np.zeros((1, 2)), np.cumsum(0.5 * h * (i[a:b - 1] + i[a + 1:b]), axis=0)])
        parts.append((volt, amp, np.broadcast_to(i[a], (b - a, 2)), i[a:b]))
    if not parts:
        return None
    stacked = [np.concatenate([p[j] for p in parts]) for j in range(4)]
    every = max(1, len(stacked[0]) // points)
    return tuple(np.ascontiguousarray(x[::every]) for x in stacked)


@functools.lru_cache(maxsize=4)
def _flux_law_kernels(names: tuple[str, ...]):
    """The static regression's residual and Jacobian in search coordinates (compiled once per ``names``)."""
    import jax
    import jax.numpy as jnp

    def residual(z, motor, volt, amp, start, measured):
        theta, _ = from_search(motor, names, z)
        m = motor.with_vector(names, theta)
        psi_d = m.lambda_m + m.Ld * start[:, 0] + volt[:, 0] - m.R * amp[:, 0]
        psi_q = m.Lq * start[:, 1] + volt[:, 1] - m.R * amp[:, 1]
        i_d, i_q = currents_of_flux(psi_d, psi_q, m)
        return jnp.concatenate([i_d - measured[:, 0], i_q - measured[:, 1]])

    return jax.jit(residual), jax.jit(jax.jacfwd(residual))


def flux_law_fit(experiment: Experiment, currents: np.ndarray, motor: MotorParams,
                 names: tuple[str, ...]) -> tuple[MotorParams, float] | None:
    """``names`` fitted by the static regression of step 1 (module docstring) from ``motor``: ``(motor, RSS)``
    (RSS in A^2 over the samples used), or None where the bench has no locked step from rest or the search
    fails. ``names`` among R, Ld, Lq, lambda_m and the law's coefficients; the rest held at ``motor``'s.
    """
    from scipy.optimize import least_squares

    data = locked_flux_data(experiment, currents)
    if data is None:
        return None
    residual, jacobian = _flux_law_kernels(tuple(names))
    z0 = np.zeros(len(names))
    try:
        with np.errstate(all="ignore"):
            sol = least_squares(lambda z: np.asarray(residual(z, motor, *data)),
                                z0, jac=lambda z: np.asarray(jacobian(z, motor, *data)), method="lm", max_nfev=400)
    except (ValueError, FloatingPointError):
        return None
    if not (sol.success and np.all(np.isfinite(sol.x)) and np.isfinite(sol.cost)):
        return None
    theta, _ = from_search(motor, tuple(names), sol.x, xp=np)
    return motor.replace(**{n: float(t) for n, t in zip(names, theta)}), float(2.0 * sol.cost)


def bridge_choices(cal: Calibration | None, why: str, requested: tuple[str, ...]) -> dict[str, EffectChoice]:
    """The selection's decisions once the bridge was tried: with the bridged law kept, every magnetic term
    not requested is fitted within it, and the bridge is; else the bridge is recorded as not supported."""
    if cal is None:
        return {BRIDGE_EFFECT: EffectChoice(BRIDGE_EFFECT, False, "not supported",
                                            note=f"{BRIDGE_EFFECTS[BRIDGE_EFFECT][2]}: tried where the law about the "
                                                 f"magnet did not converge; {why}")}
    out = {e: EffectChoice(e, True, "selected", estimate=fitted_estimate(cal, CANDIDATES[e][0]),
                           note=f"{CANDIDATES[e][2]}: fitted in the law with the iron bridge (the law without it "
                                "did not converge)")
           for e in MAGNETIC_EFFECTS if e not in requested and set(CANDIDATES[e][0]) <= set(cal.fit_names)}
    exponents = ", ".join(f"{n} = {float(getattr(cal.motor, n)):g}" for n in EXPONENTS)
    out[BRIDGE_EFFECT] = EffectChoice(
        BRIDGE_EFFECT, True, "selected", estimate=fitted_estimate(cal, BRIDGE),
        note=f"{BRIDGE_EFFECTS[BRIDGE_EFFECT][2]}: fitted, the law without it did not converge (Lelli et al.'s law, "
             f"terms about zero flux; exponents {exponents}, the least RSS of {len(EXPONENT_GRID)} candidates)")
    return out

