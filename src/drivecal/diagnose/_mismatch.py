"""Which unmodelled bench effect do the residuals point to? Score tests.

After a fit, each bench effect the model left out (a PWM/computation delay
other than the one assumed, inverter dead time, current-sensor offsets, and
on a phase file with its rotor angle an encoder offset) is tested with a
Lagrange multiplier (score) test: does the effect's signature —
its sensitivity columns ``d(predicted currents)/d(effect's parameters)`` at
the fitted motor, made orthogonal to the fitted parameters' columns — explain
more of the residuals than noise would? Under a correct model the statistic

    S = || P r ||^2 / sigma_hat^2,   P the projection onto that signature,

is chi-squared with as many degrees of freedom as the effect has parameters.
It is two-sided: an effect larger or smaller than modelled raises it alike,
and for the delay the residual's sign along the signature says which
("raise" or "lower"). A delay below zero cannot be: at a nominal delay of 0
only "more" is a finding.

The same projection gives the effect's one-step (Gauss-Newton) estimate from
the fit, ``theta_0 + (E^T E)^-1 E^T r`` with ``E`` the orthogonalised columns,
and its standard error ``sigma_hat * sqrt(diag((E^T E)^-1))``: what the effect
would be if it were fitted, without refitting. ``drivecal.selection`` uses the
tests to choose which effects to fit; what is left after that is advised.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable

import jax
import numpy as np
from jax._src import util as jax_util  # register_cache: jax.clear_caches() clears _PREPARED

from .._stats import chi2_sf
from ..model import (Experiment, ahead_of_need, model_experiment, outputs_unused, predicted_currents,
                     side_by_side, start_saturation_columns, with_experiment_delay)
from ..identify import sensitivity_jacobian
from ..physics import BRIDGE, EXPONENT_CANDIDATES, MAGNETIC, MotorParams, is_saturating, parameter_values

#: Family-wise false-alarm rate of the effect tests of one fit.
ALPHA = 1e-3

#: Bench effects: name -> (parameters a fit adds, parameters the score test probes, plain-language signature).
#: The dead time adds v_dead only: its transition is the PWM ripple the model computes, and the smooth sign's
#: width i_dead is held at the motor's (10 mA by default). Fitted, the width falls toward zero (the data want
#: the sharp edge of the ripple's dead zone) and 22 % of 32 noise seeds on the switching plant stop at the
#: step limit; held at 10 mA, every seed converges in 7-16 steps with z spreads of 0.87-1.01.
EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "delay": (("delay",), ("delay",), "a PWM/computation delay other than the one assumed"),
    "dead_time": (("v_dead",), ("v_dead",),
                  "inverter dead time (a voltage error against each phase current's sign)"),
    "offsets": (("offset_d", "offset_q"), ("offset_d", "offset_q"),
                       "current-sensor offsets (a constant shift of i_d, i_q)"),
}

#: Effects tested only where they apply, in the same form: an encoder offset, on a file with a measured
#: rotor angle (a phase file, or a dq file with its ``theta_e``; see ``model.model_experiment``). Not a
#: candidate of ``--effects``: named with its fix, the offset is estimated where the user asks for it.
ANGLE_EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "encoder_offset": (("encoder_offset",), ("encoder_offset",),
                       "an encoder offset (the angle column's zero off the rotor's d axis)"),
}
#: Magnetic saturation, tested as the bench effects are (``fit --magnetics auto``): each term of the
#: saturating law (``physics._magnetics``) with its exponents chosen among ``physics.EXPONENT_CANDIDATES``,
#: the candidate whose signature explains most of the residuals (its p-value Bonferroni-corrected for
#: the number of candidates).
MAGNETIC_EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "saturation_d": (("sat_d",), ("sat_d",), "magnetic saturation of the d axis (Ld changes with current)"),
    "saturation_q": (("sat_q",), ("sat_q",), "magnetic saturation of the q axis (Lq changes with current)"),
    "cross_saturation": (("sat_dq",), ("sat_dq",),
                         "cross-saturation (the current on each axis changes the other axis's inductance)"),
}
#: The iron bridges of a PM-assisted motor (``physics.BRIDGE``): not score-tested (at ``sat_b = 0`` its shape is
#: undefined), tried by the selection where no fit of the law about the magnet converges (``selection._bridge``).
BRIDGE_EFFECTS: dict[str, tuple[tuple[str, ...], tuple[str, ...], str]] = {
    "iron_bridge": (BRIDGE, ("sat_b",), "the iron bridges of a PM-assisted motor (saturating asymmetrically in i_d)"),
}
_ALL_EFFECTS = {**EFFECTS, **ANGLE_EFFECTS, **MAGNETIC_EFFECTS}


def _orthogonal_part(columns: np.ndarray, basis: np.ndarray) -> np.ndarray:
    if basis.shape[1] == 0:
        return columns
    coef, *_ = np.linalg.lstsq(basis, columns, rcond=None)
    return columns - basis @ coef


@dataclasses.dataclass(frozen=True)
class Score:
    """A score test of one effect against a fit's residuals.

    Attributes:
        statistic: ``||P r||^2 / sigma_hat^2`` (-), chi-squared under no effect.
        dof: its degrees of freedom (the signature's rank).
        direction: sign of the residual along the first column's unabsorbed part:
            +1 the effect is larger than modelled, -1 smaller.
        step: one-step estimate of the probed parameters' change from the fit (their units), shape (k,).
        step_se: its standard errors (their units), shape (k,).
    """

    statistic: float
    dof: int
    direction: float
    step: np.ndarray
    step_se: np.ndarray


def score_test(residual: np.ndarray, signature: np.ndarray, fitted: np.ndarray, sigma_hat: float) -> Score:
    """Score test of ``signature`` (m, k) columns against ``residual`` (m,) after a fit with columns ``fitted``."""
    e = _orthogonal_part(signature, fitted)
    if not np.all(np.isfinite(e)):  # a signature the model could not compute: no test
        return Score(float("nan"), 0, 0.0, np.full(signature.shape[1], np.nan), np.full(signature.shape[1], np.nan))
    u, s, vt = np.linalg.svd(e, full_matrices=False)
    keep = s > 1e-10 * max(float(s.max(initial=0.0)), 1e-300)
    k = signature.shape[1]
    if not keep.any():
        return Score(float("nan"), 0, 0.0, np.full(k, np.nan), np.full(k, np.nan))
    proj = u[:, keep].T @ residual
    pinv = (vt[keep].T / s[keep]) @ u[:, keep].T  # (E^T E)^+ E^T
    cov = (vt[keep].T / s[keep] ** 2) @ vt[keep]
    return Score(float(proj @ proj / sigma_hat**2), int(keep.sum()), float(np.sign(e[:, 0] @ residual)),
                 pinv @ residual, sigma_hat * np.sqrt(np.diag(cov)))


def _magnetic_scores(motor: MotorParams, fit_names: tuple[str, ...], experiment: Experiment,
                     effects: tuple[str, ...], residual: np.ndarray, sigma_hat: float,
                     fitted: np.ndarray | None = None, started: Callable[[], np.ndarray] | None = None
                     ) -> dict[str, tuple]:
    """Per magnetic effect, ``(score, motor at its best exponents, number of candidates)``.

    Every candidate of a term's exponents (``physics.EXPONENT_CANDIDATES``) is tested against the
    fitted parameters' columns ``fitted`` (m, n), computed here when not given (the bench effects'
    score tests have them: one sensitivity kernel fewer to compile); each term keeps the candidate whose
    signature has the largest statistic. The candidates' columns come from one batched rollout
    (``model.start_saturation_columns``; ``started``: that rollout, dispatched by :func:`_start_magnetic`).
    """
    if not effects:
        return {}
    if fitted is None:
        fitted, _ = effect_signatures(motor, fit_names, experiment, ())
    columns = (started or _start_magnetic(motor, experiment))()
    best: dict[str, tuple] = {}
    for e in effects:
        term = _ALL_EFFECTS[e][1][0]
        names, values = EXPONENT_CANDIDATES[term]
        for j, candidate in enumerate(values):
            score = score_test(residual, columns[MAGNETIC.index(term), j].reshape(-1, 1), fitted, sigma_hat)
            if e not in best or not np.isfinite(best[e][0].statistic) or score.statistic > best[e][0].statistic:
                best[e] = (score, motor.replace(**dict(zip(names, candidate))), len(values))
    return best


def _start_magnetic(motor: MotorParams, experiment: Experiment) -> Callable[[], np.ndarray]:
    """The magnetic candidates' columns at ``motor`` (``model.start_saturation_columns``), dispatched now."""
    return start_saturation_columns(motor, _one_substep(model_experiment(experiment, motor, MAGNETIC)))


