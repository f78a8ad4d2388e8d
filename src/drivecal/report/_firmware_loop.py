"""The sampled current loop of one axis: its frequency response, its figures of merit, and the loop gain that
meets a specification (the method is described in :mod:`drivecal.report._gains`).

Pure numpy, SI units; every function broadcasts over motors (R in ohm, L in H).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: Lowest phase margin (deg) a design may have: below it the loop rings (about 9 dB of peaking at 30 deg).
MIN_PHASE_MARGIN = 30.0


def pi_gains(resistance: Any, inductance: Any, bandwidth_hz: float) -> tuple[Any, Any]:
    """Continuous-time pole-zero-cancelling PI gains ``(Kp [V/A], Ki [V/(A*s)])`` for a crossover (Hz)."""
    w_c = 2.0 * math.pi * bandwidth_hz
    return inductance * w_c, resistance * w_c


def _held_plant(resistance, inductance, ts, delay_samples):
    """``(a, b0, b1, n)`` of the sampled plant ``z^-n (b0 + b1/z)/(z - a)`` (b in A/(V) per sample, see module)."""
    d = np.maximum(np.asarray(delay_samples, dtype=float), 0.0)
    n = np.floor(d)
    m = d - n
    x = resistance * ts / inductance
    a = np.exp(-x)
    c = np.exp(-x * (1.0 - m))
    return a, -np.expm1(-x * (1.0 - m)) / resistance, (c - a) / resistance, n


def open_loop(kp, ki, resistance, inductance, freq_hz, sample_rate_hz: float | None = None,
              delay_samples: Any = 1.0):
    """Open-loop frequency response ``C G`` (continuous) or ``C(z) G(z)`` with the delay (discrete), complex.

    All arguments broadcast; ``freq_hz`` in Hz, gains in V/A and V/(A*s),
    resistance (ohm), inductance (H), ``delay_samples`` (samples; ignored in
    continuous time).
    """
    w = 2.0 * np.pi * np.asarray(freq_hz)
    if sample_rate_hz is None:
        s = 1j * w
        return (kp + ki / s) / (inductance * s + resistance)
    ts = 1.0 / sample_rate_hz
    z = np.exp(1j * w * ts)
    a, b0, b1, n = _held_plant(resistance, inductance, ts, delay_samples)
    return (kp + ki * ts / (z - 1.0)) * z ** (-n) * (b0 + b1 / z) / (z - a)


def _phase_deg(kp, ki, resistance, inductance, freq_hz, sample_rate_hz, delay_samples=1.0):
    # Sum of the factors' angles: no wrap-around at -180 deg (np.angle of the product would wrap).
    w = 2.0 * np.pi * np.asarray(freq_hz)
    if sample_rate_hz is None:
        s = 1j * w
        return np.degrees(np.angle(kp + ki / s) - np.angle(inductance * s + resistance))
    ts = 1.0 / sample_rate_hz
    z = np.exp(1j * w * ts)
    a, b0, b1, n = _held_plant(resistance, inductance, ts, delay_samples)
    return np.degrees(np.angle(kp + ki * ts / (z - 1.0)) + np.angle(b0 + b1 / z) - np.angle(z - a) - n * w * ts)


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


def _f_range(ref_hz: float, sample_rate_hz: float | None) -> tuple[float, float]:
    """The search range (Hz) around a reference frequency: to 1000x it, or to just below Nyquist."""
    return ref_hz * 1e-3, ref_hz * 1e3 if sample_rate_hz is None else 0.5 * sample_rate_hz * (1.0 - 1e-9)


def loop_figures(kp, ki, resistance, inductance, ref_hz: float, sample_rate_hz: float | None = None,
                 delay_samples: Any = 1.0):
    """Crossover (Hz), -3 dB closed-loop bandwidth (Hz) and phase margin (deg) of PI gains on motors (R, L).

    Args:
        kp, ki: the controller's gains (scalars).
        resistance, inductance: the true motor's R (ohm) and L (H), shape (S,).
        ref_hz: a frequency near the loop's (the design's): sets the search range.
        sample_rate_hz: controller sample rate (Hz), or None for continuous time.
        delay_samples: the command's delay (samples, scalar or shape (S,)); discrete only.

    Returns:
        ``(crossover_hz, bandwidth_hz, phase_margin_deg)``, each shape (S,);
        NaN where the loop gain never crosses 1 (the closed loop never falls
        below -3 dB) before ``1000 ref_hz`` or Nyquist.
    """
    r = np.atleast_1d(np.asarray(resistance, dtype=float))[:, None]
    ind = np.atleast_1d(np.asarray(inductance, dtype=float))[:, None]
    dly = np.broadcast_to(np.asarray(delay_samples, dtype=float), r.shape[:1])[:, None]
    f_lo, f_hi = _f_range(ref_hz, sample_rate_hz)

    def cl_gap(f):  # |T|^2 - 1/2 < 0 above the -3 dB point
        lo = open_loop(kp, ki, r, ind, f, sample_rate_hz, dly)
        return np.abs(lo / (1.0 + lo)) ** 2 - 0.5

    def ol_gap(f):  # |L| - 1 < 0 above the crossover
        return np.abs(open_loop(kp, ki, r, ind, f, sample_rate_hz, dly)) - 1.0

    shape = r.shape[:1]
    bw = _first_crossing(cl_gap, f_lo, f_hi, shape)
    fc = _first_crossing(ol_gap, f_lo, f_hi, shape)
    pm = 180.0 + _phase_deg(kp, ki, r[:, 0], ind[:, 0], np.nan_to_num(fc), sample_rate_hz, dly[:, 0])
    return fc, bw, np.where(np.isfinite(fc), pm, np.nan)


def loop_metrics(kp, ki, resistance, inductance, bandwidth_hz: float, sample_rate_hz: float | None = None,
                 delay_samples: Any = 1.0):
    """``(bandwidth_hz, phase_margin_deg)`` of :func:`loop_figures` (``bandwidth_hz`` sets the search range)."""
    _, bw, pm = loop_figures(kp, ki, resistance, inductance, bandwidth_hz, sample_rate_hz, delay_samples)
    return bw, pm


def _shape(freq_hz, resistance, inductance, sample_rate_hz, delay_samples):
    """``H(f)`` of the cancelled loop ``L = g H`` (complex; see the module docstring); arguments broadcast."""
    w = 2.0 * np.pi * np.asarray(freq_hz, dtype=float)
    if sample_rate_hz is None:
        return 1.0 / (1j * w)
    ts = 1.0 / sample_rate_hz
    z = np.exp(1j * w * ts)
    a, b0, b1, n = _held_plant(resistance, inductance, ts, delay_samples)
    scale = resistance / -np.expm1(-resistance * ts / inductance)  # R/(1 - a)
    return z ** (-n) * scale * (b0 + b1 / z) / (z - 1.0)


def _shape_margin(freq_hz, resistance, inductance, sample_rate_hz, delay_samples):
    """``180 + arg H(f)`` (deg), unwrapped: the phase margin of a crossover at ``f``."""
    if sample_rate_hz is None:
        return np.full(np.shape(freq_hz), 90.0)
    th = 2.0 * np.pi * np.asarray(freq_hz, dtype=float) / sample_rate_hz
    a, b0, b1, n = _held_plant(resistance, inductance, 1.0 / sample_rate_hz, delay_samples)
    return 90.0 + np.degrees(np.angle(b0 + b1 * np.exp(-1j * th)) - n * th - th / 2)


def _margin_crossover(pm_deg, resistance, inductance, sample_rate_hz, delay_samples):
    """The crossover (Hz) where the cancelled loop has ``pm_deg`` of margin, per motor (shape (S,))."""
    r, ind = np.atleast_1d(resistance)[:, None], np.atleast_1d(inductance)[:, None]
    dly = np.broadcast_to(np.asarray(delay_samples, dtype=float), r.shape[:1])[:, None]
    return _first_crossing(lambda f: _shape_margin(f, r, ind, sample_rate_hz, dly) - pm_deg,
                           sample_rate_hz * 1e-7, 0.5 * sample_rate_hz * (1.0 - 1e-9), r.shape[:1])


def loop_gain_for(kind: str, value: float, resistance, inductance, sample_rate_hz: float | None,
                  delay_samples: Any = 1.0):
    """The loop gain ``g`` (``L = g H``) meeting one specification, per motor (arrays broadcast).

    Args:
        kind: "crossover" (Hz), "bandwidth" (closed-loop -3 dB, Hz) or "phase_margin" (deg; discrete only).
        value: the specification's value.
        resistance, inductance: R (ohm), L (H).
        sample_rate_hz, delay_samples: the loop (None: continuous time, no delay).
    """
    if kind == "phase_margin":
        f = _margin_crossover(value, resistance, inductance, sample_rate_hz, delay_samples)
        return 1.0 / np.abs(_shape(f, resistance, inductance, sample_rate_hz, delay_samples))
    h = _shape(value, resistance, inductance, sample_rate_hz, delay_samples)
    if kind == "crossover":
        return 1.0 / np.abs(h)
    m2 = np.abs(h) ** 2
    return (h.real + np.sqrt(h.real**2 + m2)) / m2


def gains_from_loop_gain(g, resistance, inductance, sample_rate_hz: float | None):
    """``(Kp [V/A], Ki [V/(A*s)])`` of a loop gain ``g``: continuous ``(g L, g R)``, discrete ``(g R/(1-a), g R/Ts)``.
    """
    if sample_rate_hz is None:
        return g * inductance, g * resistance
    ts = 1.0 / sample_rate_hz
    return g * resistance / -np.expm1(-resistance * ts / inductance), g * resistance / ts


def design_gains(kind: str, value: float, resistance, inductance, sample_rate_hz: float | None,
                 delay_samples: Any = 1.0):
    """``(Kp, Ki)`` meeting the specification on motors (R, L) (arrays broadcast); see :func:`loop_gain_for`."""
    g = loop_gain_for(kind, value, resistance, inductance, sample_rate_hz, delay_samples)
    return gains_from_loop_gain(g, resistance, inductance, sample_rate_hz)


def reachable(resistance: float, inductance: float, sample_rate_hz: float, delay_samples: float) -> dict[str, float]:
    """What a sampled loop with this delay can reach with at least :data:`MIN_PHASE_MARGIN` of margin.

    Returns:
        ``{"max_crossover_hz", "max_bandwidth_hz", "min_phase_margin_deg", "max_phase_margin_deg"}``
        (the -3 dB bandwidth at the highest crossover; the margin tends to
        90 deg as the crossover goes to zero).
    """
    fc = float(_margin_crossover(MIN_PHASE_MARGIN, resistance, inductance, sample_rate_hz, delay_samples)[0])
    kp, ki = design_gains("crossover", fc, resistance, inductance, sample_rate_hz, delay_samples)
    _, bw, _ = loop_figures(kp, ki, resistance, inductance, fc, sample_rate_hz, delay_samples)
    return {"max_crossover_hz": fc, "max_bandwidth_hz": float(bw[0]), "min_phase_margin_deg": MIN_PHASE_MARGIN,
            "max_phase_margin_deg": 90.0}
