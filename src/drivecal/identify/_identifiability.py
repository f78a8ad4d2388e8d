"""Identifiability before fitting: can this experiment pin these parameters down?

From the sensitivity Jacobian ``J = d(predicted currents)/d(theta)`` at the
nominal motor (forward mode: four parameters, thousands of outputs):

* jaxterity's ``identifiability_from_jacobian`` (the same steps, ``identifiability_report``)
  gives rank, condition number and weak parameters;
* parameters whose column is zero are *dead*: the data does not move when they
  do (e.g. lambda_m on a locked rotor), named with the reason;
* so are saturation coefficients the plan's currents cannot show (one current level on
  their axis, no d- and q-axis current together: ``_magnetic_reasons``), named with the
  segment that would show them;
* parameters that only move together with others (a null direction of J once the dead ones are removed) are *confounded*;
* the predicted 95 % CI half-widths ``t * sigma * sqrt(diag((J^T J)^-1))`` of the
  identifiable rest, for a given sensor noise, before any data exists.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import numpy as np

from .._stats import t_ppf
from ..errors import DrivecalError
from ..model import Experiment, model_experiment, simulate_states
from ..physics import ADDITIVE_SCALE, ESTIMATED, MECHANICAL, MotorParams, dq_to_abc, parameter_values, search_scale
from ._jacobian import jacobian_and_outputs, sensitivity_jacobian
from ._magnetic_reasons import magnetic_reasons

#: A parameter whose relative sensitivity is below this fraction of the
#: strongest one is dead: at double precision it is zero.
DEAD_TOL = 1e-9
#: Conditioning ceiling (column-normalised J) for the verdict "identifiable".
COND_MAX = 1e6
#: Predicted correlation with another parameter above which (in magnitude)
#: a parameter is weak: the data pins down a combination of the two, not each
#: (a common practical-identifiability threshold). Variance inflation alone is
#: no such sign: a D-optimal plan can correlate several estimates moderately
#: and still pin each down far better than the default plan.
CORR_MAX = 0.99
#: A positive parameter whose predicted 95 % CI half-width exceeds this
#: fraction of its value is weak: the plan barely constrains it.
WEAK_RELATIVE_CI = 0.5


@dataclasses.dataclass(frozen=True)
class Identifiability:
    """What an experiment can identify, judged at a nominal motor.

    Attributes:
        names: candidate parameters, in Jacobian-column order.
        rank: numerical rank of the column-normalised Jacobian.
        condition_number: of the identifiable subspace (jaxterity's convention:
            finite even when rank-deficient; read ``rank`` first).
        identifiable: full rank and well conditioned.
        weak_params: parameters barely constrained though the rank is full.
        dead_params: parameters with zero sensitivity, or hidden by the plan's structure (alpha_R at one
            temperature, a saturation coefficient without the current levels that show it).
        confounded_params: parameters that only move together with others.
        reasons: why each non-identifiable parameter is not identifiable.
        singular_values: of the column-normalised Jacobian, descending.
        sensitivity: ``||dI/d ln(theta_i)||`` (A): current change per relative
            change of each parameter.
        fit_names: the parameters a fit can estimate (the rest are held at their prior).
        noise_sigma: sensor noise (A) assumed for the predictions below.
        num_residuals: 2M, the current samples (i_d and i_q) of the experiment.
        predicted_se: predicted standard error of each parameter (its unit),
            NaN where not identifiable.
        predicted_ci95: predicted 95 % CI half-width (its unit), NaN where not identifiable.
        variance_inflation: per name, how much correlation with the other
            fitted parameters inflates its variance (1 = none; NaN where not
            fitted), for information.
    """

    names: tuple[str, ...]
    rank: int
    condition_number: float
    identifiable: bool
    weak_params: tuple[str, ...]
    dead_params: tuple[str, ...]
    confounded_params: tuple[str, ...]
    reasons: dict[str, str]
    singular_values: tuple[float, ...]
    sensitivity: tuple[float, ...]
    fit_names: tuple[str, ...]
    noise_sigma: float
    num_residuals: int
    predicted_se: tuple[float, ...]
    predicted_ci95: tuple[float, ...]
    variance_inflation: tuple[float, ...] = ()

    def verdict(self) -> tuple[str, str]:
        """``(words, colour)``: ``identifiable``, ``weakly identifiable: R, alpha_R`` (full rank, see ``reasons``),
        ``NOT identifiable: Ld, lambda_m`` (dead or confounded) or ``ill-conditioned`` (none to blame)."""
        lost, weak = ([n for n in self.names if n in group] for group in (self.dead_params + self.confounded_params,
                                                                          self.weak_params))
        if self.identifiable:
            return "identifiable", "green"
        if lost or self.rank < len(self.names):
            return "NOT identifiable" + (f": {', '.join(lost)}" if lost else ""), "red"
        return (f"weakly identifiable: {', '.join(weak)}", "yellow") if weak else ("ill-conditioned", "red")

    def summary(self, markup: bool = False) -> str:
        """``rank 4/4, condition number 3.67 -> identifiable``: the line every command prints (rich colours with ``markup``)."""
        words, colour = self.verdict()
        return f"rank {self.rank}/{len(self.names)}, condition number {self.condition_number:.3g} -> " + (
            f"[{colour}]{words}[/{colour}]" if markup else words)

    def to_dict(self) -> dict:
        """The JSON ``identifiability`` block."""
        def finite(x):
            return None if not math.isfinite(x) else x

        return {
            "names": list(self.names),
            "fit_names": list(self.fit_names),
            "num_residuals": self.num_residuals,
            "rank": self.rank,
            "num_params": len(self.names),
            "condition_number": finite(self.condition_number),
            "identifiable": self.identifiable,
            "weak_params": list(self.weak_params),
            "dead_params": list(self.dead_params),
            "confounded_params": list(self.confounded_params),
            "reasons": dict(self.reasons),
            "singular_values": list(self.singular_values),
            "sensitivity": dict(zip(self.names, self.sensitivity)),
            "noise_sigma": self.noise_sigma,
            "predicted_se": {n: finite(v) for n, v in zip(self.names, self.predicted_se)},
            "predicted_ci95": {n: finite(v) for n, v in zip(self.names, self.predicted_ci95)},
            "variance_inflation": {n: finite(v) for n, v in zip(self.names, self.variance_inflation)},
        }

    @classmethod
    def from_dict(cls, d: dict) -> Identifiability:
        """Rebuild from :meth:`to_dict` output (a saved result JSON); ``null`` becomes NaN."""
        def num(x):
            return math.nan if x is None else float(x)

        sens = d.get("sensitivity") or {}
        names = tuple(d.get("names") or sens)
        dead = tuple(d.get("dead_params", ()))
        confounded = tuple(d.get("confounded_params", ()))
        fit_names = tuple(d.get("fit_names") or (n for n in names if n not in dead + confounded))
        pse, pci = d.get("predicted_se") or {}, d.get("predicted_ci95") or {}
        return cls(
            names=names,
            rank=int(d["rank"]),
            condition_number=num(d.get("condition_number")),
            identifiable=bool(d["identifiable"]),
            weak_params=tuple(d.get("weak_params", ())),
            dead_params=dead,
            confounded_params=confounded,
            reasons=dict(d.get("reasons", {})),
            singular_values=tuple(num(s) for s in d.get("singular_values", ())),  # null: NaN, as the JSON check allows
            sensitivity=tuple(num(sens.get(n)) for n in names),
            fit_names=fit_names,
            noise_sigma=num(d.get("noise_sigma")),
            num_residuals=int(d.get("num_residuals", 0)),
            predicted_se=tuple(num(pse.get(n)) for n in names),
            predicted_ci95=tuple(num(pci.get(n)) for n in names),
            variance_inflation=tuple(num((d.get("variance_inflation") or {}).get(n)) for n in names),
        )


class _Report(NamedTuple):
    """What ``jaxterity.sysid.recipes.identifiability_from_jacobian`` reports (the fields used here)."""

    singular_values: tuple[float, ...]
    rank: int
    condition_number: float
    identifiable: bool
    weak_params: tuple[str, ...]


def identifiability_report(jacobian: np.ndarray, names: tuple[str, ...], *, weak_var_ratio: float = 1e3) -> _Report:
    """jaxterity's ``identifiability_from_jacobian(jacobian, names, cond_max=COND_MAX)``, step for step.

    Importing ``jaxterity.sysid`` loads MuJoCo (1.5 s per process) for a few
    lines of NumPy; tests/identify/test_identify.py holds this copy equal to jaxterity's.
    """
    jac = np.asarray(jacobian, dtype=np.float64)
    if jac.ndim != 2:
        jac = jac.reshape(jac.shape[0], -1)
    if jac.shape[1] != len(names):
        raise DrivecalError(f"identifiability: Jacobian has {jac.shape[1]} parameter columns but "
                            f"{len(names)} names were given.")
    # Column-normalise so conditioning measures relative, not unit-scale, spread.
    col_norm = np.linalg.norm(jac, axis=0)
    col_norm = np.where(col_norm > 0, col_norm, 1.0)
    jn = jac / col_norm
    sv = np.linalg.svd(jn, compute_uv=False)
    sv_max = float(sv[0]) if sv.size else 0.0
    tol = max(jn.shape) * np.finfo(float).eps * sv_max
    rank = int(np.sum(sv > tol))
    sv_min = float(sv[rank - 1]) if rank > 0 else 0.0
    condition_number = float(sv_max / sv_min) if sv_min > 0 else float("inf")
    # Marginal variance of each (normalised) parameter: large means weakly excited.
    weak: tuple[str, ...] = ()
    if rank == jn.shape[1] and jn.shape[1] > 0:
        var = np.diag(np.linalg.pinv(jn.T @ jn))
        ref = float(np.min(var))
        if ref > 0:
            weak = tuple(names[i] for i in range(len(names)) if var[i] > weak_var_ratio * ref)
    return _Report(
        singular_values=tuple(float(v) for v in sv),
        rank=rank,
        condition_number=condition_number,
        identifiable=rank == len(names) and condition_number <= COND_MAX,
        weak_params=weak,
    )


def structural_reason(name: str, experiment: Experiment) -> str | None:
    """Why the plan's structure hides ``name`` from the currents, or None if it does not.

    These are the reasons that hold for any motor: no free rotor for
    lambda_m, no d-axis excitation for Ld, and so on.
    """
    volts = np.asarray(experiment.voltages)
    locked = np.asarray(experiment.locked) > 0.5
    if name == "lambda_m" and locked.all():
        return "no free-rotor segment (back-EMF needs the rotor to turn)"
    if name == "Ld" and not np.any(volts[:, 0]) and locked.all():
        return "no d-axis excitation (i_d never changes)"
    if name == "Lq" and not np.any(volts[:, 1]):
        return "no q-axis excitation (i_q never changes)"
    if name == "R" and not np.any(volts) and not np.any(np.asarray(experiment.initial_state)[:, :2]):
        return "no voltage applied, so no current flows"
    if name == "alpha_R":
        temps = np.asarray(experiment.temperature)
        known = temps[np.isfinite(temps)]
        if known.size == 0:
            return "no winding temperature recorded (give each segment a 'temperature')"
        if np.ptp(known) == 0:
            return f"every segment at one winding temperature ({known[0]:g} degC): alpha_R cannot be told from R"
    if name in ("offset_a", "offset_b") and not experiment.has_angle:
        return "per-phase offsets need a phase (abc) bench file with a rotor angle"
    if name == "encoder_offset" and not experiment.has_angle:
        return ("no rotor angle column: it is a dq file, which the drive turned into dq with an angle the file "
                "does not hold, so drivecal does not correct an encoder offset in it")
    if name in MECHANICAL:
        if locked.all():
            return "no free-rotor segment (the mechanics act only where the rotor turns)"
        if np.all(np.asarray(experiment.speed_input)[~locked] > 0.5):
            return ("the measured speed as the model's input in every free segment (--speed input), so the "
                    "mechanics never reach the currents")
    return None


#: What shows an encoder offset in the currents of a phase file (identifiability's advice).
ENCODER_ADVICE = ("an encoder offset shows in a free segment (the back-EMF lies on the rotor's q axis: a spin-up "
                  "shows it best) and, with the rotor locked, only through saliency (a step along a known direction "
                  "answers with Ld along the rotor's d axis and Lq along q, so its current turns in the transient "
                  "unless the step lies on an axis); add a free spin-up")


def _why_dead(name: str, experiment: Experiment) -> str:
    """A plain-language reason a parameter has no effect on the currents."""
    if name == "encoder_offset" and experiment.has_angle:
        return f"no effect on the measured currents in this plan: {ENCODER_ADVICE}"
    return structural_reason(name, experiment) or "no effect on the measured currents in this plan"


def _why_weak(name: str, experiment: Experiment, fit_names: tuple[str, ...], cov: np.ndarray, half_width: float,
              value: float) -> str:
    """Why a fitted parameter is only weakly constrained, in plain language.

    ``cov`` is the predicted covariance of ``fit_names`` (relative units);
    the partner most correlated with ``name`` is named.
    """
    what = (f"predicted 95 % CI +/-{100 * half_width / value:.3g} %" if name not in ADDITIVE_SCALE
            else f"predicted 95 % CI +/-{half_width:.3g}")
    i = fit_names.index(name)
    sd = np.sqrt(np.diag(cov))
    corr = cov[i] / (sd[i] * sd)
    corr[i] = 0.0
    j = int(np.argmax(np.abs(corr))) if len(fit_names) > 1 else i
    partner = f"nearly confounded with {fit_names[j]} (predicted correlation {corr[j]:+.4f})" if j != i else (
        "the plan barely moves the currents with it")
    if name == "alpha_R":
        temps = np.asarray(experiment.temperature)
        known = temps[np.isfinite(temps)]
        if known.size:
            return (f"temperature spread of {np.ptp(known):.3g} K is too small to tell alpha_R from R: {partner}, "
                    f"{what}; run segments further apart in temperature")
    if name == "encoder_offset":
        return f"{partner}, {what}: {ENCODER_ADVICE}"
    return f"{partner}, {what}"


#: The dead-time parameters, and what tells them from R: current reversals and small currents.
_DEAD_TIME = ("v_dead", "i_dead")


def dead_time_advice(experiment: Experiment, motor: MotorParams) -> str:
    """Why this plan cannot tell the dead time from R, and which segment would, in plain language.

    The dead-time error ``-v_dead * sign(i_x)`` of a phase whose current keeps its sign is a
    constant voltage, which a step answers like a change of R (and, in its transient, of L); what
    shows it is a phase current that reverses within a segment (the error flips while R * i passes
    through zero) and operation at currents comparable to ``i_dead`` (A), where the error ramps.
    Counted on the nominal motor's predicted phase currents.
    """
    states = np.asarray(simulate_states(motor, experiment, keep=4))
    theta_e = np.asarray(experiment.theta_e_start) + float(motor.pole_pairs) * states[:, 3]
    phases = np.stack(dq_to_abc(states[:, 0], states[:, 1], theta_e, xp=np), axis=1)  # (M, 3)
    width = max(float(motor.i_dead), 1e-6)
    peak = float(np.max(np.abs(phases))) if phases.size else 0.0
    clear = np.abs(phases) > max(3.0 * width, 0.05 * peak)  # a sign that is not ripple around zero
    segment = np.cumsum(np.asarray(experiment.segment_start, dtype=bool))
    reversals = 0
    for x in range(3):  # sign changes between successive clear samples of one segment
        k = np.flatnonzero(clear[:, x])
        sign = np.sign(phases[k, x])
        reversals += int(np.sum((segment[k[1:]] == segment[k[:-1]]) & (sign[1:] != sign[:-1])))
    small = float(np.mean(np.abs(phases) < 3.0 * width)) if phases.size else 0.0
    near = f"{100 * small:.2g} % of the phase-current samples are within 3 i_dead ({3 * width:.3g} A) of zero"
    if not reversals:
        return (f"dead time looks like R to this plan: no phase current reverses within a segment, and {near}; add "
                "a free spin-up (every phase current reverses each electrical cycle) or a locked segment whose "
                "voltage changes sign within it")
    return (f"the phase currents reverse {reversals} time{'s' if reversals != 1 else ''} within a segment, but {near}, "
            "too few to shape the dead time's transition; a slower reversal (a longer free spin-up, or a slow "
            "voltage ramp through zero) would show it")


def _advise_dead_time(reasons: dict[str, str], names: tuple[str, ...], weak: list[str], confounded: tuple[str, ...],
                      fit_names: tuple[str, ...], cov: np.ndarray, experiment: Experiment, motor: MotorParams) -> None:
    """Add :func:`dead_time_advice` to the reasons of the dead-time parameters and of R where they are not pinned down."""
    unclear = [n for n in _DEAD_TIME if n in names and (n in weak or n in confounded)]
    if "R" in weak and "R" in fit_names and "v_dead" in fit_names:
        sd = np.sqrt(np.diag(cov))
        i, j = fit_names.index("R"), fit_names.index("v_dead")
        if abs(cov[i, j] / (sd[i] * sd[j])) > CORR_MAX:
            unclear.append("R")
    if not unclear:
        return
    advice = dead_time_advice(experiment, motor)
    for n in unclear:
        reasons[n] = f"{reasons[n]}; {advice}" if reasons.get(n) else advice


def check_requested(names: tuple[str, ...], experiment: Experiment, source: str) -> None:
    """Refuse a run that cannot show a parameter the user asked for by name.

    Raises:
        DrivecalError: naming ``source``, the parameter, the reason and the fix.
    """
    for name in names:
        reason = structural_reason(name, experiment)
        if reason is not None:
            fix = {
                "lambda_m": "add a free spin-up segment (locked = false)",
                "Ld": "add a segment with d-axis voltage",
                "Lq": "add a segment with q-axis voltage",
                "R": "apply a voltage",
                "alpha_R": "run segments at two or more winding temperatures",
                "offset_a": "give a phase bench file (i_a, i_b, v_a, v_b, theta_e) or estimate offset_d/offset_q",
                "offset_b": "give a phase bench file (i_a, i_b, v_a, v_b, theta_e) or estimate offset_d/offset_q",
                "encoder_offset": "give the phase bench file (i_a, i_b, v_a, v_b with theta_e or theta_m) or set the "
                                  "encoder's zero in the drive and record again",
                **dict.fromkeys(MECHANICAL, "fit with --speed output (the measured speed as a second output) or "
                                            "--speed ignore, on a run with a free segment (a spin-up followed by a "
                                            "coast-down shows friction best)"),
            }[name]
            raise DrivecalError(
                f"{source}: {name} is requested ('estimate' in the motor file) but the run has {reason}; "
                f"{fix}, or drop {name} from 'estimate'."
            )


def _confounded(jac_scaled: np.ndarray, names: tuple[str, ...]) -> tuple[str, ...]:
    """Parameters that load on a null direction of the (live) Jacobian."""
    if not names:
        return ()
    norms = np.linalg.norm(jac_scaled, axis=0)
    jn = jac_scaled / np.where(norms > 0, norms, 1.0)
    _, s, vt = np.linalg.svd(jn, full_matrices=False)
    tol = max(jn.shape) * np.finfo(float).eps * s[0]
    null = vt[s <= tol]
    if null.size == 0:
        return ()
    loading = np.max(np.abs(null), axis=0)
    return tuple(n for n, w in zip(names, loading) if w > 1e-3)


def assess_identifiability(
    experiment: Experiment,
    motor: MotorParams,
    *,
    noise_sigma: float = 0.02,
    names: tuple[str, ...] = ESTIMATED,
) -> Identifiability:
    """Judge whether ``experiment`` identifies ``names`` of ``motor``, before any data.

    Args:
        experiment: the applied voltages and rotor conditions.
        motor: nominal motor (the datasheet values, or the prior of a fit).
        noise_sigma: current-sensor noise standard deviation (A), for the
            predicted intervals.
        names: the parameters to be estimated.
    """
    experiment = model_experiment(experiment, motor, names)
    jac, outputs = (np.asarray(a) for a in jacobian_and_outputs(motor, experiment, names))
    if not np.all(np.isfinite(jac)):
        raise DrivecalError(
            "the motor's predicted currents are not finite on this experiment (the nominal values "
            f"{', '.join(f'{n} = {float(getattr(motor, n)):.4g}' for n in names)} make the model blow up): "
            "check the motor file's values and units against the datasheet.")
    # d I / d ln(theta) (per additive step for offsets and dead time): comparable across parameters.
    scale = search_scale(motor, names, np)[1]
    jac_scaled = jac * scale
    sensitivity = np.linalg.norm(jac_scaled, axis=0)
    strongest = float(sensitivity.max()) if sensitivity.size else 0.0
    # A structural reason (e.g. alpha_R with one temperature) makes a parameter dead even where its
    # column is not zero but merely a copy of another's: hold it, so the other stays fitted. So does a
    # saturation coefficient the plan's currents cannot show (one level on its axis, no d and q together).
    hidden = magnetic_reasons(experiment, motor, names, outputs[: 2 * experiment.num_samples].reshape(-1, 2))
    dead = tuple(n for n, s in zip(names, sensitivity) if s <= DEAD_TOL * strongest or n in hidden
                 or (n not in ESTIMATED and structural_reason(n, experiment)))
    live = tuple(n for n in names if n not in dead)
    live_idx = [names.index(n) for n in live]
    confounded = _confounded(jac_scaled[:, live_idx], live)
    fit_names = tuple(n for n in live if n not in confounded)

    report = identifiability_report(jac, names)
    reasons = {n: hidden.get(n) or _why_dead(n, experiment) for n in dead}
    reasons.update({n: structural_reason(n, experiment)
                    or "moves the currents only together with " + ", ".join(m for m in confounded if m != n)
                    for n in confounded})

    m = jac.shape[0]
    se = np.full(len(names), np.nan)
    cov_rel = np.zeros((0, 0))
    vif = np.full(len(names), np.nan)
    paired = np.zeros(len(names))
    if fit_names:
        idx = [names.index(n) for n in fit_names]
        js = jac_scaled[:, idx]
        cov_rel = noise_sigma**2 * np.linalg.inv(js.T @ js)
        se[idx] = np.sqrt(np.diag(cov_rel)) * scale[idx]
        norms = np.linalg.norm(js, axis=0)
        vif[idx] = np.diag(cov_rel) * norms**2 / noise_sigma**2
        sd = np.sqrt(np.diag(cov_rel))
        corr = cov_rel / np.outer(sd, sd) - np.eye(len(idx))
        paired[idx] = np.max(np.abs(corr), axis=1) if len(idx) > 1 else 0.0
    t_factor = float(t_ppf(0.975, max(m - len(fit_names), 1)))
    weak = [n for n in report.weak_params if n in fit_names]
    theta = parameter_values(motor, names, np)
    for i, n in enumerate(names):
        # A positive parameter whose predicted interval spans more than half its value is not pinned down.
        loose = n not in ADDITIVE_SCALE and t_factor * se[i] > WEAK_RELATIVE_CI * abs(theta[i])
        if n in fit_names and (loose or paired[i] > CORR_MAX) and n not in weak:
            weak.append(n)
    for n in weak:
        reasons[n] = _why_weak(n, experiment, fit_names, cov_rel, t_factor * se[names.index(n)],
                               abs(theta[names.index(n)]))
    _advise_dead_time(reasons, names, weak, confounded, fit_names, cov_rel, experiment, motor)
    return Identifiability(
        names=tuple(names),
        rank=int(report.rank),
        condition_number=float(report.condition_number),
        identifiable=bool(report.identifiable) and not dead and not confounded and not weak,
        weak_params=tuple(weak),
        dead_params=dead,
        confounded_params=confounded,
        reasons=reasons,
        singular_values=tuple(float(s) for s in report.singular_values),
        sensitivity=tuple(float(s) for s in sensitivity),
        fit_names=fit_names,
        noise_sigma=float(noise_sigma),
        num_residuals=int(m),
        predicted_se=tuple(float(s) for s in se),
        predicted_ci95=tuple(float(t_factor * s) for s in se),
        variance_inflation=tuple(float(v) for v in vif),
    )