def _one_substep(experiment: Experiment) -> Experiment:
    """The experiment for a probe's sensitivity columns: no dead-time sub-steps (they resolve the sign's turn at
    v_dead != 0; a probe's columns are directions to test, each one program run once). Without the dead-time
    model the sub-steps do nothing and the experiment stays as it is. The fitted parameters' columns are the
    fit's own (its sub-steps too): the residuals are orthogonal to those at its optimum."""
    return dataclasses.replace(experiment, dead_time_substeps=1) if experiment.dead_time else experiment


def effect_signatures(motor: MotorParams, fit_names: tuple[str, ...], experiment: Experiment,
                      effects: tuple[str, ...]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The fitted parameters' sensitivity columns (m, n) and each effect's probe columns (m, k) at ``motor``.

    ``m`` = 2 x samples (i_d and i_q interleaved per sample, as ``currents.reshape(-1)``). The fitted
    columns come from the fit's own sensitivity kernel (``identify.sensitivity_jacobian``: the one its
    identifiability check runs), each effect's columns from a kernel of its own: the model with that
    effect alone switched on (``model_experiment``), differentiated along its probes only. The kernels
    run side by side in threads (XLA releases the GIL while it compiles and loads).

    One kernel for all the columns was a first fit's largest: the delay's two integrations per
    sample and the dead time's sequential rollout in one program, differentiated along every
    column (examples/bench.csv: 10.4 s to compile, 9.2 MB to load). Apart, the delay's, the dead
    time's and the offsets' compile in 1.9, 3.3 and 0.3 s (1.3, 3.9 and 0.2 MB), and the fitted
    parameters' kernel is the fit's. The columns are the same derivatives at the same motor (the
    other effects' terms are zero at the nominal values: no dead-time voltage at ``v_dead = 0``, no
    second sub-interval at a whole-sample delay), equal to float64 rounding.
    """
    work, assemble = _signature_work(motor, fit_names, experiment, effects)
    return assemble(side_by_side(work))


def _signature_work(motor: MotorParams, fit_names: tuple[str, ...], experiment: Experiment,
                    effects: tuple[str, ...]) -> tuple[list[Callable[[], np.ndarray]], Callable]:
    """The jobs of :func:`effect_signatures`, the probes' first (delay, dead time, offsets: the largest first)
    and the fitted columns' last, and the function of their results that is its value."""
    m = 2 * experiment.num_samples
    names = tuple(fit_names)
    groups = {e: tuple(n for n in _ALL_EFFECTS[e][1] if n not in names) for e in effects}

    def fitted_columns() -> np.ndarray:
        # The fit's own kernel, dead-time sub-steps and all: with them at one sub-step, the columns of a fit
        # with the dead time were another kernel to compile in each round of the selection (a cold fit of
        # examples/inverter_bench.csv 15.8 -> 13.9 s, median of 3 A/B), and not those the residuals are
        # orthogonal to (its rejected terms' statistics, all below 1, moved by up to 0.03).
        return np.asarray(sensitivity_jacobian(motor, experiment, names))[:m]

    def probe_columns(probes: tuple[str, ...]) -> np.ndarray:
        # The currents' rows only (a measured speed as an output adds rows of its own): the tests read
        # current residuals.
        probe = _one_substep(model_experiment(experiment, motor, probes))
        return np.asarray(sensitivity_jacobian(motor, probe, probes, probing=True))[:m]

    probed = [p for p in dict.fromkeys(groups.values()) if p]

    def assemble(results: list) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        fitted, found = results[-1], dict(zip(probed, results))
        columns = {}
        for e in effects:
            by_name = {n: fitted[:, names.index(n)] for n in _ALL_EFFECTS[e][1] if n in names}
            by_name.update({n: found[groups[e]][:, i] for i, n in enumerate(groups[e])})
            columns[e] = np.stack([by_name[n] for n in _ALL_EFFECTS[e][1]], axis=1)
        return fitted, columns

    return [functools.partial(probe_columns, p) for p in probed] + [fitted_columns], assemble


