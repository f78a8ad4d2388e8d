"""D-optimal design: improve a plan's amplitudes, durations and bands before bench time.

The predicted covariance of the estimates is ``Cov = sigma^2 (J^T J)^-1`` with
``J = d(i_d, i_q at every sample) / d ln(theta)`` on the nominal motor (the same
Jacobian ``identify`` and ``fit`` use). A D-optimal plan minimises ``log det Cov``,
i.e. the volume of the confidence ellipsoid, subject to

* the margins ``drivecal plan`` keeps (``_bench_limits``): voltages inside
  :data:`VOLTAGE_FRACTION` of the circle ``|v_dq| <= v_dc / sqrt(3)`` (held by
  construction: every waveform is a bounded map of unconstrained variables),
  predicted peak ``|i_dq|`` under :data:`CURRENT_MARGIN` of the current limit, on
  free segments the speed under :data:`SPEED_FRACTION` of the speed limit
  (``max_speed``, the no-load speed the voltage circle allows, and the RK4 step
  bound), on locked ones the clamp torque under :data:`TORQUE_MARGIN` of
  ``max_torque`` (smooth quadratic penalties, then exact scaling);
* a time budget: the durations are fractions of the budget (softmax) above each
  segment's least (:func:`min_durations`: 200 samples, 3 electrical time constants
  of a locked step's axes, 1.5 spin-up times of a free one); a plan shorter than
  that gets a longer budget unless one is given.

The structure of the plan is kept: which segments are locked or free, which
axis carries which waveform kind. What moves is the waveform's level (step),
amplitude and offset (chirp, multisine, PRBS), its band (chirp f_start/f_stop,
multisine f_min/f_max), a gain (measured sequences) and the durations. A chirp,
multisine or PRBS whose amplitude the optimum leaves at nothing is written as the
constant it is, and its segment's name says "step" instead.

To differentiate through the durations, each segment is simulated on a fixed,
maximal sample grid and each sample's Fisher contribution is weighted by a
smooth window ``sigmoid((T_s - t_k) / tau)``. ``log det`` of the windowed
Fisher matrix is minimised with optimistix's BFGS, its gradient taken by
``jax.grad`` through ``jax.jacfwd`` of the forward model. The result is then
rounded to whole samples, built with the plan-file waveform generators, scaled
down where the exact simulation still passes a margin, and judged exactly with
:func:`drivecal.design.assess_design`. A plan that is not better than its input
is never returned as an improvement; an input that breaks the margins is not
returned at all.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._assess import DesignReport, assess_design, predict_segments
from ._bench_limits import (CURRENT_MARGIN, SPEED_FRACTION, TORQUE_MARGIN, VOLTAGE_FRACTION, margin_problems,
                            min_durations, speed_limit)
from ._design_space import _AXES, Spec, _Param, build_param, free_durations, infer_waveforms
from ..errors import DrivecalError, PlanError
from ..model import Experiment, predict_currents, simulate_states
from ..identify import assess_identifiability, sensitivity_jacobian
from ..physics import ESTIMATED, MotorParams
from ..plan import Plan
from ..results import solver_code, solver_message

#: Peak current, speed and clamp torque are pushed to at most this fraction of the plan margins' limits
#: (CURRENT_MARGIN of the current limit, SPEED_FRACTION of the speed limit, TORQUE_MARGIN of max_torque) in
#: the smooth problem.
LIMIT_MARGIN = 0.995
#: Where the input plan is shorter than the plan margins' least durations and no budget is given, the budget
#: becomes this many times their sum, room for the durations to move.
BUDGET_ROOM = 1.2
#: The peak's window falls this many times faster than the Fisher window (one sample period).
PEAK_WINDOW_SHARPNESS = 2.0
#: Exponent of the smooth minimum that scales a segment's voltage down to its limits (-).
SCALE_SHARPNESS = 32.0
#: Sharpness of the soft maximum of |i| and |w_m| over samples (per unit of the limit).
SOFTMAX_SHARPNESS = 200.0



# ----------------------------------------------------------------------------------------------
# The smooth problem
# ----------------------------------------------------------------------------------------------


def _soft_peak(x, log_window, limit):
    """Soft maximum of ``x`` (>= 0) over the last axis inside the window (a softmax-weighted mean, <= max)."""
    weights = jax.nn.softmax(SOFTMAX_SHARPNESS * x / limit + log_window, axis=-1)
    return jnp.sum(weights * x, axis=-1)


def _objective_fn(par: _Param, motor: MotorParams, names: tuple[str, ...]):
    """The smooth problem: ``(objective(u, args), scales(u))``.

    ``objective`` is ``-log det F`` plus the limit penalties, with ``F`` the
    windowed Fisher matrix per sigma^2 in relative units (``J = dI/d ln theta``).
    ``scales`` (S,) is the factor each segment's voltage gets so its peak current
    (and, when free, its speed) stays under the limits: a smooth minimum of 1 and
    ``limit / peak``, exact for locked segments (linear in the voltage from rest),
    first order for free ones (the penalty takes the rest).
    """
    plan = par.plan
    fs, s_count, grid = plan.sample_rate, len(plan.segments), par.grid
    template = Experiment.from_segments([np.zeros((grid, 2))] * s_count, [seg.locked for seg in plan.segments],
                                        plan.sample_period)
    theta0 = motor.vector(names)
    free_rotor = jnp.asarray([0.0 if seg.locked else 1.0 for seg in plan.segments])
    t_mid = (jnp.arange(grid) + 0.5) / fs
    i_lim, w_lim = CURRENT_MARGIN * float(plan.current_limit), SPEED_FRACTION * speed_limit(plan, motor)
    t_lim = math.inf if plan.max_torque is None else TORQUE_MARGIN * float(plan.max_torque)
    locked_rotor = 1.0 - free_rotor
    kt = 1.5 * float(motor.pole_pairs) * float(motor.lambda_m)  # torque per i_q (N*m/A)
    kr = 1.5 * float(motor.pole_pairs) * (float(motor.Ld) - float(motor.Lq))  # per i_d * i_q (N*m/A^2)

    def experiment(volts):
        return dataclasses.replace(template, voltages=volts.reshape(s_count * grid, 2))

    def peaks(states, log_window):
        magnitude = jnp.sqrt(states[:, 0] ** 2 + states[:, 1] ** 2 + 1e-12).reshape(s_count, grid)
        speed = jnp.abs(states[:, 2]).reshape(s_count, grid)
        torque = jnp.sqrt((kt * states[:, 1] + kr * states[:, 0] * states[:, 1]) ** 2 + 1e-12).reshape(s_count, grid)
        torque_peak = _soft_peak(torque, log_window, t_lim) if math.isfinite(t_lim) else jnp.zeros(s_count)
        return _soft_peak(magnitude, log_window, i_lim), _soft_peak(speed, log_window, w_lim), torque_peak

    def scaled(u):
        durations = par.durations(u)
        log_window = jax.nn.log_sigmoid((durations[:, None] - t_mid) * fs)  # tau = one sample period
        # The inverter stops at the segment's end (smoothly, on the window), so a
        # rising current is not seen rising on past it.
        raw = par.voltages(u, durations) * jnp.exp(log_window)[..., None]
        inside = jax.nn.log_sigmoid((durations[:, None] - t_mid) * fs * PEAK_WINDOW_SHARPNESS)
        peak_i, peak_w, peak_t = peaks(simulate_states(motor, experiment(raw)), inside)
        over = (peak_i / (LIMIT_MARGIN * i_lim)) ** SCALE_SHARPNESS + free_rotor * (
            peak_w / (LIMIT_MARGIN * w_lim)) ** SCALE_SHARPNESS
        if math.isfinite(t_lim):
            over = over + locked_rotor * (peak_t / (LIMIT_MARGIN * t_lim)) ** SCALE_SHARPNESS
        scales = (1.0 + over) ** (-1.0 / SCALE_SHARPNESS)
        return scales, raw * scales[:, None, None], log_window

    def objective(u, _args):
        _, volts, log_window = scaled(u)
        exp = experiment(volts)

        def currents(z):
            return predict_currents(motor.with_vector(names, theta0 * jnp.exp(z)), exp).reshape(-1)

        jac = jax.jacfwd(currents)(jnp.zeros(len(names)))  # (2 * S * grid, n)
        weight = jnp.repeat(jnp.exp(log_window).reshape(-1), 2)
        fisher = jnp.einsum("mp,m,mq->pq", jac, weight, jac)
        return -2.0 * jnp.sum(jnp.log(jnp.diag(jnp.linalg.cholesky(fisher))))

    return _forward_gradient(objective), jax.jit(lambda u: scaled(u)[0])


def _forward_gradient(objective):
    """``objective(u, args)`` whose reverse-mode gradient is computed in forward mode.

    Few design variables, a long scan: forward mode over the sensitivity
    ``jacfwd`` (one sweep, all directions together) is several times faster
    than reverse mode through the scan, so the VJP reuses it.
    """

    def value_and_grad(u):
        basis = jnp.eye(u.shape[-1], dtype=u.dtype)
        return jax.vmap(lambda t: jax.jvp(lambda x: objective(x, None), (u,), (t,)), out_axes=(None, 0))(basis)

    @jax.custom_vjp
    def value(u):
        return objective(u, None)

    def value_bwd(grad, cotangent):
        return (cotangent * grad,)

    value.defvjp(value_and_grad, value_bwd)
    return lambda u, _args: value(u)


# ----------------------------------------------------------------------------------------------
# Exact evaluation
# ----------------------------------------------------------------------------------------------


def predicted_covariance(plan: Plan, motor: MotorParams, *, noise_sigma: float = 0.02,
                         names: tuple[str, ...] = ESTIMATED) -> np.ndarray:
    """``sigma^2 (J^T J)^-1`` (SI units), shape (n, n), of the plan on the nominal motor."""
    jac = np.asarray(sensitivity_jacobian(motor, Experiment.from_plan(plan), names))
    theta = np.asarray(motor.vector(names))
    js = jac * theta
    return noise_sigma**2 * np.linalg.inv(js.T @ js) * np.outer(theta, theta)


def _log_det(cov: np.ndarray) -> float:
    sign, value = np.linalg.slogdet(cov)
    return float(value) if sign > 0 else math.inf


def _repair(par: _Param, u: np.ndarray, scales: np.ndarray, motor: MotorParams) -> tuple[Plan, dict]:
    """The exact plan for ``u`` and segment ``scales``, each segment scaled down further until its
    exact peaks are inside the plan margins' limits (:func:`~drivecal.design.margin_problems`)."""
    i_lim, w_lim = CURRENT_MARGIN * float(par.plan.current_limit), SPEED_FRACTION * speed_limit(par.plan, motor)
    t_lim = math.inf if par.plan.max_torque is None else TORQUE_MARGIN * float(par.plan.max_torque)
    for _ in range(12):
        plan, specs = par.to_plan(u, scales)
        factors = np.ones(len(scales))
        for s, pred in enumerate(predict_segments(plan, motor)):
            if not pred.finite:
                factors[s] = 0.5
                continue
            if pred.peak_current > i_lim:
                factors[s] = min(factors[s], 0.999 * i_lim / pred.peak_current)
            if not pred.locked and pred.peak_speed > w_lim:
                factors[s] = min(factors[s], 0.999 * w_lim / pred.peak_speed)
            if pred.locked and pred.peak_torque > t_lim:
                factors[s] = min(factors[s], 0.999 * t_lim / pred.peak_torque)
        if np.all(factors == 1.0):
            return plan, specs
        scales = scales * factors
    return plan, specs


