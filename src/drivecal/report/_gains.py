"""Controller hand-off: current-loop PI gains from a calibration that meet a stated specification.

Plant per axis (rotor at standstill, or with the speed-voltage coupling
cancelled by feed-forward, see :mod:`drivecal.report._firmware`):
``G(s) = 1 / (L s + R)`` with ``L = Ld`` (d axis) or ``Lq`` (q axis); at an operating point
``(i_d, i_q)`` the calibrated flux law's incremental ``L_dd`` or ``L_qq`` there (``d psi =
[[L_dd, L_dq], [L_dq, L_qq]] d i``: what a small current step about the point sees; a linear
calibration has ``L_dd = Ld``, ``L_qq = Lq`` at every current).

Controller (``sample_rate`` given, ``Ts = 1/fs``): the PI
``u[k] = Kp e[k] + x[k]``, ``x[k+1] = x[k] + Ki Ts e[k]`` (forward-Euler
integrator, ``C(z) = Kp + Ki Ts/(z - 1)``), whose command acts ``d`` samples
late (computation and PWM; ``d = 1`` by default, the calibration's fitted
``delay`` where it has one). The plant seen at the sample instants is the
exact discretisation of ``G`` under that held, delayed voltage: with
``d = n + m`` (whole samples ``n``, fraction ``m``), ``a = exp(-R Ts/L)`` and
``c = a^(1-m)``::

    G(z) = z^-n (b0 + b1 z^-1) / (z - a),  b0 = (1 - c)/R,  b1 = (c - a)/R

(``d = 1``: ``(1 - a) / (R z (z - a))``, zero-order hold plus one sample.)

Gains by discrete pole-zero cancellation: the PI zero ``1 - Ki Ts/Kp`` is put
on the plant pole ``a``, so ``Ki Ts = Kp (1 - a)`` and the loop is
``L(z) = g H(z)``, ``H(z) = z^-n (b0' + b1' z^-1)/(z - 1)`` with
``b0' + b1' = 1`` and ``g = Kp (1 - a)/R`` its one free gain::

    Kp = g R / (1 - a)   [V/A]        Ki = g R / Ts   [V/(A*s)]

``g`` meets the one specification asked for, on the sampled loop with its delay:

- crossover ``f_c``: ``g = 1/|H(f_c)|``;
- closed-loop -3 dB bandwidth ``f_b``: ``|g H/(1 + g H)|^2 = 1/2`` at ``f_b``,
  ``g = (Re H + sqrt(Re H^2 + |H|^2)) / |H|^2``;
- phase margin ``PM``: the crossover where ``180 deg + arg H = PM``
  (``arg H`` falls monotonically from -90 deg), then ``g = 1/|H|`` there.

A design is reachable when its phase margin is at least :data:`MIN_PHASE_MARGIN`
(and its frequencies below Nyquist). Without a sample rate the loop is judged
in continuous time without delay: ``H = 1/s``, ``Kp = L w_c``, ``Ki = R w_c``
(``w_c = 2 pi f``; crossover and -3 dB bandwidth coincide, the margin is 90 deg).

Uncertainty: the gains are smooth functions of (R, L, and the delay where it was fitted; ``L`` at an
operating point of those of Ld, Lq, lambda_m, sat_d, sat_q, sat_dq estimated, by forward-mode autodiff);
first order ``J Cov J^T`` (``J`` by central differences) and Monte Carlo (each motor drawn from
``N(estimate, Cov)`` gets its own design, its own flux law's ``L``) agree up to the map's curvature and the
sampling error. The draws also serve as true motors under the *fixed* calibrated gains: the achieved
crossover, -3 dB bandwidth and phase margin, as mean and 2.5 / 97.5 % quantiles.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import DrivecalError
from ..physics import BRIDGE, MAGNETIC, flux_of_currents, incremental_inductances, is_saturating
from ..results import Calibration
from ._firmware_loop import MIN_PHASE_MARGIN, design_gains, loop_figures, reachable

#: Kept for compatibility (drivecal 0.2 refused a bandwidth above this fraction of the sample rate);
#: what is reachable is now computed from the loop: :data:`MIN_PHASE_MARGIN`.
MAX_BANDWIDTH_FRACTION = 0.1
#: Inductance of each axis.
AXES = (("d", "Ld"), ("q", "Lq"))
#: The kinds of specification, their option and unit.
SPECS = {"bandwidth": ("--bandwidth", "Hz"), "crossover": ("--crossover", "Hz"),
         "phase_margin": ("--phase-margin", "deg")}
#: The parameters the gains are made of.
_GAIN_PARAMS = ("R", "Ld", "Lq")
#: What the incremental inductances at an operating point are made of (where estimated).
_FLUX_PARAMS = ("Ld", "Lq", "lambda_m") + MAGNETIC + BRIDGE
#: An operating point past this multiple of a saturating fit's ``i_ref`` (its data's peak |i|, to two
#: significant digits, so up to ~5 % below it) is an extrapolation of the fitted flux law.
EXTRAPOLATION_MARGIN = 1.05


@dataclasses.dataclass(frozen=True)
class Spread:
    """A closed-loop figure of merit: at the estimate, and over the confidence region (Monte Carlo)."""

    nominal: float
    mean: float
    p025: float
    p975: float

    @classmethod
    def of(cls, nominal: float, draws: np.ndarray) -> Spread:
        d = draws[np.isfinite(draws)]
        if d.size == 0:
            return cls(float(nominal), math.nan, math.nan, math.nan)
        return cls(float(nominal), float(d.mean()), float(np.quantile(d, 0.025)), float(np.quantile(d, 0.975)))

    def to_dict(self) -> dict[str, float | None]:
        return {k: (v if math.isfinite(v) else None) for k, v in dataclasses.asdict(self).items()}


def _num(x):
    return None if x is None or not math.isfinite(x) else float(x)


@dataclasses.dataclass(frozen=True)
class AxisGains:
    """PI gains of one current axis and what they achieve.

    Attributes:
        axis: "d" or "q".
        inductance_name: "Ld" or "Lq"; "L_dd" or "L_qq" at an operating point.
        inductance, resistance: the calibrated L (H; incremental at an operating point) and R (ohm) used.
        kp, ki: proportional (V/A) and integral (V/(A*s)) gains.
        ki_ts: discrete integrator increment ``Ki Ts`` (V/A), None in continuous time.
        kp_se, ki_se: first-order standard deviations (V/A, V/(A*s)); NaN if a
            parameter they depend on was not calibrated.
        kp_sd_mc, ki_sd_mc: Monte Carlo standard deviations, same units.
        calibrated: R and every parameter of this axis's L were identified by the fit.
        bandwidth: achieved -3 dB closed-loop bandwidth (Hz).
        phase_margin: achieved phase margin (deg).
        crossover: achieved crossover (Hz).
        operating_point: ``(i_d, i_q)`` (A) of the incremental inductance, None: zero current (Ld, Lq).
        inductance_at_zero_current: the calibrated Ld or Lq (H).
    """

    axis: str
    inductance_name: str
    inductance: float
    resistance: float
    kp: float
    ki: float
    ki_ts: float | None
    kp_se: float
    ki_se: float
    kp_sd_mc: float
    ki_sd_mc: float
    calibrated: bool
    bandwidth: Spread
    phase_margin: Spread
    crossover: Spread | None = None
    operating_point: tuple[float, float] | None = None
    inductance_at_zero_current: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "axis": self.axis, "inductance_name": self.inductance_name, "inductance": self.inductance,
            "resistance": self.resistance, "kp": self.kp, "ki": self.ki, "ki_ts": _num(self.ki_ts),
            "kp_se_first_order": _num(self.kp_se), "ki_se_first_order": _num(self.ki_se),
            "kp_sd_monte_carlo": _num(self.kp_sd_mc), "ki_sd_monte_carlo": _num(self.ki_sd_mc),
            "calibrated": self.calibrated,
            "crossover_hz": None if self.crossover is None else self.crossover.to_dict(),
            "bandwidth_hz": self.bandwidth.to_dict(), "phase_margin_deg": self.phase_margin.to_dict(),
            "operating_point_a": self.operating_point and dict(zip(("i_d", "i_q"), self.operating_point)),
            "inductance_at_zero_current": _num(self.inductance_at_zero_current),
        }


@dataclasses.dataclass(frozen=True)
class CurrentLoopDesign:
    """Current-loop gains of both axes, their uncertainty and the achieved loop.

    Attributes:
        bandwidth_hz: the requested -3 dB bandwidth (Hz), None for another kind of specification.
        omega_c: the d axis's designed crossover (rad/s).
        sample_rate_hz: controller sample rate (Hz), or None (continuous time).
        discretisation: the controller and loop model, in words.
        num_samples, seed: Monte Carlo draws and their seed.
        axes: d and q.
        warnings: plain-language caveats.
        spec_kind, spec_value: the specification met ("bandwidth" Hz, "crossover" Hz, "phase_margin" deg).
        delay_samples: the command delay of the loop (controller samples; 0 in continuous time).
        delay_source: where that delay came from, in words.
        limits: what the sampled loop can reach (:func:`reachable`), None in continuous time.
        operating_point: ``(i_d, i_q)`` (A) of the plant's incremental inductances, None: zero current.
        extrapolated: the operating point lies beyond the currents of a saturating calibration's data.
        data_peak_current: a saturating calibration's ``i_ref`` (A, its data's peak |i|), else None.
    """

    bandwidth_hz: float | None
    omega_c: float
    sample_rate_hz: float | None
    discretisation: str
    num_samples: int
    seed: int
    axes: tuple[AxisGains, ...]
    warnings: tuple[str, ...]
    spec_kind: str = "bandwidth"
    spec_value: float = math.nan
    delay_samples: float = 0.0
    delay_source: str = "continuous time: no delay"
    limits: dict[str, float] | None = None
    operating_point: tuple[float, float] | None = None
    extrapolated: bool = False
    data_peak_current: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """The ``gains`` JSON (SI units: V/A, V/(A*s), Hz, deg)."""
        return {
            "specification": {"kind": self.spec_kind, "value": self.spec_value, "unit": SPECS[self.spec_kind][1]},
            "bandwidth_hz": self.bandwidth_hz, "omega_c": self.omega_c, "sample_rate_hz": self.sample_rate_hz,
            "delay_samples": self.delay_samples, "delay_source": self.delay_source, "reachable": self.limits,
            "discretisation": self.discretisation,
            "monte_carlo": {"num_samples": self.num_samples, "seed": self.seed},
            "axes": {a.axis: a.to_dict() for a in self.axes},
            "warnings": list(self.warnings),
            "operating_point": None if self.operating_point is None else {
                **dict(zip(("i_d", "i_q"), self.operating_point)), "unit": "A", "extrapolated": self.extrapolated,
                "data_peak_current": self.data_peak_current},
        }


def _draws(cal: Calibration, estimate: np.ndarray, num_samples: int, seed: int,
           params: tuple[str, ...] = _GAIN_PARAMS) -> np.ndarray:
    """Motors from N(estimate, Cov) over the fitted names, shape (S, len(names)); the rest fixed.

    Where the covariance is not finite outside the gains' parameters (``params`` and the delay), only
    their block is drawn (the marginal of the same normal).
    """
    rng = np.random.default_rng(seed)
    cov = np.asarray(cal.covariance, dtype=float)
    keep = list(range(len(cal.fit_names)))
    if not np.all(np.isfinite(cov)):
        keep = [i for i, n in enumerate(cal.fit_names) if n in params + ("delay",)]
        cov = cov[np.ix_(keep, keep)]
        if not np.all(np.isfinite(cov)):  # the delay's block undefined too: draw R, Ld, Lq only
            keep = [i for i in keep if cal.fit_names[i] in params]
            cov = np.asarray(cal.covariance, dtype=float)[np.ix_(keep, keep)]
    idx = [cal.names.index(cal.fit_names[i]) for i in keep]
    out = np.broadcast_to(estimate, (num_samples, len(cal.names))).copy()
    if idx:
        out[:, idx] = rng.multivariate_normal(estimate[idx], cov, size=num_samples, method="eigh",
                                              check_valid="ignore")  # checked by from_dict
    return out


def _gain_inputs(cal: Calibration, source: str, extra: tuple[str, ...] = ()) -> np.ndarray:
    """The estimate the gains use: the fit's, the prior's for a parameter not fitted (as the fit holds it).

    Raises:
        DrivecalError: R, Ld, Lq (or one of ``extra``) fitted but its estimate or variance undefined;
            R, Ld or Lq not positive.
    """
    fix = "refit, or pass a result whose fit converged"
    estimate = np.array(cal.estimate, dtype=float)
    cov = np.asarray(cal.covariance, dtype=float)
    for name in _GAIN_PARAMS + extra:
        i = cal.names.index(name)
        fitted = name in cal.fit_names
        if not math.isfinite(estimate[i]):
            if fitted:
                need = "every inductance and R" if name in _GAIN_PARAMS else "every flux-law parameter"
                raise DrivecalError(f"{source}: parameters.{name}.estimate is null; gains need {need} "
                                    f"estimated — {fix}.")
            estimate[i] = float(getattr(cal.prior, name))
        if name in _GAIN_PARAMS and not estimate[i] > 0:
            what = "estimate" if fitted else "prior"
            raise DrivecalError(f"{source}: parameters.{name}.{what} is {estimate[i]:.6g}; gains need a positive "
                                f"R, Ld and Lq — {fix}.")
    block = [cal.fit_names.index(n) for n in _GAIN_PARAMS + extra if n in cal.fit_names]
    sub = cov[np.ix_(block, block)]
    if not np.all(np.isfinite(sub)):
        bad = cal.fit_names[block[int(np.argwhere(~np.isfinite(sub))[0, 0])]]
        raise DrivecalError(f"{source}: covariance of {bad} is null; the gains' uncertainty needs the covariance of "
                            f"every fitted R and L{' and flux-law parameter' if extra else ''} — {fix}.")
    return estimate


@functools.partial(jax.jit, static_argnames="names")
def _axis_inductances(i_d, i_q, base, names, values, tangents):
    """``(L_dd, L_qq)`` (H) at ``(i_d, i_q)`` of the motors ``base.with_vector(names, values)`` (rows), and
    their derivatives along ``tangents`` (rows): each shape (rows, 2)."""
    def at(v):
        motor = base.with_vector(names, v)
        l_dd, _, l_qq = incremental_inductances(*flux_of_currents(i_d, i_q, motor), motor)
        return jnp.stack([l_dd, l_qq], axis=-1)

    return jax.jvp(at, (values,), (tangents,))


def _operating_point(cal: Calibration, estimate: np.ndarray, draws: np.ndarray, op, deps: tuple[str, ...],
                     source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plant inductances (d, q) at ``op``: nominal (2,), ``d L / d deps`` (2, k), per draw (S, 2); one call."""
    idx, k = [cal.names.index(n) for n in deps], len(deps)
    values = np.vstack([np.tile(estimate[idx], (k, 1)), draws[:, idx]])  # the estimate once per tangent
    tangents = np.vstack([np.eye(k), np.zeros((len(draws), k))])
    value, slope = (np.asarray(x, dtype=float) for x in _axis_inductances(*op, cal.prior, deps, values, tangents))
    nominal = value[0]
    if not (np.all(np.isfinite(nominal)) and np.all(nominal > 0) and np.all(np.isfinite(slope[:k]))):
        raise DrivecalError(f"{source}: the calibrated flux law gives no positive incremental inductance at the "
                            f"operating point i_d = {op[0]:g} A, i_q = {op[1]:g} A (L_dd, L_qq = {nominal[0]:.4g}, "
                            f"{nominal[1]:.4g} H); choose a current within the calibration's data.")
    return nominal, slope[:k].T, value[k:]