def untested_effects(fit_names: tuple[str, ...], experiment: Experiment) -> tuple[str, ...]:
    """The effects :func:`unmodelled_effects` tests by default: every one of :data:`EFFECTS` none of whose
    parameters the fit estimated, and with a measured rotor angle the encoder offset (:data:`ANGLE_EFFECTS`)."""
    groups = {**EFFECTS, **ANGLE_EFFECTS} if experiment.has_angle else EFFECTS
    return tuple(e for e, (params, _, _) in groups.items() if not set(params) & set(fit_names))


class _Prepared:
    """The keys of what :func:`prepare_unmodelled_effects` has compiled in this process, forgotten with JAX's own
    caches: ``jax.clear_caches()`` drops the compiled kernels the keys stand for (with drivecal's on-disk cache
    off, the plain jitted calls'), and a stale key would skip the preparation and leave them to compile at the
    fit (a test worker clears JAX's caches at its memory-map limit: tests/conftest.py)."""

    def __init__(self) -> None:
        self.keys: set = set()

    def cache_clear(self) -> None:
        self.keys.clear()

    def cache_info(self) -> int:
        return len(self.keys)

    def cache_keys(self) -> list:
        return list(self.keys)


#: What :func:`prepare_unmodelled_effects` has compiled in this process, cleared by ``jax.clear_caches()``.
_PREPARED = _Prepared()
jax_util.register_cache(_PREPARED, "drivecal.diagnose.prepare_unmodelled_effects")


