"""Controller hand-off: current-loop PI gains from a calibration, with their uncertainty.

Plant per axis (rotor at standstill, or with the speed-voltage coupling
cancelled by feed-forward, as usual in field-oriented control):
``G(s) = 1 / (L s + R)`` with ``L = Ld`` (d axis) or ``Lq`` (q axis).

Gains by pole-zero cancellation, ``w_c = 2 pi f_bw``::

    Kp = L * w_c   [V/A]        Ki = R * w_c   [V/(A*s)]

The PI zero ``Ki/Kp = R/L`` cancels the plant pole, so on the calibrated
motor the open loop is ``w_c/s`` and the closed loop ``w_c/(s + w_c)``:
-3 dB bandwidth exactly ``f_bw``, phase margin 90 deg.

Discrete time (``sample_rate`` given, ``Ts = 1/fs``): the PI is
``u[k] = Kp e[k] + x[k]``, ``x[k+1] = x[k] + Ki Ts e[k]`` (forward-Euler
integrator, ``C(z) = Kp + Ki Ts/(z - 1)``); the plant is the zero-order-hold
discretisation ``G(z) = (1 - a) / (R (z - a))``, ``a = exp(-R Ts / L)``; and
one sample of computation delay ``z^-1`` (the voltage computed at sample k is
applied at k + 1). The loop is ``L(z) = C(z) G(z) / z``, evaluated on
``z = exp(j w Ts)`` up to Nyquist.

Uncertainty: the gains are linear in (R, L), so the first-order (Jacobian)
propagation ``J Cov J^T`` is exact and Monte Carlo (draws from
``N(estimate, Cov)``) agrees up to its sampling error. The Monte Carlo draws
matter for what is not linear: the closed loop of the *fixed* calibrated
gains on a true motor anywhere in the confidence region, summarised by the
mean and the 2.5 / 97.5 % quantiles of its -3 dB bandwidth and phase margin.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..errors import DrivecalError
from ..results import Calibration

#: Highest bandwidth accepted, as a fraction of the controller's sample rate:
#: beyond ~fs/10 the sample-and-delay phase lag (1.5 samples) eats the margin.
MAX_BANDWIDTH_FRACTION = 0.1
#: Inductance of each axis.
AXES = (("d", "Ld"), ("q", "Lq"))
#: The parameters the gains are made of.
_GAIN_PARAMS = ("R", "Ld", "Lq")


def pi_gains(resistance: Any, inductance: Any, bandwidth_hz: float) -> tuple[Any, Any]:
    """Pole-zero-cancelling PI gains ``(Kp [V/A], Ki [V/(A*s)])`` for ``bandwidth_hz`` (Hz)."""
    w_c = 2.0 * math.pi * bandwidth_hz
    return inductance * w_c, resistance * w_c


def open_loop(kp, ki, resistance, inductance, freq_hz, sample_rate_hz: float | None = None):
    """Open-loop frequency response ``C G`` (continuous) or ``C(z) G(z) z^-1`` (discrete), complex.

    All arguments broadcast; ``freq_hz`` in Hz, gains in V/A and V/(A*s),
    resistance (ohm), inductance (H).
    """
    w = 2.0 * np.pi * np.asarray(freq_hz)
    if sample_rate_hz is None:
        s = 1j * w
        return (kp + ki / s) / (inductance * s + resistance)
    ts = 1.0 / sample_rate_hz
    z = np.exp(1j * w * ts)
    a = np.exp(-resistance * ts / inductance)
    return (kp + ki * ts / (z - 1.0)) * (1.0 - a) / (resistance * (z - a)) / z


def _phase_deg(kp, ki, resistance, inductance, freq_hz, sample_rate_hz):
    # Sum of the factors' angles: no wrap-around at -180 deg (np.angle of the product would wrap).
    w = 2.0 * np.pi * np.asarray(freq_hz)
    if sample_rate_hz is None:
        s = 1j * w
        return np.degrees(np.angle(kp + ki / s) - np.angle(inductance * s + resistance))
    ts = 1.0 / sample_rate_hz
    z = np.exp(1j * w * ts)
    a = np.exp(-resistance * ts / inductance)
    return np.degrees(np.angle(kp + ki * ts / (z - 1.0)) - np.angle(z - a) - w * ts)


def _first_crossing(fun, f_lo: float, f_hi: float, shape: tuple[int, ...], n_grid: int = 600, iters: int = 60):
    """First frequency (Hz) in ``[f_lo, f_hi]`` where ``fun(f) < 0``, per element; NaN where none.

    ``fun`` maps frequencies of shape (S, F) to values of the same shape;
    a log grid brackets the first sign change, bisection refines it.
    """
    grid = np.geomspace(f_lo, f_hi, n_grid)
    below = fun(np.broadcast_to(grid, shape + (n_grid,))) < 0
    found = below.any(axis=-1) & ~below[..., 0]
    idx = np.clip(np.argmax(below, axis=-1), 1, n_grid - 1)
    lo, hi = grid[idx - 1], grid[idx]
    for _ in range(iters):
        mid = np.sqrt(lo * hi)
        neg = fun(mid[..., None])[..., 0] < 0
        hi, lo = np.where(neg, mid, hi), np.where(neg, lo, mid)
    return np.where(found, np.sqrt(lo * hi), np.nan)


def loop_metrics(kp, ki, resistance, inductance, bandwidth_hz: float, sample_rate_hz: float | None = None):
    """-3 dB closed-loop bandwidth (Hz) and phase margin (deg) of PI gains on motors (R, L).

    Args:
        kp, ki: the controller's gains (scalars).
        resistance, inductance: the true motor's R (ohm) and L (H), shape (S,).
        bandwidth_hz: the requested bandwidth: sets the search range.
        sample_rate_hz: controller sample rate (Hz), or None for continuous time.

    Returns:
        ``(bandwidth_hz, phase_margin_deg)``, each shape (S,); NaN where the
        closed loop never falls below -3 dB (or the loop gain never crosses 1)
        before ``1000 f_bw`` or Nyquist.
    """
    r = np.atleast_1d(np.asarray(resistance, dtype=float))[:, None]
    ind = np.atleast_1d(np.asarray(inductance, dtype=float))[:, None]
    f_lo = bandwidth_hz * 1e-3
    f_hi = bandwidth_hz * 1e3 if sample_rate_hz is None else 0.5 * sample_rate_hz * (1.0 - 1e-9)

    def cl_gap(f):  # |T|^2 - 1/2 < 0 above the -3 dB point
        lo = open_loop(kp, ki, r, ind, f, sample_rate_hz)
        return np.abs(lo / (1.0 + lo)) ** 2 - 0.5

    def ol_gap(f):  # |L| - 1 < 0 above the crossover
        return np.abs(open_loop(kp, ki, r, ind, f, sample_rate_hz)) - 1.0

    shape = r.shape[:1]
    bw = _first_crossing(cl_gap, f_lo, f_hi, shape)
    fc = _first_crossing(ol_gap, f_lo, f_hi, shape)
    pm = 180.0 + _phase_deg(kp, ki, r[:, 0], ind[:, 0], np.nan_to_num(fc), sample_rate_hz)
    return bw, np.where(np.isfinite(fc), pm, np.nan)


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


@dataclasses.dataclass(frozen=True)
class AxisGains:
    """PI gains of one current axis and what they achieve.

    Attributes:
        axis: "d" or "q".
        inductance_name: "Ld" or "Lq".
        inductance, resistance: the calibrated L (H) and R (ohm) the gains use.
        kp, ki: proportional (V/A) and integral (V/(A*s)) gains.
        ki_ts: discrete integrator increment ``Ki Ts`` (V/A), None in continuous time.
        kp_se, ki_se: first-order standard deviations (V/A, V/(A*s)); NaN if not calibrated.
        kp_sd_mc, ki_sd_mc: Monte Carlo standard deviations, same units.
        calibrated: both R and L of this axis were identified by the fit.
        bandwidth: achieved -3 dB closed-loop bandwidth (Hz).
        phase_margin: achieved phase margin (deg).
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

    def to_dict(self) -> dict[str, Any]:
        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "axis": self.axis,
            "inductance_name": self.inductance_name,
            "inductance": self.inductance,
            "resistance": self.resistance,
            "kp": self.kp,
            "ki": self.ki,
            "ki_ts": num(self.ki_ts),
            "kp_se_first_order": num(self.kp_se),
            "ki_se_first_order": num(self.ki_se),
            "kp_sd_monte_carlo": num(self.kp_sd_mc),
            "ki_sd_monte_carlo": num(self.ki_sd_mc),
            "calibrated": self.calibrated,
            "bandwidth_hz": self.bandwidth.to_dict(),
            "phase_margin_deg": self.phase_margin.to_dict(),
        }


