"""The design space of D-optimal design: a plan's waveforms as specs, mapped from unconstrained variables.

Every waveform of a plan is a spec (a constant, or a plan-file table such as
``{"kind": "chirp", ...}``); :class:`_Param` maps unconstrained variables ``u``
to the waveforms' levels, amplitudes, offsets and bands, each inside the
voltage circle by construction, and to the segment durations (softmax shares of
the time budget). The waveforms themselves are the plan files' generators
(``plan.waveforms``), in ``jax.numpy`` on the maximal grid for the smooth
problem and in numpy, on whole samples, for the exact plan (``_optimal``).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DrivecalError
from ..plan import Plan, Segment, waveforms


#: A waveform spec: ``{"kind": "chirp", "amplitude": 6.0, ...}`` (SI), or a float for a constant (V).
Spec = Any
_AXES = ("v_d", "v_q")
#: Band limits for chirps and multisines (Hz; the upper one as a fraction of the sample rate).
F_LOW, F_HIGH_FRACTION = 1.0, 0.45
#: Shortest segment, as a fraction of the budget shared equally (s / s); the plan margins' least durations
#: (``_bench_limits.min_durations``) bind where they are longer.
MIN_DURATION_FRACTION = 0.1
#: A chirp's, multisine's or PRBS's amplitude under this share of its peak ``amplitude + |offset|`` leaves a
#: constant: the optimised waveform is written, and its segment named, as the step it is.
COLLAPSED_AMPLITUDE = 0.02
#: The words of a segment name that say which waveform it carries.
_KIND_WORDS = ("multisine", "chirp", "prbs")


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
    pattern: np.ndarray | None = None  # samples (V) on the grid


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
    min_duration: np.ndarray  # shortest duration of each segment (s), shape (S,) (fixed ones: their own)
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
        least = self.min_duration[free]
        spare = self.budget - self.fixed_time - float(least.sum())
        free_t = jnp.asarray(least) + spare * share
        idx = np.cumsum(free) - 1
        return jnp.where(free, free_t[np.clip(idx, 0, k - 1)], fixed)

    def _freq(self, v):
        return F_LOW * (self._f_high() / F_LOW) ** jax.nn.sigmoid(v)

    def waveform_params(self, u, ax: _Axis) -> dict:
        """The waveform's free numbers (SI) for unconstrained ``u`` (traceable)."""
        p = u[ax.start : ax.start + ax.size]
        if ax.kind in ("zero",):
            return {}
        if ax.kind in ("constant", "step", "ramp"):
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
        """The axis voltage (V) on the maximal grid, shape (grid,), for a segment of ``duration`` (s).

        The plan files' waveform generators (``plan.waveforms``) in ``jax.numpy``,
        traced in the waveform's numbers and the duration.
        """
        fs = self.sample_rate
        q = self.waveform_params(u, ax)
        spec = ax.spec
        if ax.kind == "zero":
            return jnp.zeros(self.grid)
        if ax.kind == "constant":
            return jnp.full(self.grid, math.copysign(1.0, spec) * q["peak"])
        if ax.kind == "step":
            scale = max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
            level, initial = spec["level"] / scale, spec.get("initial", 0.0) / scale
            return q["peak"] * waveforms.step(self.grid, fs, level=level, initial=initial,
                                              delay=spec.get("delay", 0.0), xp=jnp)
        if ax.kind == "ramp":
            scale = max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
            level, initial = spec["level"] / scale, spec.get("initial", 0.0) / scale
            return q["peak"] * waveforms.ramp(self.grid, fs, level=level, initial=initial, rise=spec["rise"],
                                              delay=spec.get("delay", 0.0), xp=jnp)
        if ax.kind == "samples":
            return q["gain"] * jnp.asarray(ax.pattern)
        if ax.kind == "prbs":
            params = {k: v for k, v in spec.items() if k not in ("kind", "amplitude", "offset") and v is not None}
            return waveforms.prbs(self.grid, fs, amplitude=q["amplitude"], offset=q["offset"], xp=jnp, **params)
        if ax.kind == "chirp":
            return waveforms.chirp(self.grid, fs, amplitude=q["amplitude"], offset=q["offset"], f_start=q["f_start"],
                                   f_stop=q["f_stop"], sweep=spec.get("sweep", "linear"),
                                   phase=spec.get("phase", 0.0), duration=duration, xp=jnp)
        if ax.kind == "multisine":
            # Smooth stand-in: log-spaced tones at continuous frequencies with Schroeder
            # phases; the exact plan puts them on harmonics of 1/duration.
            count = int(spec.get("num_tones", 16))
            freqs = jnp.exp(jnp.linspace(jnp.log(q["f_min"]), jnp.log(q["f_max"]), count))
            t = jnp.arange(self.grid) / fs
            return waveforms.schroeder_tones(t, freqs, amplitude=q["amplitude"], offset=q["offset"],
                                             window=t < duration, xp=jnp)
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
        taken = {seg.name for seg in self.plan.segments}
        for s, (seg, pair) in enumerate(zip(self.plan.segments, self.axes)):
            n = int(counts[s])
            exact = {axis: self._exact_spec(u, ax, n, scales[s]) for axis, ax in zip(_AXES, pair)}
            name = _named_for(seg.name, [ax.kind for ax in pair], list(exact.values()), taken)
            values = {}
            for axis in _AXES:
                values[axis] = _generate(exact[axis], n, fs)
                specs[(name, axis)] = exact[axis]
            segments.append(dataclasses.replace(seg, name=name, duration=n / fs, v_d=values["v_d"],
                                                v_q=values["v_q"]))
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
        if ax.kind in ("step", "ramp"):
            norm = max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
            out = dict(spec, level=spec["level"] / norm * q["peak"] * scale,
                       initial=spec.get("initial", 0.0) / norm * q["peak"] * scale)
            return out
        if q["amplitude"] <= COLLAPSED_AMPLITUDE * (q["amplitude"] + abs(q["offset"])):
            return q["offset"] * scale  # collapsed to its offset: a constant, written as one
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