def prepare_unmodelled_effects(motor: MotorParams, fit_names: tuple[str, ...], experiment: Experiment,
                               effects: tuple[str, ...]) -> None:
    """Trace and compile now (or load) the kernels :func:`unmodelled_effects` will run; none of them runs here.

    The score tests' sensitivity columns (:func:`effect_signatures`, and the magnetic candidates'
    where ``effects`` name them and the motor is linear) and the residuals' prediction are seconds
    of compilation in a first fit; ``select_effects`` calls this in a thread while the base fit
    compiles, so they compile beside it. The kernels depend on the experiment's shapes and on which
    parameters are fitted and probed, not on their values: the later call at the fitted motor finds
    them ready (the fitted columns' kernel, the fit's own, is compiled once for both).
    """
    plain = tuple(e for e in effects if e not in MAGNETIC_EFFECTS)
    magnetic = bool(set(effects) & set(MAGNETIC_EFFECTS)) and not is_saturating(motor)
    leaves, tree = jax.tree_util.tree_flatten(experiment)
    key = (tuple(fit_names), plain, magnetic, tree, tuple(np.shape(x) for x in leaves))
    if (plain or magnetic) and key not in _PREPARED.keys:  # once per kernel in a process (flagged motors share)
        _PREPARED.keys.add(key)
        # as a fit returns it: the fitted parameters as float64 arrays (a Python float would trace as a weak type)
        fitted = parameter_values(motor, tuple(fit_names), np)  # on the host: no JAX operation dispatched
        motor = with_experiment_delay(motor.with_vector(tuple(fit_names), fitted), experiment)
        base = model_experiment(experiment, motor, tuple(fit_names))
        # What unmodelled_effects runs after the fit: kept kernels load side by side, new ones compile one at a
        # time (model.ahead_of_need), the largest first; none runs (model.outputs_unused).
        bench = tuple(e for e in plain if e not in ANGLE_EFFECTS)
        work = _signature_work(motor, tuple(fit_names), base, bench)[0] if bench else []
        if magnetic:
            work.append(lambda: _start_magnetic(motor, base)())
        work.append(lambda: predicted_currents(motor, base))
        # An encoder offset's test last: the verdict's, after the selection's own tests.
        angle = tuple(e for e in plain if e in ANGLE_EFFECTS)
        work += _signature_work(motor, tuple(fit_names), base, angle)[0][:-1] if angle else []
        with ahead_of_need(), outputs_unused():
            side_by_side(work)