@dataclasses.dataclass(frozen=True)
class CurrentLoopDesign:
    """Current-loop gains of both axes, their uncertainty and the achieved loop.

    Attributes:
        bandwidth_hz: requested bandwidth (Hz); omega_c = 2 pi bandwidth (rad/s).
        sample_rate_hz: controller sample rate (Hz), or None (continuous time).
        discretisation: the controller and loop model, in words.
        num_samples, seed: Monte Carlo draws and their seed.
        axes: d and q.
        warnings: plain-language caveats.
    """

    bandwidth_hz: float
    omega_c: float
    sample_rate_hz: float | None
    discretisation: str
    num_samples: int
    seed: int
    axes: tuple[AxisGains, ...]
    warnings: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        """The ``gains`` JSON (SI units: V/A, V/(A*s), Hz, deg)."""
        return {
            "bandwidth_hz": self.bandwidth_hz,
            "omega_c": self.omega_c,
            "sample_rate_hz": self.sample_rate_hz,
            "discretisation": self.discretisation,
            "monte_carlo": {"num_samples": self.num_samples, "seed": self.seed},
            "axes": {a.axis: a.to_dict() for a in self.axes},
            "warnings": list(self.warnings),
        }


def _draws(cal: Calibration, estimate: np.ndarray, num_samples: int, seed: int) -> np.ndarray:
    """Motors from N(estimate, Cov) over the fitted names, shape (S, len(names)); the rest fixed.

    Where the covariance is not finite outside the gains' parameters (R, Ld, Lq), only their
    block is drawn (the marginal of the same normal).
    """
    rng = np.random.default_rng(seed)
    cov = np.asarray(cal.covariance, dtype=float)
    keep = list(range(len(cal.fit_names)))
    if not np.all(np.isfinite(cov)):
        keep = [i for i, n in enumerate(cal.fit_names) if n in _GAIN_PARAMS]
        cov = cov[np.ix_(keep, keep)]
    idx = [cal.names.index(cal.fit_names[i]) for i in keep]
    out = np.broadcast_to(estimate, (num_samples, len(cal.names))).copy()
    if idx:
        out[:, idx] = rng.multivariate_normal(estimate[idx], cov, size=num_samples, method="eigh",
                                              check_valid="ignore")  # checked by from_dict
    return out