def _spec(bandwidth_hz, crossover_hz, phase_margin_deg, sample_rate_hz) -> tuple[str, float]:
    """The one specification given, checked: ``(kind, value)``."""
    given = {k: v for k, v in (("bandwidth", bandwidth_hz), ("crossover", crossover_hz),
                               ("phase_margin", phase_margin_deg)) if v is not None}
    if len(given) != 1:
        got = " and ".join(SPECS[k][0] for k in given) or "none"
        raise DrivecalError(f"give exactly one of --bandwidth, --crossover or --phase-margin (got {got}).")
    (kind, value), = given.items()
    option, unit = SPECS[kind]
    if not (isinstance(value, (int, float)) and value > 0 and math.isfinite(value)):
        example = "60" if kind == "phase_margin" else "1000"
        raise DrivecalError(f"{option} {value}: must be a positive number of {unit}, e.g. {example}.")
    if kind == "phase_margin":
        if sample_rate_hz is None:
            raise DrivecalError(f"{option} needs --sample-rate: without sampling and delay the loop has 90 deg of "
                                "margin at any crossover.")
        if not MIN_PHASE_MARGIN <= value < 90.0:
            raise DrivecalError(f"{option} {value:g} deg is not reachable: a PI with pole-zero cancellation gives "
                                f"{MIN_PHASE_MARGIN:g} deg (lowest accepted) up to just under 90 deg; choose one in "
                                "that range.")
    return kind, float(value)


