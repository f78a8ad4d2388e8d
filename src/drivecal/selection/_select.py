"""Which bench effects the data support: forward selection by nested likelihood-ratio tests.

The procedure (``--effects auto``, the default of ``drivecal fit``):

1. Fit the motor's parameters alone (the user's ``estimate``), the delay held
   at its nominal value.
2. Score-test every candidate effect not yet in the model
   (``diagnose.unmodelled_effects``: delay, dead time, sensor offsets). If
   none is significant at ``ALPHA`` (Bonferroni over the candidates), stop.
3. Add the most significant one (the largest evidence first), starting its
   parameters at their one-step estimates, and refit everything.
4. Keep it if the likelihood-ratio statistic ``m ln(RSS_without / RSS_with)``
   (chi-squared with as many degrees of freedom as parameters added, m the
   number of current samples) is significant at the same level; else drop
   it as a candidate. Go to 2.

So an effect that only looked significant because a larger one was missing
(dead time mimicking a delay, offsets mimicking dead time) is tested again
after the larger one is modelled, and is neither fitted nor advised when it
no longer shows. Effects not included are reported with their last score
test and their one-step estimate (what the data say they would be, with a
standard error), so the delay is reported with an interval either way.

With ``--magnetics auto`` (the default) the terms of the saturating law are
candidates too, in the same order of evidence. Once a saturation term is in,
its exponents are chosen again and a backward step (``_backward``) refits
each selected candidate out: a saturation term the bench effects explain
(below ``MATERIAL_SATURATION`` of the flux, or no longer significant) is
dropped, and so is a bench effect the saturating law explains.

On a motor with a magnet whose law about the magnet's flux does not converge although a score test
found saturation, the iron bridges of a PM-assisted motor are tried last (``_bridge``: the law's shape
read from the locked steps' flux linkages, then everything refitted; the least RSS kept), and the bench
effects are then chosen against that law.

The same machinery serves any family of nested model extensions: a
candidate is a name, the parameters it adds and the parameters whose
sensitivity columns its score test probes (``diagnose.EFFECTS``).
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import nullcontext
from typing import Any, Callable

import numpy as np

from .._stats import chi2_sf
from ..diagnose import (ALPHA, EFFECTS, MAGNETIC_EFFECTS, prepare_unmodelled_effects, unmodelled_effects,
                        untested_effects)
from ..errors import DrivecalError
from ..fitting import FitOptions, fit_currents
from ..identify import assess_identifiability
from ..model import Experiment, compiled_ahead
from ..physics import EXPONENT_CANDIDATES, EXPONENTS, MotorParams, is_saturating
from ..results import Calibration
from ._backward import drop_effects, refine_exponents
from ._bridge import BRIDGE_EFFECT, bridge_choices, bridge_wanted, fit_bridge
from ._choices import (CANDIDATES, MATERIAL_SATURATION, EffectChoice, choice_note, fitted_estimate, lr_statistic,
                       names_with, one_step, saturation_size)

#: Values of ``--effects`` besides a list of effect names.
MODES: tuple[str, ...] = ("auto", "none")
#: Values of ``--magnetics``: the data choose; the linear machine only; the saturating law always.
MAGNETICS: tuple[str, ...] = ("auto", "linear", "saturating")

#: A one-step delay estimate further than this (samples) from the fitted one is not a start: use the nominal.
_DELAY_START_SPAN = 10.0


def parse_effects(text: str, source: str = "--effects") -> str | tuple[str, ...]:
    """``"auto"``, ``"none"`` or a tuple of effect names from a comma-separated list (e.g. ``delay,dead_time``).

    Raises:
        DrivecalError: naming ``source``, an unknown name and the choices.
    """
    words = tuple(w.strip().replace("-", "_").replace(" ", "_") for w in str(text).split(",") if w.strip())
    if len(words) == 1 and words[0] in MODES:
        return words[0]
    unknown = [w for w in words if w not in EFFECTS]
    if unknown or not words:
        raise DrivecalError(f"{source}: unknown effect(s) {', '.join(unknown) or '(none given)'}; give auto, none, "
                            f"or a comma-separated list of {', '.join(EFFECTS)}.")
    return tuple(e for e in EFFECTS if e in words)


@dataclasses.dataclass(frozen=True)
class EffectSelection:
    """A fit with its bench effects chosen: the final calibration and the decision on each effect.

    Attributes:
        calibration: the final fit (its names include the included effects' parameters).
        experiment: the experiment it used.
        mode: ``"auto"``, ``"none"`` or ``"list"``.
        choices: one :class:`EffectChoice` per effect of ``diagnose.EFFECTS`` and of
            ``diagnose.MAGNETIC_EFFECTS``, in that order.
        fits: how many fits the selection ran.
        magnetics: the ``--magnetics`` mode (``auto``, ``linear``, ``saturating``).
    """

    calibration: Calibration
    experiment: Experiment
    mode: str
    choices: tuple[EffectChoice, ...]
    fits: int = 1

    @property
    def included(self) -> tuple[str, ...]:
        """The effects the final fit estimates."""
        return tuple(c.effect for c in self.choices if c.included)

    magnetics: str = "linear"

    @property
    def magnetic_model(self) -> str:
        """``"saturating"`` when the final fit includes a term of the saturating law or holds one (a motor file's
        law), else ``"linear"``."""
        fitted = bool(set(self.included) & set(MAGNETIC_EFFECTS))
        return "saturating" if fitted or is_saturating(self.calibration.motor) else "linear"

    def to_dict(self) -> dict[str, Any]:
        """The result JSON's ``effects`` section (the magnetic terms among them: ``magnetics``, ``magnetic_model``)."""
        return {"mode": self.mode, "included": list(self.included), "alpha": ALPHA, "fits": self.fits,
                "magnetics": self.magnetics, "magnetic_model": self.magnetic_model,
                "effects": [c.to_dict() for c in self.choices]}


def _start(motor: MotorParams, test: dict[str, Any]) -> MotorParams:
    """``motor`` with the tested effect's probed parameters at their one-step estimates (where sensible)."""
    changes = {}
    for n, v in test["one_step"].items():
        value = v["estimate"]
        if not math.isfinite(value):
            continue
        if n in ("sat_d", "sat_q", "sat_dq"):
            value = max(value, 0.0)  # a start the law stays monotone from; the fit may still go below
        if n == "delay":
            if abs(value - float(motor.delay)) > _DELAY_START_SPAN:
                continue
            value = max(value, 0.0)
        if n == "v_dead":
            value = abs(value)
        changes[n] = value
    return motor.replace(**changes)


def select_effects(
    experiment: Experiment,
    currents: np.ndarray,
    prior: MotorParams,
    *,
    names: tuple[str, ...],
    effects: str | tuple[str, ...] = "auto",
    options: FitOptions = FitOptions(),
    source: str = "bench",
    fixed_delay: bool = False,
    magnetics: str = "auto",
) -> EffectSelection:
    """Fit ``names`` with the bench effects and the magnetic law the data support (see the module docstring).

    Args:
        experiment: the experiment (the nominal delay ``prior.delay`` applied).
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2).
        prior: the nominal motor; its ``delay`` is the nominal delay (samples).
        names: the parameters the user asks for (an effect's parameters among
            them make that effect requested).
        effects: ``"auto"``, ``"none"``, or the effects to fit whatever the tests say.
        options: solver settings.
        source: label of the data.
        fixed_delay: the delay is given (``--delay``): held at ``prior.delay``, never a candidate.
        magnetics: ``"auto"`` (the terms of the saturating law are candidates like the bench
            effects), ``"linear"`` (never) or ``"saturating"`` (every term the plan can identify is
            fitted, each with the exponents its score test prefers).
    """
    if magnetics not in MAGNETICS:
        raise DrivecalError(f"--magnetics: unknown mode {magnetics!r}; give {', '.join(MAGNETICS)}.")
    requested = tuple(e for e, (params, _, _) in CANDIDATES.items() if set(params) & set(names))
    magnetic = tuple(e for e in MAGNETIC_EFFECTS if e not in requested) if magnetics != "linear" else ()
    if magnetic or set(requested) & set(MAGNETIC_EFFECTS):
        prior = _with_reference_current(prior, currents)
    if effects == "none" or isinstance(effects, tuple):
        listed = () if effects == "none" else effects
        fit_names = names_with(names, tuple(n for e in listed for n in EFFECTS[e][0]))
        cal = fit_currents(experiment, currents, prior, names=fit_names, options=options, source=source)
        fits, decided, last = 1, {}, {}
        if magnetic:
            left_out = tuple(e for e in EFFECTS if e not in listed and e not in requested)
            cal, fits, decided, last = _add_effects(experiment, currents, prior, cal, list(magnetic), options,
                                                    source, force=magnetics == "saturating", left_out=left_out)
            cal, fits = _with_bridge(experiment, currents, prior, cal, fits, decided, last, fit_names, requested,
                                     magnetics, options, source, [])
        choices = []
        for e, (params, _, _) in CANDIDATES.items():
            if e in MAGNETIC_EFFECTS and e not in requested:
                choices.append(_choice(e, cal, decided, last, magnetics))
                continue
            chosen = e in listed or e in requested
            est = fitted_estimate(cal, params)
            how = "requested" if chosen else "not tested"
            choices.append(EffectChoice(e, chosen and bool(est), how, estimate=est, note=choice_note(e, chosen, how)))
        choices += [decided[BRIDGE_EFFECT]] if BRIDGE_EFFECT in decided else []
        return EffectSelection(cal, experiment, "none" if effects == "none" else "list", tuple(choices), fits,
                               magnetics)

    candidates = [e for e in EFFECTS if e not in requested and not (fixed_delay and e == "delay")]
    with compiled_ahead(prepare_unmodelled_effects, prior, names, experiment, tuple(candidates) + magnetic,
                        after_first_trace=True):
        cal = fit_currents(experiment, currents, prior, names=names, options=options, source=source)
    cal, fits, decided, last = _add_effects(experiment, currents, prior, cal, candidates + list(magnetic), options,
                                            source, force=magnetics == "saturating",
                                            left_out=("delay",) if fixed_delay and "delay" not in requested else ())
    bench = [e for e in candidates if e in EFFECTS and e not in decided]
    cal, fits = _with_bridge(experiment, currents, prior, cal, fits, decided, last, names, requested, magnetics,
                             options, source, bench)
    choices = []
    for e, (params, _, _) in CANDIDATES.items():
        if e in requested:
            choices.append(EffectChoice(e, True, "requested", estimate=fitted_estimate(cal, params),
                                        note=choice_note(e, True, "requested")))
        elif fixed_delay and e == "delay":
            choices.append(EffectChoice(e, False, "fixed", estimate={"delay": (float(prior.delay), 0.0)},
                                        note=f"delay fixed at {float(prior.delay):g} samples (--delay)"))
        else:
            choices.append(_choice(e, cal, decided, last, magnetics))
    choices += [decided[BRIDGE_EFFECT]] if BRIDGE_EFFECT in decided else []
    return EffectSelection(cal, experiment, "auto", tuple(choices), 1 + fits, magnetics)


def _with_bridge(experiment: Experiment, currents: np.ndarray, prior: MotorParams, cal: Calibration, fits: int,
                 decided: dict, last: dict, names: tuple[str, ...], requested: tuple[str, ...], magnetics: str,
                 options: FitOptions, source: str, bench: list[str]) -> tuple[Calibration, int]:
    """The law with a PM-assisted motor's iron bridge where the selection's law did not converge (``_bridge``).

    Updates ``decided`` and ``last`` in place; with the bridge kept, the bench effects of ``bench`` are then
    chosen against it as they would have been against the law about the magnet. Returns ``(calibration,
    fits)``."""
    if not bridge_wanted(prior, cal, last, magnetics, names):
        return cal, fits
    bridged, more, why = fit_bridge(experiment, currents, prior, names, options, source)
    decided.update(bridge_choices(bridged, why, requested))
    if bridged is None:
        return cal, fits + more
    cal, added, chosen, tests = _add_effects(experiment, currents, prior.replace(sat_at_zero=1.0), bridged, bench,
                                             options, source)
    decided.update(chosen)
    last.update(tests)
    return cal, fits + more + added


def _with_reference_current(prior: MotorParams, currents: np.ndarray) -> MotorParams:
    """``prior`` with ``i_ref`` at the data's largest current (A, two significant digits) where its law is linear.

    The saturation coefficients are then per unit of what the test reached, of order one where it saturates.
    """
    if is_saturating(prior):
        return prior
    peak = float(np.max(np.abs(np.asarray(currents, dtype=float)), initial=0.0))
    if not math.isfinite(peak) or peak <= 0.0:
        return prior
    return prior.replace(i_ref=float(f"{peak:.2g}"))


def _choice(e: str, cal: Calibration, decided: dict, last: dict, magnetics: str) -> EffectChoice:
    """The final word on effect ``e`` that the user did not name: fitted, rejected, or its last score test."""
    params = CANDIDATES[e][0]
    if e in MAGNETIC_EFFECTS and magnetics == "linear":
        return EffectChoice(e, False, "not tested", note=f"{CANDIDATES[e][2]}: not tested (--magnetics linear)")
    if e in decided and decided[e].included:  # the final fit's estimates, not those when it was added
        return dataclasses.replace(decided[e], estimate=fitted_estimate(cal, params))
    if e in decided and (e not in last or decided[e].how == "masked"):
        return decided[e]
    if e in last:
        t = last[e]
        how = decided[e].how if e in decided else "not supported"
        if how == "not identifiable" and not t["suspected"]:
            how = "not supported"
        return EffectChoice(e, False, how, "score", t["statistic"], t["dof"], t["p_value"], t["p_threshold"],
                            one_step(t), choice_note(e, False, how))
    return EffectChoice(e, False, "not tested", note=choice_note(e, False, "not tested"))


def _add_effects(experiment: Experiment, currents: np.ndarray, prior: MotorParams, cal: Calibration,
                 candidates: list[str], options: FitOptions, source: str, force: bool = False,
                 left_out: tuple[str, ...] = ()) -> tuple:
    """Forward selection from ``cal`` over ``candidates`` (steps 2 to 4 of the module docstring).

    With ``force`` the magnetic candidates are added whatever their tests say (``--magnetics
    saturating``), where the plan can identify them. ``left_out`` are bench effects the fit does not
    model (``--effects none`` or a list, a delay fixed by ``--delay``): they are score-tested beside
    the candidates, and where one of them has the largest evidence, no saturation term is added for
    what it does (the verdict names it). Returns ``(calibration, refits, decided, last)``:
    the final fit, how many fits were run, an :class:`EffectChoice` per effect decided on, and each
    remaining candidate's last score test.
    """
    candidates = list(candidates)
    decided: dict[str, EffectChoice] = {}
    last: dict[str, dict[str, Any]] = {}
    fits = 0
    # Where saturation is a candidate, a base fit that did not converge (a saturating machine fitted as
    # linear) still shows in its residuals what is missing: the search goes on from it until a term is in.
    saturation = bool(set(candidates) & set(MAGNETIC_EFFECTS))
    tested_last: tuple = (None, (), [])  # the fit, the effects and the tests of the loop's latest score tests
    while candidates and (bool(cal.converged) or (saturation and not any(c.included for c in decided.values()))):
        tested = tuple(candidates)
        if not bool(cal.converged) and set(candidates) & set(MAGNETIC_EFFECTS):
            # A base fit that could not converge is far from the data: the iron's saturation, not a small
            # bench effect, is what stops a linear model converging on a plan that identifies it.
            tested = tuple(e for e in candidates if e in MAGNETIC_EFFECTS)
        blockers = left_out if bool(cal.converged) and not force else ()
        tests = unmodelled_effects(cal.motor, cal.fit_names, experiment, currents, float(cal.sigma_hat),
                                   effects=tested + blockers)
        tested_last = (cal, tested + blockers, tests)
        last.update({t["effect"]: t for t in tests if t["effect"] not in blockers})
        if tests[0]["suspected"] and tests[0]["effect"] in blockers:
            # What the fit leaves out explains more than any saturation term would: none stands in for it.
            for e in [c for c in candidates if c in MAGNETIC_EFFECTS]:
                t = last[e]
                decided[e] = EffectChoice(e, False, "masked", "score", t["statistic"], t["dof"], t["p_value"],
                                          t["p_threshold"], one_step(t),
                                          f"{CANDIDATES[e][2]}: not fitted, the residuals point first at "
                                          f"{CANDIDATES[tests[0]['effect']][2]}, which this fit does not model")
                candidates.remove(e)
            tests = [t for t in tests if t["effect"] in candidates]
            if not tests:
                break
        forced = [t for t in tests if force and t["effect"] in MAGNETIC_EFFECTS]
        # The largest evidence first, the iron's law and the bench's effects alike: whichever was added for
        # what the other explains is refitted out by the backward step (``drop_effects``).
        best = tests[0] if tests[0]["suspected"] or not forced else forced[0]
        if not best["suspected"] and not forced:
            break
        effect = best["effect"]
        candidates.remove(effect)
        start = _start(cal.motor, best)
        if not bool(cal.converged):  # no estimates to start from: the nominal motor, the test's exponents
            start = prior.replace(**{n: v["estimate"] for n, v in best["one_step"].items() if n in EXPONENTS})
        trial = names_with(cal.fit_names, CANDIDATES[effect][0])
        try:
            # Judged at the fit so far with the effect at its one-step estimate: the dead time's width
            # shows only where v_dead is not zero.
            ident = assess_identifiability(experiment, start, names=trial)
        except DrivecalError:
            ident = None
        probes = CANDIDATES[effect][1]
        if ident is None or not set(probes) <= set(ident.fit_names):
            decided[effect] = EffectChoice(effect, False, "not identifiable", "score", best["statistic"],
                                           best["dof"], best["p_value"], best["p_threshold"], one_step(best),
                                           choice_note(effect, False, "not identifiable", ident))
            continue
        trial = tuple(n for n in trial if n in ident.fit_names or n in cal.fit_names)
        if trial != ident.names:
            ident = assess_identifiability(experiment, start, names=trial)
        # The prior stays the nominal motor (the search's centre and the value of what is not fitted);
        # a magnetic term's exponents are the ones its test chose.
        centre = prior.replace(**{n: getattr(start, n) for n in EXPONENTS + ("i_ref",)})
        # The next round's score tests (the model with this effect in) compile beside the refit, as the first
        # round's beside the base fit: a bench effect's refit has the structure of the model that keeps it
        # (examples/inverter_bench.csv, cold, A/B medians of 3: with the fitted columns the fit's own, 16.2 ->
        # 13.5 s, against 15.8 -> 13.9 s for that change alone).
        # After the last bench effect, the verdict's test of what no candidate covers (an encoder offset) too.
        # The refit traces nothing of its own (its kernel is the identifiability check's, compiled above), so
        # the work does not wait for a first trace: it compiles while the refit solves, not after it
        # (inverter bench, cold, A/B medians of 3: 30.2 -> 29.3 s on a slower machine; output the same).
        ahead = None
        if effect in EFFECTS:
            verdict = () if set(candidates) & set(EFFECTS) else tuple(
                e for e in untested_effects(trial, experiment) if e not in CANDIDATES)
            ahead = (start, trial, experiment, tuple(candidates) + blockers + verdict)
        with compiled_ahead(prepare_unmodelled_effects, *ahead, after_first_trace=False) if ahead else nullcontext():
            refit = fit_currents(experiment, currents, centre, names=trial, initial=start, options=options,
                                 source=source, identifiability=ident)
        fits += 1
        added = len(refit.fit_names) - len(cal.fit_names)
        statistic = lr_statistic(cal, refit) if bool(refit.converged) and added > 0 else math.nan
        choices = len(EXPONENT_CANDIDATES["sat_d"][1]) if effect in MAGNETIC_EFFECTS else 1
        p = float(min(1.0, choices * chi2_sf(statistic, added))) if math.isfinite(statistic) else math.nan
        threshold = best["p_threshold"]
        forced_in = force and effect in MAGNETIC_EFFECTS and bool(refit.converged)
        size = saturation_size(refit.motor, CANDIDATES[effect][1][0], currents) if effect in MAGNETIC_EFFECTS else 1.0
        if math.isfinite(p) and p < threshold and size < MATERIAL_SATURATION and not forced_in:
            decided[effect] = EffectChoice(effect, False, "too small", "likelihood ratio", statistic, added, p,
                                           threshold, fitted_estimate(refit, CANDIDATES[effect][0]),
                                           f"{CANDIDATES[effect][2]}: {100 * size:.2g} % of the flux at the tested "
                                           f"currents, below the {100 * MATERIAL_SATURATION:g} % that is modelled")
            continue
        if (math.isfinite(p) and p < threshold) or forced_in:
            how = "selected" if math.isfinite(p) and p < threshold else "requested"
            decided[effect] = EffectChoice(effect, True, how, "likelihood ratio", statistic, added, p,
                                           threshold, fitted_estimate(refit, CANDIDATES[effect][0]),
                                           choice_note(effect, True, how))
            cal = refit
            # Earlier decisions stand; what is left is tested again against the larger model.
        else:
            decided[effect] = EffectChoice(effect, False, "not supported", "likelihood ratio", statistic, added, p,
                                           threshold, one_step(best), choice_note(effect, False, "not supported"))
    added_terms = [e for e, c in decided.items() if c.included and e in MAGNETIC_EFFECTS]
    if added_terms and bool(cal.converged):
        cal, more = refine_exponents(experiment, currents, prior, cal, added_terms, options, source)
        fits += more
        cal, more, dropped = drop_effects(experiment, currents, prior, cal, decided, options, source)
        fits += more
        candidates += dropped
    # The final word on what was not added, and on what the plan could not show: the score tests against the
    # final fit (a term suggested only while a larger effect was missing is then no longer suggested).
    candidates += [e for e, c in decided.items() if c.how == "not identifiable" and e not in candidates]
    if candidates and bool(cal.converged):
        if tested_last[0] is cal and tested_last[1] == tuple(candidates):  # the loop's last tests: nothing changed
            final = tested_last[2]
        else:
            final = unmodelled_effects(cal.motor, cal.fit_names, experiment, currents, float(cal.sigma_hat),
                                       effects=tuple(candidates))
        for t in final:
            last[t["effect"]] = t
    return cal, fits, decided, last