def _gain_inputs(cal: Calibration, source: str) -> np.ndarray:
    """The estimate the gains use: the fit's, the prior's for a parameter not fitted (as the fit holds it).

    Raises:
        DrivecalError: R, Ld or Lq fitted but its estimate or variance undefined, or not positive.
    """
    fix = "refit, or pass a result whose fit converged"
    estimate = np.array(cal.estimate, dtype=float)
    cov = np.asarray(cal.covariance, dtype=float)
    for name in _GAIN_PARAMS:
        i = cal.names.index(name)
        fitted = name in cal.fit_names
        if not math.isfinite(estimate[i]):
            if fitted:
                raise DrivecalError(f"{source}: parameters.{name}.estimate is null; gains need every inductance "
                                    f"and R estimated — {fix}.")
            estimate[i] = float(getattr(cal.prior, name))
        if not estimate[i] > 0:
            what = "estimate" if fitted else "prior"
            raise DrivecalError(f"{source}: parameters.{name}.{what} is {estimate[i]:.6g}; gains need a positive "
                                f"R, Ld and Lq — {fix}.")
    block = [cal.fit_names.index(n) for n in _GAIN_PARAMS if n in cal.fit_names]
    sub = cov[np.ix_(block, block)]
    if not np.all(np.isfinite(sub)):
        bad = cal.fit_names[block[int(np.argwhere(~np.isfinite(sub))[0, 0])]]
        raise DrivecalError(f"{source}: covariance of {bad} is null; the gains' uncertainty needs the covariance of "
                            f"every fitted R and L — {fix}.")
    return estimate