def _delay(cal: Calibration, estimate: np.ndarray, sample_rate_hz, delay_samples,
           delay_sample_rate_hz) -> tuple[float, float, str, list[str]]:
    """``(delay in controller samples, controller samples per calibration sample, where from, warnings)``."""
    if sample_rate_hz is None:
        return 0.0, 1.0, "continuous time: no delay", []
    if delay_samples is not None:
        if not (delay_samples >= 0 and math.isfinite(delay_samples)):
            raise DrivecalError(f"--delay {delay_samples}: must be a number of samples >= 0, e.g. 1.")
        return float(delay_samples), 1.0, "given (--delay)", []
    fitted = "delay" in cal.fit_names and "delay" in cal.names
    value = estimate[cal.names.index("delay")] if fitted else float(cal.prior.delay)
    if fitted and not math.isfinite(value):
        return 1.0, 1.0, "one sample of computation delay", ["the calibration's fitted delay is null; the loop "
                                                             "uses one sample"]
    if not (math.isfinite(value) and (value > 0 or fitted)):
        return 1.0, 1.0, "one sample of computation delay: the calibration has no fitted delay", []
    warnings = []
    if delay_sample_rate_hz is None:
        scale = 1.0
        warnings.append("the bench's sample rate is not in the result; its delay is taken in controller samples")
    else:
        scale = sample_rate_hz / delay_sample_rate_hz
    what = "fitted" if fitted else "fixed (not fitted)"
    if value < 0:
        warnings.append(f"the fitted delay {value:.4g} samples is negative; the loop uses 0")
    at = "" if delay_sample_rate_hz is None else f" at {delay_sample_rate_hz:g} Hz"
    return max(value, 0.0) * scale, scale, f"the calibration's {what} delay, {value:.4g} samples{at}", warnings