@dataclasses.dataclass(frozen=True)
class OptimalDesign:
    """A plan before and after D-optimal improvement, judged exactly on the nominal motor.

    Attributes:
        names: the estimated parameters, in order.
        plan_before, plan_after: the input plan and the improved one (the input
            itself when no better feasible plan was found).
        waveforms_before, waveforms_after: per ``(segment name, axis)``, the waveform
            spec (a float for a constant, V; else a plan-file table in SI units),
            for :func:`drivecal.config.write_plan`.
        report_before, report_after: :func:`drivecal.design.assess_design` of each plan.
        budget: total duration of the improved plan (s).
        noise_sigma: sensor noise assumed for the predictions (A).
        se_before, se_after: predicted standard errors (units of each parameter), shape (n,).
        ci95_before, ci95_after: predicted 95 % CI half-widths, shape (n,).
        covariance_before, covariance_after: predicted covariance (SI), shape (n, n).
        logdet_before, logdet_after: ``log det`` of those covariances (natural log).
        iterations: BFGS steps taken.
        converged: the optimiser met its tolerance (the plan is used either way if better).
        improved: the returned plan is better than the input. When it is not, ``plan_after is plan_before``
            where the input holds the plan margins; an input that breaks them gives the best plan that holds
            them, even at a larger confidence volume (``message`` says so).
        message: how the optimisation ended, in words.
    """

    names: tuple[str, ...]
    plan_before: Plan
    plan_after: Plan
    waveforms_before: dict
    waveforms_after: dict
    report_before: DesignReport
    report_after: DesignReport
    budget: float
    noise_sigma: float
    se_before: np.ndarray
    se_after: np.ndarray
    ci95_before: np.ndarray
    ci95_after: np.ndarray
    covariance_before: np.ndarray
    covariance_after: np.ndarray
    logdet_before: float
    logdet_after: float
    iterations: int
    converged: bool
    improved: bool
    message: str

    @property
    def det_ratio(self) -> float:
        """``det Cov_after / det Cov_before``."""
        return math.exp(self.logdet_after - self.logdet_before)

    @property
    def volume_ratio(self) -> float:
        """Confidence-ellipsoid volume after / before, ``sqrt(det ratio)``."""
        return math.exp(0.5 * (self.logdet_after - self.logdet_before))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the plans as segment lists, the predictions per parameter)."""
        def plan_dict(plan: Plan, specs: dict, report: DesignReport) -> dict:
            return {
                "total_duration": sum(s.duration for s in plan.segments),
                "num_samples": plan.num_samples,
                "segments": [
                    {"name": s.name, "duration": s.duration, "locked": s.locked,
                     "v_d": _spec_json(specs[(s.name, "v_d")]), "v_q": _spec_json(specs[(s.name, "v_q")]),
                     "peak_current": p.peak_current, "peak_speed": p.peak_speed}
                    for s, p in zip(plan.segments, report.segments)
                ],
                "feasible": report.feasible,
                "identifiable": report.identifiability.identifiable,
                "condition_number": report.identifiability.condition_number,
            }

        return {
            "names": list(self.names),
            "budget": self.budget,
            "noise_sigma": self.noise_sigma,
            "before": plan_dict(self.plan_before, self.waveforms_before, self.report_before),
            "after": plan_dict(self.plan_after, self.waveforms_after, self.report_after),
            "predicted": {
                n: {"se_before": float(self.se_before[i]), "se_after": float(self.se_after[i]),
                    "ci95_half_width_before": float(self.ci95_before[i]),
                    "ci95_half_width_after": float(self.ci95_after[i]),
                    "ratio": float(self.ci95_after[i] / self.ci95_before[i])}
                for i, n in enumerate(self.names)
            },
            "logdet_covariance_before": self.logdet_before,
            "logdet_covariance_after": self.logdet_after,
            "det_ratio": self.det_ratio,
            "volume_ratio": self.volume_ratio,
            "iterations": self.iterations,
            "converged": self.converged,
            "improved": self.improved,
            "message": self.message,
        }


def _spec_json(spec: Spec) -> Any:
    if not isinstance(spec, dict):
        return float(spec)
    if spec.get("kind") == "samples":
        return {"kind": "samples", "num_values": len(spec["values"])}
    return dict(spec)


def _ci(report: DesignReport) -> tuple[np.ndarray, np.ndarray]:
    ident = report.identifiability
    return np.asarray(ident.predicted_se, dtype=float), np.asarray(ident.predicted_ci95, dtype=float)


def optimize_plan(
    plan: Plan,
    motor: MotorParams,
    *,
    waveforms_spec: dict | None = None,
    budget: float | None = None,
    noise_sigma: float = 0.02,
    names: tuple[str, ...] = ESTIMATED,
    max_steps: int = 150,
) -> OptimalDesign:
    """Improve ``plan`` for the smallest predicted confidence volume on the nominal ``motor``.

    Args:
        plan: the plan to improve; its segments' structure (order, locked or
            free, which axis carries which waveform kind) is kept.
        motor: nominal motor (datasheet values).
        waveforms_spec: per ``(segment name, axis)`` the waveform spec, as
            :func:`load_plan_waveforms` returns; default :func:`infer_waveforms`
            (constants, or per-sample sequences that only get a gain).
        budget: total duration (s) of the improved plan; default the input's, or
            :data:`BUDGET_ROOM` times the least durations the margins need where the input is shorter.
        noise_sigma: sensor noise (A) for the predicted intervals (it scales
            every interval alike and does not change the optimum).
        names: parameters to estimate.
        max_steps: BFGS steps at most.

    Raises:
        DrivecalError: the plan cannot identify some parameter whatever its
            amplitudes (a structural gap), or the budget is unusable.
    """
    plan.check_feasible()
    specs = infer_waveforms(plan) if waveforms_spec is None else dict(waveforms_spec)
    missing = [(s.name, a) for s in plan.segments for a in _AXES if (s.name, a) not in specs]
    if missing:
        raise DrivecalError(f"no waveform spec for {missing[0][0]!r} {missing[0][1]}; pass one for every axis.")
    total = sum(s.duration for s in plan.segments)
    if budget is not None and not (budget > 0 and math.isfinite(budget)):
        raise DrivecalError(f"budget must be a positive number of seconds, got {budget!r}.")
    least = min_durations(plan, motor)
    free = free_durations(plan, specs)
    need = sum(s.duration for s, f in zip(plan.segments, free) if not f) + float(least[free].sum())
    raised = ""
    if budget is None and total < need * (1 - 1e-9):  # the input breaks the margins' durations: room to hold them
        budget = BUDGET_ROOM * need
        raised = (f"budget raised from {total:.4g} s to {budget:.4g} s: the plan margins' least durations "
                  f"(200 samples a segment, 3 electrical time constants a locked step) need {need:.4g} s")
    budget = total if budget is None else float(budget)
    ident = assess_identifiability(Experiment.from_plan(plan), motor, noise_sigma=noise_sigma, names=names)
    gaps = ident.dead_params + ident.confounded_params
    if gaps:
        raise DrivecalError(f"the plan cannot identify {', '.join(gaps)} ({'; '.join(ident.reasons[n] for n in gaps)}), "
                            "whatever its amplitudes; change its segments before optimising.")
    report_before = assess_design(plan, motor, noise_sigma=noise_sigma, names=names)
    cov_before = predicted_covariance(plan, motor, noise_sigma=noise_sigma, names=names)
    logdet_before = _log_det(cov_before)

    par = build_param(plan, specs, budget, least, VOLTAGE_FRACTION)
    objective, scales = _objective_fn(par, motor, names)
    import optimistix as optx  # only optimising needs it (~0.35 s to import)

    solver = optx.BFGS(rtol=1e-3, atol=1e-3)
    sol = optx.minimise(objective, solver, jnp.asarray(par.u0), max_steps=max_steps, throw=False)
    u = np.asarray(sol.value)
    iterations = int(sol.stats["num_steps"])
    converged = bool(sol.result == optx.RESULTS.successful)
    message = "converged" if converged else (solver_message(solver_code(sol.result)) or "stopped")
    if raised:
        message = f"{raised}; {message}"
    # An input outside the plan margins is not kept: the result holds them even at a larger volume.
    input_kept = report_before.ok and not margin_problems(report_before, motor) and not raised

    try:
        candidate, cand_specs = _repair(par, u, np.asarray(scales(jnp.asarray(u))), motor)
        report_after = assess_design(candidate, motor, noise_sigma=noise_sigma, names=names)
        cov_after = predicted_covariance(candidate, motor, noise_sigma=noise_sigma, names=names)
        logdet_after = _log_det(cov_after)
        usable = report_after.ok and (logdet_after < logdet_before or not input_kept)
    except PlanError as exc:  # e.g. a band the exact waveform generator refuses
        usable, message = False, f"{message}; the rounded plan was refused: {exc}"
    if not usable:
        if not input_kept or abs(budget - total) * plan.sample_rate >= 0.5:
            raise DrivecalError(f"no feasible, identifiable plan better than the input was found within "
                                f"{budget:g} s; lower the plan's amplitudes, change its segments or its budget.")
        candidate, cand_specs, report_after, cov_after, logdet_after = (
            plan, specs, report_before, cov_before, logdet_before)
        message += "; no better feasible plan found, the input is kept"
    se_b, ci_b = _ci(report_before)
    se_a, ci_a = _ci(report_after)
    return OptimalDesign(
        names=tuple(names), plan_before=plan, plan_after=candidate, waveforms_before=specs,
        waveforms_after=cand_specs, report_before=report_before, report_after=report_after,
        budget=sum(s.duration for s in candidate.segments), noise_sigma=float(noise_sigma),
        se_before=se_b, se_after=se_a, ci95_before=ci_b, ci95_after=ci_a,
        covariance_before=cov_before, covariance_after=cov_after, logdet_before=logdet_before,
        logdet_after=logdet_after, iterations=iterations, converged=converged,
        improved=usable and logdet_after < logdet_before, message=message,
    )
