"""The selection's last steps once a saturation term is in: exponents chosen again, then the backward step."""

from __future__ import annotations

import numpy as np

from .._stats import chi2_sf
from ..diagnose import EFFECTS
from ..fitting import FitOptions, fit_currents
from ..model import Experiment
from ..physics import EXPONENT_CANDIDATES, EXPONENTS, MotorParams
from ..results import Calibration
from ._choices import CANDIDATES, MATERIAL_SATURATION, EffectChoice, fitted_estimate, lr_statistic, saturation_size


#: A candidate whose Wald test (its estimates against their covariance) is significant at this fraction of its
#: level is kept without refitting it out: the likelihood ratio agrees with the Wald test to far better than
#: a factor 1000 in p (Hinkkanen's SyRM: its three terms at z of 150-280; each refit costs a compilation).
_CLEAR = 1e-3


def _wald_p(cal: Calibration, off: dict[str, float]) -> float:
    """The Wald test's p-value of fitted parameters against the values in ``off`` (1.0 if not all are fitted)."""
    if not set(off) <= set(cal.fit_names):
        return 1.0
    index = [cal.fit_names.index(n) for n in off]
    delta = np.array([float(getattr(cal.motor, n)) - float(v) for n, v in off.items()])
    cov = np.asarray(cal.covariance, dtype=float)[np.ix_(index, index)]
    try:
        statistic = float(delta @ np.linalg.solve(cov, delta))
    except np.linalg.LinAlgError:
        return 1.0
    return float(chi2_sf(statistic, len(off))) if np.isfinite(statistic) else 1.0


def drop_effects(experiment: Experiment, currents: np.ndarray, prior: MotorParams, cal: Calibration,
                 decided: dict, options: FitOptions, source: str) -> tuple[Calibration, int, list[str]]:
    """The backward step once a saturation term is in: whatever the final model explains otherwise is dropped.

    The forward search adds the candidate of largest evidence first, so either kind may stand in for the
    other while it is missing: offsets or a delay for the iron of a reluctance motor, or, on a linear motor
    behind a switching inverter, a saturation term for the dead time (it shrinks to 0.08 % of the flux once
    the dead time is in: 1 us at 10 kHz). So each selected candidate, bench effect or saturation term, is
    refitted out of the final model, and

    - a saturation term that now changes the flux by less than ``MATERIAL_SATURATION`` is dropped (the
      smallest first);
    - else the candidate whose likelihood ratio is least significant is dropped if it is no longer
      significant at the level it was added at (a saturation term's p-value Bonferroni-corrected for its
      exponent candidates, as when it was added);

    and the step repeats. A candidate far beyond its level by the Wald test (``_CLEAR``) is kept without a
    refit. Returns ``(calibration, refits, dropped candidates)``.
    """
    fits, dropped = 0, []
    while True:
        trials = []
        for e, c in decided.items():
            if not (c.included and c.how == "selected"):
                continue
            params = CANDIDATES[e][0]
            magnetic = e not in EFFECTS
            off = {n: 0.0 if magnetic else getattr(prior, n) for n in params}
            start = cal.motor.replace(**off)
            centre = prior.replace(**{n: getattr(cal.motor, n) for n in EXPONENTS + ("i_ref",)}, **off)
            size = saturation_size(cal.motor, params[0], currents) if magnetic else 1.0
            choices = len(EXPONENT_CANDIDATES[params[0]][1]) if magnetic else 1
            if size >= MATERIAL_SATURATION and _wald_p(cal, off) * choices < _CLEAR * c.p_threshold:
                continue  # far beyond its level: a refit could not drop it
            reduced = fit_currents(experiment, currents, centre, names=tuple(n for n in cal.names if n not in params),
                                   initial=start, options=options, source=source)
            fits += 1
            removed = len(cal.fit_names) - len(reduced.fit_names)
            if bool(reduced.converged) and removed > 0:
                statistic = max(0.0, lr_statistic(reduced, cal))
                p = float(min(1.0, choices * chi2_sf(statistic, removed)))
                trials.append((size, p, e, statistic, removed, reduced))
        small = [t for t in trials if t[0] < MATERIAL_SATURATION]
        if small:
            size, p, e, statistic, removed, reduced = min(small, key=lambda t: t[0])
            how, note = "too small", (f"{CANDIDATES[e][2]}: dropped, {100 * size:.2g} % of the flux at the tested "
                                      f"currents once the rest is modelled, below the {100 * MATERIAL_SATURATION:g} % "
                                      "that is modelled")
        elif trials:
            size, p, e, statistic, removed, reduced = max(trials, key=lambda t: t[1])
            if not p >= decided[e].p_threshold:
                return cal, fits, dropped
            by = "the saturating law explains" if e in EFFECTS else "the bench effects explain"
            how, note = "not supported", f"{CANDIDATES[e][2]}: dropped, {by} what it stood in for"
        else:
            return cal, fits, dropped
        decided[e] = EffectChoice(e, False, how, "likelihood ratio", statistic, removed, p, decided[e].p_threshold,
                                  fitted_estimate(cal, CANDIDATES[e][0]), note)
        cal = reduced
        dropped.append(e)


def refine_exponents(experiment: Experiment, currents: np.ndarray, prior: MotorParams, cal: Calibration,
                      terms: list[str], options: FitOptions, source: str) -> tuple[Calibration, int]:
    """Each added magnetic term's exponents chosen again with the whole law fitted: the candidate of least RSS.

    A term's exponents were chosen by its score test against the fit it was added to; with the other
    terms in, another candidate may fit better. One pass, term by term, each candidate refitted from the
    current estimates (the same parameters, so the compiled fit is reused).
    """
    fits = 0
    for effect in terms:
        names, values = EXPONENT_CANDIDATES[CANDIDATES[effect][1][0]]
        for candidate in values:
            if all(float(getattr(cal.motor, n)) == v for n, v in zip(names, candidate)):
                continue
            changes = dict(zip(names, candidate))
            centre = prior.replace(**{**{n: getattr(cal.motor, n) for n in EXPONENTS + ("i_ref",)}, **changes})
            trial = fit_currents(experiment, currents, centre, names=cal.names,
                                 initial=cal.motor.replace(**changes), options=options, source=source,
                                 identifiability=cal.identifiability)
            fits += 1
            if bool(trial.converged) and float(trial.rss) < float(cal.rss):
                cal = trial
    return cal, fits