def _named_for(name: str, kinds: list[str], specs: list, taken: set[str]) -> str:
    """``name``, with the waveform word it carries ("multisine", "chirp", "prbs") made "step" where that
    waveform came out of the optimisation a constant (and the segment now carries no such waveform)."""
    collapsed = [k for k, spec in zip(kinds, specs) if k in _KIND_WORDS and not isinstance(spec, dict)]
    kept = {spec["kind"] for spec in specs if isinstance(spec, dict)}
    new = name
    for kind in collapsed:
        if kind in new and kind not in kept:
            new = new.replace(kind, "step")
    if new != name and new in taken:
        new = f"{new} (was {name})"
    taken.add(new)
    return new


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
    if spec["kind"] in ("step", "ramp"):
        return max(abs(spec["level"]), abs(spec.get("initial", 0.0)))
    if spec["kind"] == "samples":
        return float(np.max(np.abs(spec["values"]))) if len(spec["values"]) else 0.0
    return abs(spec.get("amplitude", 0.0)) + abs(spec.get("offset", 0.0))


def free_durations(plan: Plan, specs: dict) -> np.ndarray:
    """Per segment, whether the design may move its duration (all but measured sequences), shape (S,)."""
    return np.array([not any(_axis_kind(specs[(s.name, a)]) == "samples" for a in _AXES) for s in plan.segments])


def build_param(plan: Plan, specs: dict, budget: float, least: np.ndarray | None = None,
                 voltage_fraction: float = 1.0) -> _Param:
    """The design space of ``plan``: durations at least ``least`` (s, per segment; default none) and at least
    :data:`MIN_DURATION_FRACTION` of an equal share of the budget, voltages inside ``voltage_fraction`` of
    the voltage circle."""
    fs = plan.sample_rate
    limit = voltage_fraction * plan.voltage_limit
    segs = plan.segments
    free = tuple(bool(f) for f in free_durations(plan, specs))
    fixed_time = sum(s.duration for s, f in zip(segs, free) if not f)
    k = sum(free)
    if k and budget - fixed_time <= 0:
        raise DrivecalError(f"budget {budget:g} s leaves no time beside the {fixed_time:g} s of measured-sequence "
                            "segments (whose duration is fixed); raise --budget.")
    share = MIN_DURATION_FRACTION * (budget - fixed_time) / max(k, 1)
    least = np.zeros(len(segs)) if least is None else np.asarray(least, dtype=float)
    min_duration = np.where(free, np.maximum(least, share), [s.duration for s in segs])
    if k and share * fs < 2:
        raise DrivecalError(f"budget {budget:g} s is too short for {k} segments at {fs:g} Hz; raise --budget.")
    need = fixed_time + float(min_duration[np.array(free)].sum())
    if k and need > budget * (1 + 1e-9):
        raise DrivecalError(f"budget {budget:g} s is too short for the plan's margins: its segments need at least "
                            f"{need:.3g} s (200 samples each, 3 electrical time constants per locked step, 1.5 "
                            f"spin-up times per free one); raise --budget to {need:.3g} s or more.")
    longest = max([budget - fixed_time - float(min_duration[np.array(free)].sum())
                   + float(np.max(min_duration[np.array(free)]))] * bool(k)
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
            if kind in ("constant", "step", "ramp"):
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
            pair.append(_Axis(kind=kind, start=start, size=len(init), bound=bound, spec=spec, pattern=pattern))
            u0 += init
            start += len(init)
        axes.append(tuple(pair))
    duration_start = start
    for seg, f, lo in zip(segs, free, min_duration):
        if f:
            u0.append(math.log(max(seg.duration * stretch - lo, 1e-3 * lo)))
    return _Param(plan=plan, axes=tuple(axes), free_duration=free, duration_start=duration_start,
                  u0=np.asarray(u0, dtype=float), budget=float(budget), fixed_time=float(fixed_time),
                  min_duration=min_duration, grid=grid)