def unmodelled_effects(
    motor: MotorParams,
    fit_names: tuple[str, ...],
    experiment: Experiment,
    currents: np.ndarray,
    sigma_hat: float,
    predicted: np.ndarray | None = None,
    effects: tuple[str, ...] | None = None,
) -> list[dict[str, Any]]:
    """Score tests of the bench effects missing from a fit.

    Args:
        motor: the fitted motor (estimates in place; its ``delay`` is the one the fit used).
        fit_names: the parameters the fit estimated.
        experiment: the experiment the fit used.
        currents: measured ``[i_d, i_q]`` (A), shape (M, 2).
        sigma_hat: residual standard deviation of the fit (A).
        predicted: the fit's predicted ``[i_d, i_q]`` (A), shape (M, 2), when
            already computed (the report has them); else computed here.
        effects: the effects to test (default: every one of :data:`EFFECTS`
            none of whose parameters the fit estimated, and on a file with a
            measured rotor angle the encoder offset of :data:`ANGLE_EFFECTS`).

    Returns:
        Per tested effect, most significant first: ``effect``, ``parameters``,
        ``statistic``, ``dof``, ``p_value``, ``p_threshold``, ``suspected``,
        ``direction``, ``one_step`` (``{parameter: {"estimate", "se"}}``, the
        one-step estimate and its standard error, SI units) and a ``message``.
    """
    if effects is None:
        effects = untested_effects(fit_names, experiment)
    if not effects:
        return []
    motor = with_experiment_delay(motor, experiment)
    base = model_experiment(experiment, motor, fit_names)
    y = np.asarray(currents, dtype=float).reshape(-1)
    if predicted is None:
        predicted = predicted_currents(motor, base)
    residual = y - np.asarray(predicted, dtype=float).reshape(-1)
    plain = tuple(e for e in effects if e not in MAGNETIC_EFFECTS)
    magnetic = tuple(e for e in effects if e in MAGNETIC_EFFECTS)
    at = motor  # where the magnetic candidates are tested
    if magnetic and not is_saturating(motor):
        # The law's coefficients are per unit of i_ref: at the data's peak current (as the selection sets
        # it) the candidates' signatures are of order one; at an arbitrary i_ref a step of 1e-4 in a
        # coefficient could bend the law past monotone at the data's currents.
        peak = float(np.max(np.abs(np.asarray(currents, dtype=float)), initial=0.0))
        if np.isfinite(peak) and peak > 0.0:
            at = motor.replace(i_ref=float(f"{peak:.2g}"))
    # The candidates' rollout dispatched first: XLA runs it while the bench effects' tests are computed.
    started = _start_magnetic(at, base) if magnetic else None
    scores, fitted = {}, None
    if plain:
        fitted, columns = effect_signatures(motor, fit_names, base, plain)
        scores = {e: (score_test(residual, columns[e], fitted, sigma_hat), motor, 1) for e in plain}
    motor = at
    # The fitted columns do not depend on i_ref (a linear motor's currents do not): the plain tests' serve.
    scores.update(_magnetic_scores(motor, fit_names, base, magnetic, residual, sigma_hat, fitted, started))
    threshold = ALPHA / len(effects)
    delay = float(motor.delay)
    out = []
    for effect in effects:
        params, probes, what = _ALL_EFFECTS[effect]
        score, at, choices = scores[effect]
        p = float(min(1.0, choices * chi2_sf(score.statistic, score.dof))) if score.dof else float("nan")
        suspected = bool(score.dof and p < threshold)
        fix = "add " + ", ".join(params) + " to 'estimate' (motor file) or --estimate, or use --effects auto"
        if effect == "delay":
            # Two-sided, but a delay cannot go below zero: at 0 only "more" is a finding.
            more = score.direction >= 0
            suspected = suspected and (more or delay > 0)
            what = f"{'more' if more else 'less'} PWM/computation delay than the {delay:g} sample(s) assumed"
            fix = f"{'raise' if more else 'lower'} 'delay_samples' (motor file) or --delay, or use --effects auto"
        if effect in ANGLE_EFFECTS:
            step = float(getattr(motor, probes[0])) + float(score.step[0])
            fix = (f"one step from this fit puts it at {np.degrees(step):.3g} deg electrical (SE "
                   f"{np.degrees(float(score.step_se[0])):.2g} deg); add encoder_offset to 'estimate' (motor file) "
                   "or --estimate, or set the encoder's zero in the drive")
        one_step = {n: {"estimate": float(getattr(motor, n)) + float(d), "se": float(se)}
                    for n, d, se in zip(probes, score.step, score.step_se)}
        if effect in MAGNETIC_EFFECTS:
            one_step.update({n: {"estimate": float(getattr(at, n)), "se": 0.0}
                             for n in EXPONENT_CANDIDATES[probes[0]][0]})
            fix = "use --magnetics auto or saturating (the default auto fits what the data support)"
        out.append({
            "effect": effect,
            "parameters": list(params),
            "statistic": score.statistic,
            "dof": score.dof,
            "p_value": p,
            "p_threshold": threshold,
            "suspected": suspected,
            "direction": score.direction,
            "one_step": one_step,
            "message": f"the residuals carry the signature of {what} (score test p = {p:.2g}); {fix}"
            if suspected else f"no sign of {what} (score test p = {p:.2g})",
        })
    # The most likely cause first; among p-values that underflow alike, the largest statistic per degree of freedom.
    out.sort(key=lambda e: (not e["suspected"], e["p_value"] if np.isfinite(e["p_value"]) else 2.0,
                            -e["statistic"] / max(e["dof"], 1) if np.isfinite(e["statistic"]) else 0.0))
    return out
