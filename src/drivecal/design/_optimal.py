"""D-optimal design: improve a plan's amplitudes, durations and bands before bench time.

The predicted covariance of the estimates is ``Cov = sigma^2 (J^T J)^-1`` with
``J = d(i_d, i_q at every sample) / d ln(theta)`` on the nominal motor (the same
Jacobian ``identify`` and ``fit`` use). A D-optimal plan minimises ``log det Cov``,
i.e. the volume of the confidence ellipsoid, subject to

* the voltage circle ``|v_dq| <= v_dc / sqrt(3)`` (held by construction: every
  waveform is a bounded map of unconstrained variables),
* the plan's current limit on the predicted peak ``|i_dq|`` of every segment and,
  on free segments, a speed limit (``max_speed``, the no-load speed the voltage
  circle allows, and the RK4 step bound) (smooth quadratic penalties),
* a time budget: the durations are fractions of the budget (softmax).

The structure of the plan is kept: which segments are locked or free, which
axis carries which waveform kind. What moves is the waveform's level (step),
amplitude and offset (chirp, multisine, PRBS), its band (chirp f_start/f_stop,
multisine f_min/f_max), a gain (measured sequences) and the durations.

To differentiate through the durations, each segment is simulated on a fixed,
maximal sample grid and each sample's Fisher contribution is weighted by a
smooth window ``sigmoid((T_s - t_k) / tau)``. ``log det`` of the windowed
Fisher matrix is minimised with optimistix's BFGS, its gradient taken by
``jax.grad`` through ``jax.jacfwd`` of the forward model. The result is then
rounded to whole samples, built with the plan-file waveform generators, scaled
down where the exact simulation still touches a limit, and judged exactly with
:func:`drivecal.design.assess_design`. A plan that is not better than its input
is never returned as an improvement.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..plan import waveforms
from ._assess import MAX_ELECTRICAL_STEP, DesignReport, assess_design, predict_segments
from ..errors import DrivecalError, PlanError
from ..model import Experiment, predict_currents, simulate_states
from ..identify import assess_identifiability, sensitivity_jacobian
from ..physics import ESTIMATED, MotorParams
from ..plan import Plan, Segment

#: A waveform spec: ``{"kind": "chirp", "amplitude": 6.0, ...}`` (SI), or a float for a constant (V).
Spec = Any
_AXES = ("v_d", "v_q")
#: Band limits for chirps and multisines (Hz; the upper one as a fraction of the sample rate).
F_LOW, F_HIGH_FRACTION = 1.0, 0.45
#: Shortest segment, as a fraction of the budget shared equally (s / s).
MIN_DURATION_FRACTION = 0.1
#: Peak current and speed are pushed to at most this fraction of their limits in the smooth problem.
LIMIT_MARGIN = 0.995
#: The peak's window falls this many times faster than the Fisher window (one sample period).
PEAK_WINDOW_SHARPNESS = 2.0
#: Exponent of the smooth minimum that scales a segment's voltage down to its limits (-).
SCALE_SHARPNESS = 32.0
#: Sharpness of the soft maximum of |i| and |w_m| over samples (per unit of the limit).
SOFTMAX_SHARPNESS = 200.0


# ----------------------------------------------------------------------------------------------
# Waveform specs
# ----------------------------------------------------------------------------------------------


def _infer_spec(values: Any) -> Spec:
    arr = np.asarray(values, dtype=float)
    if arr.ndim == 0:
        return float(arr)
    if arr.size and np.all(arr == arr[0]):
        return float(arr[0])
    return {"kind": "samples", "values": [float(v) for v in arr]}


def infer_waveforms(plan: Plan) -> dict[tuple[str, str], Spec]:
    """Waveform specs of a plan built in Python: constants stay constants, sequences become ``samples``."""
    return {(seg.name, axis): _infer_spec(getattr(seg, axis)) for seg in plan.segments for axis in _AXES}


def load_plan_waveforms(path: str | Path) -> tuple[Plan, dict[tuple[str, str], Spec]]:
    """A checked plan file and its waveform specs, per ``(segment name, "v_d" | "v_q")``.

    Constants are floats (V); chirp, multisine, PRBS and step tables are dicts
    in SI units; a measured sequence (inline or from a CSV file) is a
    ``samples`` dict with its values.
    """
    from ..plan import PlanSpec, SamplesSpec, load_plan, read_toml

    plan = load_plan(path)
    spec = PlanSpec.model_validate(read_toml(path))
    out = {}
    for seg_spec, seg in zip(spec.segment, plan.segments):
        for axis in _AXES:
            value = getattr(seg_spec, axis)
            if isinstance(value, float) or isinstance(value, SamplesSpec):
                out[(seg.name, axis)] = _infer_spec(getattr(seg, axis))
            else:
                out[(seg.name, axis)] = value.model_dump()
    return plan, out


def _generate(spec: Spec, n: int, sample_rate: float) -> np.ndarray | float:
    if not isinstance(spec, dict):
        return float(spec)
    params = {k: v for k, v in spec.items() if k != "kind" and v is not None}
    return waveforms.GENERATORS[spec["kind"]](n, sample_rate, **params)


# ----------------------------------------------------------------------------------------------
# The parametrisation: unconstrained u -> feasible waveforms and durations
# ----------------------------------------------------------------------------------------------


def _logit(p: float) -> float:
    p = min(max(p, 1e-3), 1.0 - 1e-3)
    return math.log(p / (1.0 - p))


def _amp_offset(peak, phi):
    """``(amplitude, offset)`` with ``amplitude + |offset| = peak`` exactly, smooth in phi."""
    s = jnp.sin(phi)
    return peak * jnp.cos(phi) ** 2, peak * s * jnp.abs(s)


def _phi0(amplitude: float, offset: float) -> float:
    peak = amplitude + abs(offset)
    if offset == 0.0 or peak == 0.0:
        # A sign flip of the whole waveform leaves a locked segment's Fisher matrix
        # unchanged, so zero offset is a stationary point: start slightly off it.
        return 0.2
    return math.copysign(math.asin(math.sqrt(abs(offset) / peak)), offset)


@dataclasses.dataclass(frozen=True)
class _Axis:
    """How one (segment, axis) waveform is parametrised (static)."""

    kind: str  # zero, constant, step, chirp, multisine, prbs, samples
    start: int  # first entry in u
    size: int
    bound: float  # peak |v| bound on this axis (V)
    spec: Spec  # the input spec (static fields are read from it)
    pattern: np.ndarray | None = None  # prbs (+-1) or samples (V) on the grid


@dataclasses.dataclass(frozen=True)
class _Param:
    """The design space of one plan: static layout, initial point, and its maps."""

    plan: Plan
    axes: tuple[tuple[_Axis, _Axis], ...]  # per segment (v_d, v_q)
    free_duration: tuple[bool, ...]  # per segment
    duration_start: int  # index of the first duration logit in u
    u0: np.ndarray
    budget: float  # total duration (s)
    fixed_time: float  # time of the fixed-duration segments (s)
    min_duration: float  # shortest free segment (s)
    grid: int  # samples per segment on the maximal grid

    @property
    def sample_rate(self) -> float:
        return self.plan.sample_rate

    def _f_high(self) -> float:
        return F_HIGH_FRACTION * self.sample_rate

    def durations(self, u):
        """Segment durations (s), shape (S,); free ones sum to the budget left by the fixed ones."""
        free = np.array(self.free_duration)
        fixed = np.array([seg.duration for seg in self.plan.segments])
        k = int(free.sum())
        if k == 0:
            return jnp.asarray(fixed)
        share = jax.nn.softmax(u[self.duration_start : self.duration_start + k])
        spare = self.budget - self.fixed_time - k * self.min_duration
        free_t = self.min_duration + spare * share
        idx = np.cumsum(free) - 1
        return jnp.where(free, free_t[np.clip(idx, 0, k - 1)], fixed)

    def _freq(self, v):
        return F_LOW * (self._f_high() / F_LOW) ** jax.nn.sigmoid(v)

    def waveform_params(self, u, ax: _Axis) -> dict:
        """The waveform's free numbers (SI) for unconstrained ``u`` (traceable)."""
        p = u[ax.start : ax.start + ax.size]
        if ax.kind in ("zero",):
            return {}
        if ax.kind in ("constant", "step"):
            return {"peak": ax.bound * jax.nn.sigmoid(p[0])}
        if ax.kind == "samples":
            return {"gain": ax.bound * jax.nn.sigmoid(p[0])}
        amplitude, offset = _amp_offset(ax.bound * jax.nn.sigmoid(p[0]), p[1])
        out = {"amplitude": amplitude, "offset": offset}
        if ax.kind == "chirp":
            out.update(f_start=self._freq(p[2]), f_stop=self._freq(p[3]))
        elif ax.kind == "multisine":
            f_min = self._freq(p[2])
            out.update(f_min=f_min, f_max=f_min * (self._f_high() / f_min) ** jax.nn.sigmoid(p[3]))
        return out

    def voltage(self, u, ax: _Axis, duration):
        """The axis voltage (V) on the maximal grid, shape (grid,), for a segment of ``duration`` (s)."""
        fs = self.sample_rate
        t = jnp.arange(self.grid) / fs
        q = self.waveform_params(u, ax)
        spec = ax.spec
        if ax.kind == "zero":
            return jnp.zeros(self.grid)
        if ax.kind == "constant":
            return jnp.full(self.grid, math.copysign(1.0, spec) * q["peak"])
        if ax.kind == "step":
            scale = max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
            level, initial = spec["level"] / scale, spec.get("initial", 0.0) / scale
            delay = spec.get("delay", 0.0)
            return q["peak"] * jnp.where(t >= delay - 0.5 / fs, level, initial)
        if ax.kind == "samples":
            return q["gain"] * jnp.asarray(ax.pattern)
        if ax.kind == "prbs":
            return q["offset"] + q["amplitude"] * jnp.asarray(ax.pattern)
        if ax.kind == "chirp":
            f0, f1 = q["f_start"], q["f_stop"]
            if spec.get("sweep", "linear") == "log":
                k = jnp.log(f1 / f0) / duration
                safe_k = jnp.where(jnp.abs(k) > 1e-9, k, 1.0)
                phi = jnp.where(jnp.abs(k) > 1e-9, 2 * jnp.pi * f0 * jnp.expm1(safe_k * t) / safe_k,
                                2 * jnp.pi * f0 * t)
            else:
                phi = 2 * jnp.pi * (f0 * t + 0.5 * (f1 - f0) / duration * t**2)
            return q["offset"] + q["amplitude"] * jnp.sin(phi + spec.get("phase", 0.0))
        if ax.kind == "multisine":
            # Smooth stand-in: log-spaced tones at continuous frequencies with Schroeder
            # phases; the exact plan puts them on harmonics of 1/duration.
            count = int(spec.get("num_tones", 16))
            freqs = jnp.exp(jnp.linspace(jnp.log(q["f_min"]), jnp.log(q["f_max"]), count))
            phases = -jnp.pi * np.arange(1, count + 1) * np.arange(count) / count
            signal = jnp.sin(2 * jnp.pi * t[:, None] * freqs + phases).sum(axis=1)
            inside = t < duration
            peak = jnp.max(jnp.where(inside, jnp.abs(signal), 0.0))
            return q["offset"] + q["amplitude"] * signal / peak
        raise AssertionError(ax.kind)

    def voltages(self, u, durations):
        """All segments on the maximal grid, ``[v_d, v_q]`` (V), shape (S, grid, 2)."""
        return jnp.stack([jnp.stack([self.voltage(u, ax, durations[s]) for ax in pair], axis=-1)
                          for s, pair in enumerate(self.axes)])

    def to_plan(self, u: np.ndarray, scales: np.ndarray | None = None) -> tuple[Plan, dict]:
        """The exact plan for ``u``: whole samples (total kept), plan-file waveforms; ``scales`` per segment."""
        fs = self.sample_rate
        durations = np.asarray(self.durations(jnp.asarray(u)))
        counts = _round_counts(durations, fs, np.array(self.free_duration))
        scales = np.ones(len(self.axes)) if scales is None else scales
        segments, specs = [], {}
        for s, (seg, pair) in enumerate(zip(self.plan.segments, self.axes)):
            n = int(counts[s])
            values = {}
            for axis, ax in zip(_AXES, pair):
                spec = self._exact_spec(u, ax, n, scales[s])
                values[axis] = _generate(spec, n, fs)
                specs[(seg.name, axis)] = spec
            segments.append(Segment(seg.name, n / fs, seg.locked, v_d=values["v_d"], v_q=values["v_q"]))
        plan = dataclasses.replace(self.plan, segments=tuple(segments))
        return plan, specs

    def _exact_spec(self, u, ax: _Axis, n: int, scale: float) -> Spec:
        q = {k: float(v) for k, v in self.waveform_params(jnp.asarray(u), ax).items()}
        spec = ax.spec
        scale = float(scale)
        if ax.kind == "zero":
            return 0.0
        if ax.kind == "constant":
            return math.copysign(1.0, spec) * q["peak"] * scale
        if ax.kind == "samples":
            return {"kind": "samples", "values": [float(v) for v in q["gain"] * scale * ax.pattern[:n]]}
        if ax.kind == "step":
            norm = max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
            out = dict(spec, level=spec["level"] / norm * q["peak"] * scale,
                       initial=spec.get("initial", 0.0) / norm * q["peak"] * scale)
            return out
        out = dict(spec, amplitude=q["amplitude"] * scale, offset=q["offset"] * scale)
        if ax.kind == "chirp":
            out.update(f_start=q["f_start"], f_stop=q["f_stop"])
        elif ax.kind == "multisine":
            base = self.sample_rate / n
            f_max = max(q["f_max"], q["f_min"] + 2.0 * base)
            if f_max >= self.sample_rate / 2:
                f_max = 0.49 * self.sample_rate
            out.update(f_min=q["f_min"], f_max=f_max)
        return {k: v for k, v in out.items() if v is not None}