def design_current_loop(
    cal: Calibration,
    bandwidth_hz: float,
    *,
    sample_rate_hz: float | None = None,
    num_samples: int = 4000,
    seed: int = 0,
    source: str = "the calibration",
) -> CurrentLoopDesign:
    """PI gains for both current axes, their uncertainty, and the loop they achieve.

    Args:
        cal: a single calibration (``Calibration.from_dict`` of a saved result works).
        bandwidth_hz: requested closed-loop bandwidth (Hz), > 0.
        sample_rate_hz: controller sample rate (Hz); None judges the loop in
            continuous time. Must be at least ``bandwidth / MAX_BANDWIDTH_FRACTION``.
        num_samples: Monte Carlo draws from the parameter covariance.
        seed: Monte Carlo seed.
        source: where ``cal`` came from (the result file), for messages.

    A parameter the fit did not identify keeps its prior value (and the
    gains that use it have no uncertainty, with a warning).

    Raises:
        DrivecalError: non-positive bandwidth or sample rate, a bandwidth too
            high for the sample rate, R, Ld or Lq not estimated (null, or not
            positive), the covariance of a fitted one undefined, or so wide that
            (almost) every Monte Carlo draw has a non-positive R or L.
    """
    if not (bandwidth_hz > 0 and math.isfinite(bandwidth_hz)):
        raise DrivecalError(f"--bandwidth {bandwidth_hz}: must be a positive number of Hz, e.g. 1000.")
    if sample_rate_hz is not None:
        if not (sample_rate_hz > 0 and math.isfinite(sample_rate_hz)):
            raise DrivecalError(f"--sample-rate {sample_rate_hz}: must be a positive number of Hz, e.g. 20000.")
        if bandwidth_hz > MAX_BANDWIDTH_FRACTION * sample_rate_hz:
            raise DrivecalError(
                f"--bandwidth {bandwidth_hz:g} Hz is above {MAX_BANDWIDTH_FRACTION:g} x --sample-rate "
                f"{sample_rate_hz:g} Hz; lower the bandwidth to at most {MAX_BANDWIDTH_FRACTION * sample_rate_hz:g} "
                "Hz or raise the sample rate."
            )
    if not all(n in cal.names for n in _GAIN_PARAMS):
        raise DrivecalError(f"{source}: the result does not estimate R, Ld and Lq; gains need all three.")
    w_c = 2.0 * math.pi * bandwidth_hz
    estimate = _gain_inputs(cal, source)
    est = dict(zip(cal.names, estimate))
    fit_idx = {n: i for i, n in enumerate(cal.fit_names)}
    cov = np.asarray(cal.covariance, dtype=float)
    draws = _draws(cal, estimate, num_samples, seed)
    col = {n: draws[:, i] for i, n in enumerate(cal.names)}
    ok = np.all(draws[:, [cal.names.index(n) for n in _GAIN_PARAMS]] > 0, axis=1)
    warnings = []
    if ok.sum() < 2:
        raise DrivecalError(f"{source}: {int((~ok).sum())} of {num_samples} Monte Carlo draws from the covariance "
                            "have a non-positive R or L, too few left to judge the loop; refit with more data (a "
                            "covariance this wide does not calibrate the motor).")
    if not ok.all():
        warnings.append(f"{int((~ok).sum())} of {num_samples} Monte Carlo draws had a non-positive R or L and "
                        "were dropped")
    ts = None if sample_rate_hz is None else 1.0 / sample_rate_hz

    def first_order_sd(name: str) -> float:
        # d(gain)/d(theta) is w_c on the one parameter the gain is proportional to.
        return w_c * math.sqrt(cov[fit_idx[name], fit_idx[name]]) if name in fit_idx else math.nan

    axes = []
    for axis, lname in AXES:
        r, ind = est["R"], est[lname]
        kp, ki = pi_gains(r, ind, bandwidth_hz)
        calibrated = "R" in fit_idx and lname in fit_idx
        kp_mc, ki_mc = pi_gains(col["R"][ok], col[lname][ok], bandwidth_hz)
        bw0, pm0 = loop_metrics(kp, ki, r, ind, bandwidth_hz, sample_rate_hz)
        bw, pm = loop_metrics(kp, ki, col["R"][ok], col[lname][ok], bandwidth_hz, sample_rate_hz)
        axes.append(AxisGains(
            axis=axis,
            inductance_name=lname,
            inductance=float(ind),
            resistance=float(r),
            kp=float(kp),
            ki=float(ki),
            ki_ts=None if ts is None else float(ki * ts),
            kp_se=first_order_sd(lname),
            ki_se=first_order_sd("R"),
            kp_sd_mc=float(np.std(kp_mc, ddof=1)) if lname in fit_idx else math.nan,
            ki_sd_mc=float(np.std(ki_mc, ddof=1)) if "R" in fit_idx else math.nan,
            calibrated=calibrated,
            bandwidth=Spread.of(bw0[0], bw),
            phase_margin=Spread.of(pm0[0], pm),
        ))
        if not calibrated:
            missing = [n for n in ("R", lname) if n not in fit_idx]
            warnings.append(f"{axis} axis: {', '.join(missing)} not identified by this calibration; its gains use "
                            "the prior value and their uncertainty is unknown")
    if sample_rate_hz is None:
        disc = "continuous-time PI C(s) = Kp + Ki/s on G(s) = 1/(L s + R), no delay"
    else:
        disc = (f"discrete PI at {sample_rate_hz:g} Hz: u[k] = Kp e[k] + x[k], x[k+1] = x[k] + Ki*Ts e[k] "
                "(forward-Euler integrator), ZOH plant, one-sample computation delay")
    return CurrentLoopDesign(
        bandwidth_hz=float(bandwidth_hz),
        omega_c=w_c,
        sample_rate_hz=None if sample_rate_hz is None else float(sample_rate_hz),
        discretisation=disc,
        num_samples=int(num_samples),
        seed=int(seed),
        axes=tuple(axes),
        warnings=tuple(warnings),
    )