def _not_reachable(kind: str, value: float, limits: dict[str, float], sample_rate_hz: float, delay: float) -> str:
    option, unit = SPECS[kind]
    return (f"{option} {value:g} {unit} is not reachable at --sample-rate {sample_rate_hz:g} Hz with a delay of "
            f"{delay:.3g} sample(s): with at least {MIN_PHASE_MARGIN:g} deg of phase margin the crossover reaches at "
            f"most {limits['max_crossover_hz']:.4g} Hz and the closed-loop -3 dB bandwidth "
            f"{limits['max_bandwidth_hz']:.4g} Hz; lower the specification or raise the sample rate.")


def design_current_loop(
    cal: Calibration,
    bandwidth_hz: float | None = None,
    *,
    crossover_hz: float | None = None,
    phase_margin_deg: float | None = None,
    sample_rate_hz: float | None = None,
    delay_samples: float | None = None,
    delay_sample_rate_hz: float | None = None,
    num_samples: int = 4000,
    seed: int = 0,
    source: str = "the calibration",
    operating_point: tuple[float, float] | None = None,
) -> CurrentLoopDesign:
    """PI gains for both current axes meeting one specification, their uncertainty, and the loop they achieve.

    Args:
        cal: a single calibration (``Calibration.from_dict`` of a saved result works).
        bandwidth_hz: closed-loop -3 dB bandwidth (Hz) of the sampled loop with its delay; or
        crossover_hz: open-loop crossover (Hz); or
        phase_margin_deg: phase margin (deg, ``MIN_PHASE_MARGIN`` to 90; needs a sample rate).
            Exactly one of the three.
        sample_rate_hz: controller sample rate (Hz); None designs and judges
            the loop in continuous time without delay (``Kp = L w_c``, ``Ki = R w_c``).
        delay_samples: the command's delay (controller samples, >= 0); None
            takes the calibration's fitted ``delay`` (or its fixed non-zero one),
            else one sample of computation delay.
        delay_sample_rate_hz: the sample rate (Hz) of the calibration's delay
            (the bench's); None: the same as ``sample_rate_hz``.
        num_samples: Monte Carlo draws from the parameter covariance.
        seed: Monte Carlo seed.
        source: where ``cal`` came from (the result file), for messages.
        operating_point: ``(i_d, i_q)`` (A) where the plant's L is the flux law's incremental
            ``L_dd`` (d) or ``L_qq`` (q), uncertain through every estimated parameter of the law (Ld,
            Lq, lambda_m, sat_d, sat_q, sat_dq); None: Ld, Lq. A saturating fit states its law at
            ``i_ref``, which it sets to its data's peak |i| (two significant digits, so up to ~5 %
            low): past ``max(|i_d|, |i_q|) > 1.05 * i_ref`` the inductances extrapolate the law (a
            warning; ``extrapolated``). A linear calibration's are Ld, Lq at any current: no warning.

    A parameter the fit did not identify keeps its prior value (and the
    gains that use it have no uncertainty, with a warning).

    Raises:
        DrivecalError: not exactly one specification, a non-positive value or
            sample rate, a specification the sampled loop cannot reach with
            ``MIN_PHASE_MARGIN`` of margin (the message says what it can), R,
            Ld or Lq not estimated (null, or not positive), the covariance of a
            fitted one undefined, or so wide that (almost) every Monte Carlo
            draw has a non-positive R or L; an operating point that is not two
            finite currents, or where the law gives no positive inductance.
    """
    if sample_rate_hz is not None and not (sample_rate_hz > 0 and math.isfinite(sample_rate_hz)):
        raise DrivecalError(f"--sample-rate {sample_rate_hz}: must be a positive number of Hz, e.g. 20000.")
    kind, value = _spec(bandwidth_hz, crossover_hz, phase_margin_deg, sample_rate_hz)
    if not all(n in cal.names for n in _GAIN_PARAMS):
        raise DrivecalError(f"{source}: the result does not estimate R, Ld and Lq; gains need all three.")
    fs = sample_rate_hz
    try:
        op = None if operating_point is None else tuple(float(x) for x in operating_point)
    except (TypeError, ValueError):
        op = ()
    if op is not None and (len(op) != 2 or not all(map(math.isfinite, op))):
        raise DrivecalError(f"--operating-point {operating_point}: must be two finite currents ID,IQ in A, e.g. -5,20.")
    deps = () if op is None else tuple(n for n in _FLUX_PARAMS if n in cal.names)  # what L there is made of
    extra = tuple(n for n in deps if n not in _GAIN_PARAMS)
    estimate = _gain_inputs(cal, source, extra)
    delay, delay_scale, delay_source, warnings = _delay(cal, estimate, fs, delay_samples, delay_sample_rate_hz)
    est = dict(zip(cal.names, estimate))
    fit_idx = {n: i for i, n in enumerate(cal.fit_names)}
    delay_fitted = (fs is not None and delay_samples is None and "delay" in fit_idx and "delay" in cal.names
                    and math.isfinite(est["delay"]))
    cov = np.asarray(cal.covariance, dtype=float)
    draws = _draws(cal, estimate, num_samples, seed, _GAIN_PARAMS + extra)
    col = {n: draws[:, i] for i, n in enumerate(cal.names)}
    ok = np.all(draws[:, [cal.names.index(n) for n in _GAIN_PARAMS]] > 0, axis=1)
    # per axis, the plant's L: the parameters it is made of, its derivatives over them, per draw, at the estimate
    chain = {ln: ([ln], np.ones(1), col[ln], est[ln]) for _, ln in AXES}
    peak = float(cal.prior.i_ref) if is_saturating(cal.motor) else None
    extrapolated = op is not None and peak is not None and max(map(abs, op)) > EXTRAPOLATION_MARGIN * peak
    if op is not None:
        l_op, slope, l_draws = _operating_point(cal, estimate, draws, op, deps, source)
        ok &= np.all(np.isfinite(l_draws) & (l_draws > 0), axis=1)
        chain = {ln: (list(deps), slope[a], l_draws[:, a], float(l_op[a])) for a, (_, ln) in enumerate(AXES)}
        if extrapolated:
            warnings.append(f"the operating point i_d = {op[0]:g} A, i_q = {op[1]:g} A lies beyond the currents "
                            f"the calibration's data reached (peak |i| about i_ref = {peak:g} A): its incremental "
                            "inductances extrapolate the fitted saturation law")
    if delay_fitted:
        ok &= np.isfinite(col["delay"])
    if ok.sum() < 2:
        raise DrivecalError(f"{source}: {int((~ok).sum())} of {num_samples} Monte Carlo draws from the covariance "
                            "have a non-positive R or L, too few left to judge the loop; refit with more data (a "
                            "covariance this wide does not calibrate the motor).")
    if not ok.all():
        warnings.append(f"{int((~ok).sum())} of {num_samples} Monte Carlo draws had a non-positive R or L and "
                        "were dropped")
    d_draws = np.maximum(col["delay"][ok], 0.0) * delay_scale if delay_fitted else delay
    limits = None

    def gains_of(params: dict[str, Any]):
        return design_gains(kind, value, params["R"], params["L"], fs, params["delay"])

    axes = []
    for axis, lname in AXES:
        l_names, l_slope, l_col, ind = chain[lname]
        r = est["R"]
        nominal = {"R": r, "L": ind, "delay": delay}
        kp, ki = (float(np.squeeze(g)) for g in gains_of(nominal))
        ref = value if kind != "phase_margin" else fs * 1e-4  # the search reaches down to fs * 1e-7
        fc0, bw0, pm0 = (float(x[0]) for x in loop_figures(kp, ki, r, ind, ref, fs, delay))
        if fs is not None:
            axis_limits = reachable(r, ind, fs, delay)
            limits = limits or axis_limits
            met = {"crossover": fc0, "bandwidth": bw0, "phase_margin": pm0}[kind]
            if (value >= 0.5 * fs or not (kp > 0 and ki > 0) or not pm0 >= MIN_PHASE_MARGIN - 1e-6
                    or not abs(met - value) <= 1e-6 * value):
                raise DrivecalError(_not_reachable(kind, value, axis_limits, fs, delay))
        # First order: central differences of the design map over (R, L, delay), L chained to its parameters.
        keys = ["R", "L"] + (["delay"] if delay_fitted else [])
        jac = np.zeros((2, len(keys)))
        for j, key in enumerate(keys):
            step = 1e-6 * (abs(nominal[key]) if key != "delay" else 1.0)
            hi, lo = ({**nominal, key: nominal[key] + h} for h in (step, -step))
            scale = delay_scale if key == "delay" else 1.0
            jac[:, j] = [(float(np.squeeze(a)) - float(np.squeeze(b))) / (2 * step) * scale
                         for a, b in zip(gains_of(hi), gains_of(lo))]
        names = ["R"] + l_names + keys[2:]
        jac = np.concatenate([jac[:, :1], jac[:, 1:2] * l_slope[None, :], jac[:, 2:]], axis=1)
        size = [1.0 if p == "delay" else max(abs(est[p]), 1.0) if p in MAGNETIC + BRIDGE else abs(est[p]) for p in names]
        uses = np.abs(jac) * np.array(size) > 1e-7 * np.abs([[kp], [ki]])
        known = np.array([p in fit_idx for p in names])
        fitted = [fit_idx[p] for p in names if p in fit_idx]
        j_fit = jac[:, known]
        first = np.sqrt(np.diag(j_fit @ cov[np.ix_(fitted, fitted)] @ j_fit.T)) if fitted else np.full(2, np.nan)
        defined = ~np.any(uses & ~known, axis=1)
        kp_mc, ki_mc = gains_of({"R": col["R"][ok], "L": l_col[ok], "delay": d_draws})
        mc = np.array([np.std(kp_mc, ddof=1), np.std(ki_mc, ddof=1)])
        fc, bw, pm = loop_figures(kp, ki, col["R"][ok], l_col[ok], fc0 if math.isfinite(fc0) else ref, fs, d_draws)
        need = ["R", lname] + [p for j, p in enumerate(names) if uses[:, j].any() and p not in ("R", lname, "delay")]
        calibrated = all(p in fit_idx for p in need)
        se, sd = (np.where(defined, x, math.nan) for x in (first, mc))
        axes.append(AxisGains(
            axis=axis, inductance_name=lname if op is None else {"Ld": "L_dd", "Lq": "L_qq"}[lname],
            inductance=float(ind), resistance=float(r), kp=kp, ki=ki, ki_ts=None if fs is None else ki / fs,
            kp_se=float(se[0]), ki_se=float(se[1]), kp_sd_mc=float(sd[0]), ki_sd_mc=float(sd[1]),
            calibrated=calibrated, bandwidth=Spread.of(bw0, bw), phase_margin=Spread.of(pm0, pm),
            crossover=Spread.of(fc0, fc), operating_point=op, inductance_at_zero_current=float(est[lname])))
        if not calibrated:
            missing = [n for n in need if n not in fit_idx]
            warnings.append(f"{axis} axis: {', '.join(missing)} not identified by this calibration; its gains use "
                            "the prior value and their uncertainty is unknown")
    if fs is None:
        disc = "continuous-time PI C(s) = Kp + Ki/s on G(s) = 1/(L s + R), no delay"
    else:
        disc = (f"discrete PI at {fs:g} Hz: u[k] = Kp e[k] + x[k], x[k+1] = x[k] + Ki*Ts e[k] (forward-Euler "
                f"integrator), its zero on the plant pole exp(-R Ts/L), command delay {delay:.4g} sample(s)")
    return CurrentLoopDesign(
        bandwidth_hz=value if kind == "bandwidth" else None, omega_c=2.0 * math.pi * axes[0].crossover.nominal,
        sample_rate_hz=None if fs is None else float(fs), discretisation=disc, num_samples=int(num_samples),
        seed=int(seed), axes=tuple(axes), warnings=tuple(warnings), spec_kind=kind, spec_value=value,
        delay_samples=float(delay), delay_source=delay_source, limits=limits, operating_point=op,
        extrapolated=extrapolated, data_peak_current=peak)