def _round_counts(durations: np.ndarray, fs: float, free: np.ndarray) -> np.ndarray:
    """Whole samples per segment; the free segments' total is kept (largest remainders)."""
    exact = durations * fs
    counts = np.round(exact).astype(int)
    if free.any():
        total = int(round(exact[free].sum()))
        base = np.floor(exact[free]).astype(int)
        order = np.argsort(-(exact[free] - base))
        base[order[: total - base.sum()]] += 1
        counts[free] = base
    return counts


def _axis_kind(spec: Spec) -> str:
    if not isinstance(spec, dict):
        return "zero" if float(spec) == 0.0 else "constant"
    return spec["kind"]


def _peak_of(spec: Spec) -> float:
    if not isinstance(spec, dict):
        return abs(float(spec))
    if spec["kind"] == "step":
        return max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
    if spec["kind"] == "samples":
        return float(np.max(np.abs(spec["values"]))) if len(spec["values"]) else 0.0
    return abs(spec.get("amplitude", 0.0)) + abs(spec.get("offset", 0.0))


def _build_param(plan: Plan, specs: dict, budget: float) -> _Param:
    fs = plan.sample_rate
    limit = plan.voltage_limit
    segs = plan.segments
    free = tuple(not any(_axis_kind(specs[(s.name, a)]) == "samples" for a in _AXES) for s in segs)
    fixed_time = sum(s.duration for s, f in zip(segs, free) if not f)
    k = sum(free)
    if k and budget - fixed_time <= 0:
        raise DrivecalError(f"budget {budget:g} s leaves no time beside the {fixed_time:g} s of measured-sequence "
                            "segments (whose duration is fixed); raise --budget.")
    min_duration = MIN_DURATION_FRACTION * (budget - fixed_time) / max(k, 1)
    if k and min_duration * fs < 2:
        raise DrivecalError(f"budget {budget:g} s is too short for {k} segments at {fs:g} Hz; raise --budget.")
    longest = max([budget - fixed_time - (k - 1) * min_duration] * bool(k)
                  + [s.duration for s, f in zip(segs, free) if not f])
    grid = int(math.ceil(longest * fs)) + 2
    old_total = sum(s.duration for s, f in zip(segs, free) if f)
    stretch = (budget - fixed_time) / old_total if k else 1.0

    u0, axes, start = [], [], 0
    for seg in segs:
        peaks = np.array([_peak_of(specs[(seg.name, a)]) for a in _AXES])
        # Per-axis bounds on the voltage circle, in the input's proportion (a box inside the circle).
        norm = math.hypot(*peaks)
        bounds = limit * peaks / norm if norm > 0 else np.full(2, limit)
        pair = []
        for a, axis in enumerate(_AXES):
            spec = specs[(seg.name, axis)]
            kind = _axis_kind(spec)
            bound = float(bounds[a]) if kind != "samples" else float(bounds[a]) / max(peaks[a], 1e-300)
            pattern, init = None, []
            if kind in ("constant", "step"):
                init = [_logit(peaks[a] / bounds[a])]
            elif kind == "samples":
                pattern = np.zeros(grid)
                pattern[: len(spec["values"])] = spec["values"]
                init = [_logit(1.0 / (bound * 1.0))]  # gain 1 reproduces the input
            elif kind in ("chirp", "multisine", "prbs"):
                amplitude, offset = abs(spec["amplitude"]), spec.get("offset", 0.0)
                init = [_logit(peaks[a] / bounds[a]), _phi0(amplitude, offset)]
                if kind == "chirp":
                    init += [_logit(math.log(f / F_LOW) / math.log(F_HIGH_FRACTION * fs / F_LOW))
                             for f in (spec["f_start"], spec["f_stop"])]
                elif kind == "multisine":
                    f_hi = F_HIGH_FRACTION * fs
                    f_min, f_max = spec["f_min"], min(spec["f_max"], 0.999 * f_hi)
                    init += [_logit(math.log(f_min / F_LOW) / math.log(f_hi / F_LOW)),
                             _logit(math.log(f_max / f_min) / math.log(f_hi / f_min))]
                elif kind == "prbs":
                    params = {k_: v for k_, v in spec.items() if k_ not in ("kind", "amplitude", "offset")}
                    pattern = waveforms.prbs(grid, fs, amplitude=1.0, **params)
            pair.append(_Axis(kind=kind, start=start, size=len(init), bound=bound, spec=spec, pattern=pattern))
            u0 += init
            start += len(init)
        axes.append(tuple(pair))
    duration_start = start
    for seg, f in zip(segs, free):
        if f:
            u0.append(math.log(max(seg.duration * stretch - min_duration, 1e-3 * min_duration)))
    return _Param(plan=plan, axes=tuple(axes), free_duration=free, duration_start=duration_start,
                  u0=np.asarray(u0, dtype=float), budget=float(budget), fixed_time=float(fixed_time),
                  min_duration=float(min_duration), grid=grid)


