"""Excitation waveforms: one applied voltage per sample (V), held between samples.

Each generator takes the number of samples ``n`` and the sample rate (Hz) and
returns an array of shape (n,). Value k is applied on ``[t_k, t_k+1)`` with
``t_k = k / sample_rate``. Amplitudes are peak values about ``offset``, so the
largest ``|v|`` of a waveform is ``|offset| + amplitude``; the plan's feasibility
check then holds the two axes together inside the voltage circle.

One definition serves the plan files and the D-optimal design: ``xp`` picks
the array module, ``numpy`` (the default) or ``jax.numpy``, with which the
levels, amplitudes, offsets, frequencies and durations may be traced (the
design differentiates the waveforms through them). The plan's checks of those
numbers (Nyquist, positive frequencies) run where they are plain numbers.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import numpy as np

from ..errors import PlanError

#: Below this sweep rate ``|ln(f_stop/f_start)| / duration`` (1/s) a log chirp is the plain sine: its
#: phase ``expm1(k t) / k`` (and, under JAX, the derivative in k) loses its digits as k goes to 0.
FLAT_SWEEP_RATE = 1e-9


def _concrete(*values: Any) -> bool:
    """All plain numbers (Python or numpy scalars), not arrays of ``jax.numpy`` or their tracers."""
    return all(isinstance(v, (int, float, np.number)) for v in values)


def _times(n: int, sample_rate: float, xp: Any = np) -> Any:
    return xp.arange(n) / sample_rate


def step(n: int, sample_rate: float, *, level: Any, initial: Any = 0.0, delay: float = 0.0, xp: Any = np) -> Any:
    """``initial`` (V) before ``delay`` (s), ``level`` (V) from then on."""
    return xp.where(_times(n, sample_rate, xp) >= delay - 0.5 / sample_rate, level, initial).astype(float)


def ramp(n: int, sample_rate: float, *, level: Any, rise: Any, initial: Any = 0.0, delay: float = 0.0,
         xp: Any = np) -> Any:
    """``initial`` (V) until ``delay`` (s), then a straight line to ``level`` (V) over ``rise`` (s), ``level`` after.

    Sample k holds the line's value at ``t_k = k / sample_rate``. An open-loop spin-up on a ramp
    accelerates the rotor at a steady current instead of the surge of a voltage step.
    """
    if _concrete(rise) and not rise > 0:
        raise PlanError(f"ramp: rise must be a positive time, got {rise} s.")
    share = xp.clip((_times(n, sample_rate, xp) - delay) / rise, 0.0, 1.0)
    return initial + (level - initial) * share


def chirp(
    n: int,
    sample_rate: float,
    *,
    amplitude: Any,
    f_start: Any,
    f_stop: Any,
    sweep: str = "linear",
    offset: Any = 0.0,
    phase: float = 0.0,
    duration: Any = None,
    xp: Any = np,
) -> Any:
    """Swept sine ``offset + amplitude*sin(phi(t) + phase)`` from ``f_start`` to ``f_stop`` (Hz).

    ``sweep`` is ``"linear"`` (frequency linear in time) or ``"log"``
    (exponential: equal time per octave). The sweep spans ``duration`` (s),
    the whole segment (``n / sample_rate``) unless given.
    """
    if _concrete(f_start, f_stop):
        if not (0 < f_start and 0 < f_stop):
            raise PlanError(f"chirp: f_start and f_stop must be positive, got {f_start} Hz and {f_stop} Hz.")
        if max(f_start, f_stop) >= sample_rate / 2:
            raise PlanError(
                f"chirp: {max(f_start, f_stop):g} Hz is at or above the Nyquist frequency {sample_rate / 2:g} Hz; "
                "lower f_stop."
            )
    t = _times(n, sample_rate, xp)
    duration = n / sample_rate if duration is None else duration
    if sweep == "linear":
        phi = 2 * math.pi * (f_start * t + 0.5 * (f_stop - f_start) / duration * t**2)
    elif sweep == "log":
        ratio = f_stop / f_start
        k = (math.log(ratio) if _concrete(ratio) else xp.log(ratio)) / duration
        bent = xp.abs(k) > FLAT_SWEEP_RATE
        safe_k = xp.where(bent, k, 1.0)  # no 0/0, nor its NaN derivative, where the sweep is flat
        phi = xp.where(bent, 2 * math.pi * f_start * xp.expm1(safe_k * t) / safe_k, 2 * math.pi * f_start * t)
    else:
        raise PlanError(f"chirp: sweep must be 'linear' or 'log', got {sweep!r}.")
    return offset + amplitude * xp.sin(phi + phase)


def multisine(
    n: int,
    sample_rate: float,
    *,
    amplitude: float,
    f_min: float,
    f_max: float,
    num_tones: int = 16,
    offset: float = 0.0,
) -> np.ndarray:
    """Schroeder-phased multisine with peak ``amplitude`` (V) about ``offset``.

    ``num_tones`` equal-amplitude tones on harmonics of the segment's base
    frequency ``sample_rate / n``, spread logarithmically over
    ``[f_min, f_max]`` (Hz). Schroeder phases ``phi_k = -pi*k*(k-1)/K`` keep
    the crest factor low; the sum is then scaled so its peak is ``amplitude``.
    """
    base = sample_rate / n
    if not (0 < f_min < f_max < sample_rate / 2):
        raise PlanError(
            f"multisine: need 0 < f_min < f_max < Nyquist ({sample_rate / 2:g} Hz), got {f_min:g} and {f_max:g} Hz."
        )
    if num_tones < 1:
        raise PlanError(f"multisine: num_tones must be at least 1, got {num_tones}.")
    lo, hi = max(1, math.ceil(f_min / base)), math.floor(f_max / base)
    if hi < lo:
        raise PlanError(
            f"multisine: no harmonic of the segment frequency {base:g} Hz lies in [{f_min:g}, {f_max:g}] Hz; "
            "lengthen the segment or widen the band."
        )
    harmonics = np.unique(np.round(np.geomspace(lo, hi, num_tones)).astype(int))
    return schroeder_tones(_times(n, sample_rate), harmonics, amplitude=amplitude, offset=offset, base=base)


def schroeder_tones(t: Any, frequencies: Any, *, amplitude: Any, offset: Any = 0.0, base: float = 1.0,
                    window: Any = None, xp: Any = np) -> Any:
    """Equal tones at ``base * frequencies`` (Hz) with Schroeder phases, scaled to peak ``amplitude`` about ``offset`` (V).

    The multisine's signal at times ``t`` (s), shape (len(t),): tone k of K has
    phase ``-pi*k*(k-1)/K``, which keeps the crest factor low; the sum is
    divided by its peak |value| over the samples where ``window`` is true (all
    of them by default). :func:`multisine` puts the tones on harmonics of the
    segment (``base`` its frequency); the D-optimal design's smooth stand-in
    on frequencies that move continuously with the band.
    """
    count = frequencies.shape[-1]
    phases = -math.pi * np.arange(1, count + 1) * np.arange(count) / count
    signal = xp.sin(2 * math.pi * base * xp.outer(t, frequencies) + phases).sum(axis=1)
    magnitude = xp.abs(signal) if window is None else xp.where(window, xp.abs(signal), 0.0)
    return offset + amplitude * signal / xp.max(magnitude)


#: Feedback taps of maximal-length Fibonacci LFSRs (x^order + ... + 1), orders 2..16.
_MLS_TAPS: dict[int, tuple[int, ...]] = {
    2: (2, 1), 3: (3, 2), 4: (4, 3), 5: (5, 3), 6: (6, 5), 7: (7, 6), 8: (8, 6, 5, 4),
    9: (9, 5), 10: (10, 7), 11: (11, 9), 12: (12, 11, 10, 4), 13: (13, 12, 11, 8),
    14: (14, 13, 12, 2), 15: (15, 14), 16: (16, 15, 13, 4),
}


def maximal_length_sequence(order: int, seed: int = 1) -> np.ndarray:
    """One period (``2**order - 1`` bits) of a maximal-length sequence, values 0/1."""
    return _maximal_length_sequence(order, seed).copy()


@functools.lru_cache(maxsize=16)
def _maximal_length_sequence(order: int, seed: int) -> np.ndarray:
    # Cached: the design rebuilds its PRBS voltages at every trace (up to 65535 bits by a Python loop).
    if order not in _MLS_TAPS:
        raise PlanError(f"prbs: order must be between 2 and 16, got {order}.")
    state = seed % (2**order - 1) + 1  # any non-zero state
    bits = np.empty(2**order - 1, dtype=np.int8)
    for i in range(bits.size):
        bits[i] = state & 1
        feedback = 0
        for tap in _MLS_TAPS[order]:
            feedback ^= (state >> (order - tap)) & 1
        state = (state >> 1) | (feedback << (order - 1))
    return bits


def prbs(
    n: int,
    sample_rate: float,
    *,
    amplitude: Any,
    order: int = 9,
    bit_rate: float | None = None,
    offset: Any = 0.0,
    seed: int = 1,
    xp: Any = np,
) -> Any:
    """Maximal-length PRBS switching between ``offset - amplitude`` and ``offset + amplitude`` (V).

    Each bit lasts ``round(sample_rate / bit_rate)`` samples (one sample when
    ``bit_rate`` is None); the sequence repeats after ``2**order - 1`` bits.
    """
    hold = 1 if bit_rate is None else int(round(sample_rate / bit_rate))
    if hold < 1:
        raise PlanError(f"prbs: bit_rate {bit_rate:g} Hz is above the sample rate {sample_rate:g} Hz.")
    bits = _maximal_length_sequence(order, seed)
    # Sample k carries bit (k // hold) of the repeating sequence: O(n) memory whatever the hold (a bit rate far
    # below the sample rate must not build the whole held sequence first).
    levels = 2.0 * bits[(np.arange(n) // min(hold, max(n, 1))) % bits.size] - 1.0
    return offset + amplitude * xp.asarray(levels)


def samples(n: int, sample_rate: float, *, values) -> np.ndarray:
    """A measured sequence (V), one value per sample, used as it is."""
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise PlanError(f"samples: got {arr.size} values for a segment of {n} samples; give one value per sample.")
    return arr


#: Waveform kinds by their name in plan files.
GENERATORS = {"step": step, "ramp": ramp, "chirp": chirp, "multisine": multisine, "prbs": prbs, "samples": samples}