# ----------------------------------------------------------------------------------------------
# The smooth problem
# ----------------------------------------------------------------------------------------------


def speed_limit(plan: Plan, motor: MotorParams) -> float:
    """Highest mechanical speed (rad/s) a free segment may reach: ``max_speed``, the no-load
    speed ``v_dc/sqrt(3) / (p * lambda_m)`` and the RK4 bound of ``design`` (rad per sample)."""
    p = float(motor.pole_pairs)
    limits = [plan.voltage_limit / (p * float(motor.lambda_m)), MAX_ELECTRICAL_STEP * plan.sample_rate / p]
    if plan.max_speed is not None:
        limits.append(float(plan.max_speed))
    return min(limits)


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
    i_lim, w_lim = float(plan.current_limit), speed_limit(plan, motor)

    def experiment(volts):
        return eqx.tree_at(lambda e: e.voltages, template, volts.reshape(s_count * grid, 2))

    def peaks(states, log_window):
        magnitude = jnp.sqrt(states[:, 0] ** 2 + states[:, 1] ** 2 + 1e-12).reshape(s_count, grid)
        speed = jnp.abs(states[:, 2]).reshape(s_count, grid)
        return _soft_peak(magnitude, log_window, i_lim), _soft_peak(speed, log_window, w_lim)

    def scaled(u):
        durations = par.durations(u)
        log_window = jax.nn.log_sigmoid((durations[:, None] - t_mid) * fs)  # tau = one sample period
        # The inverter stops at the segment's end (smoothly, on the window), so a
        # rising current is not seen rising on past it.
        raw = par.voltages(u, durations) * jnp.exp(log_window)[..., None]
        inside = jax.nn.log_sigmoid((durations[:, None] - t_mid) * fs * PEAK_WINDOW_SHARPNESS)
        peak_i, peak_w = peaks(simulate_states(motor, experiment(raw)), inside)
        over = (peak_i / (LIMIT_MARGIN * i_lim)) ** SCALE_SHARPNESS + free_rotor * (
            peak_w / (LIMIT_MARGIN * w_lim)) ** SCALE_SHARPNESS
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
    exact peaks are inside the limits."""
    i_lim, w_lim = float(par.plan.current_limit), speed_limit(par.plan, motor)
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
        improved: the returned plan is better than the input (else ``plan_after is plan_before``).
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
        budget: total duration (s) of the improved plan; default the input's.
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
    budget = total if budget is None else float(budget)
    if not (budget > 0 and math.isfinite(budget)):
        raise DrivecalError(f"budget must be a positive number of seconds, got {budget!r}.")
    ident = assess_identifiability(Experiment.from_plan(plan), motor, noise_sigma=noise_sigma, names=names)
    gaps = ident.dead_params + ident.confounded_params
    if gaps:
        raise DrivecalError(f"the plan cannot identify {', '.join(gaps)} ({'; '.join(ident.reasons[n] for n in gaps)}), "
                            "whatever its amplitudes; change its segments before optimising.")
    report_before = assess_design(plan, motor, noise_sigma=noise_sigma, names=names)
    cov_before = predicted_covariance(plan, motor, noise_sigma=noise_sigma, names=names)
    logdet_before = _log_det(cov_before)

    par = _build_param(plan, specs, budget)
    objective, scales = _objective_fn(par, motor, names)
    solver = optx.BFGS(rtol=1e-3, atol=1e-3)
    sol = optx.minimise(objective, solver, jnp.asarray(par.u0), max_steps=max_steps, throw=False)
    u = np.asarray(sol.value)
    iterations = int(sol.stats["num_steps"])
    converged = bool(sol.result == optx.RESULTS.successful)
    message = "converged" if converged else (optx.RESULTS._index_to_message[int(sol.result._value)] or "stopped")

    try:
        candidate, cand_specs = _repair(par, u, np.asarray(scales(jnp.asarray(u))), motor)
        report_after = assess_design(candidate, motor, noise_sigma=noise_sigma, names=names)
        cov_after = predicted_covariance(candidate, motor, noise_sigma=noise_sigma, names=names)
        logdet_after = _log_det(cov_after)
        usable = report_after.ok and logdet_after < logdet_before
    except PlanError as exc:  # e.g. a band the exact waveform generator refuses
        usable, message = False, f"{message}; the rounded plan was refused: {exc}"
    if not usable:
        if not report_before.ok or abs(budget - total) * plan.sample_rate >= 0.5:
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
        logdet_after=logdet_after, iterations=iterations, converged=converged, improved=usable, message=message,
    )
