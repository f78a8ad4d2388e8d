"""An incremental encoder on the synthetic bench: the angle in whole counts, the speed their difference."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..data import BenchData


def encoder_readings(bench: BenchData, counts: int, pole_pairs: float) -> BenchData:
    """``bench`` as a drive with a ``counts``-count encoder records it.

    The encoder's mechanical angle ``theta_e / pole_pairs`` (the recorded angle, its offset included)
    is floored to whole counts of ``2 pi / counts``; ``theta_e`` becomes that angle again in electrical
    radians and ``w_m`` the difference of two consecutive counts over one sample period: steps of
    ``2 pi / counts * sample_rate`` (4096 counts at 1 kHz: 1.534 rad/s), the mean speed over the
    sample period before (half a period late). A segment from rest starts at 0 rad/s; one that
    continues the previous segment differences against that one's last count.

    Args:
        bench: with ``theta_e`` and ``w_m`` recorded (``engine_bench(..., record_speed=True)``,
            ``pwm_bench(..., record_speed=True)``).
        counts: the encoder's counts per mechanical revolution (>= 1).
        pole_pairs: the motor's (theta_e is electrical).
    """
    if not (isinstance(counts, (int, np.integer)) and counts >= 1):
        raise ValueError(f"encoder counts must be a whole number >= 1, got {counts!r}")
    if any(s.theta_e is None for s in bench.segments):
        raise ValueError("an encoder needs the rotor angle recorded (record_speed=True)")
    step = 2.0 * math.pi / int(counts)
    segments, last = [], None
    for seg in bench.segments:
        angle = np.floor(seg.theta_e / pole_pairs / step) * step
        before = np.concatenate([[angle[0] if last is None or not seg.continues else last], angle[:-1]])
        segments.append(dataclasses.replace(seg, theta_e=angle * pole_pairs,
                                            w_m=(angle - before) * bench.sample_rate))
        last = angle[-1]
    return dataclasses.replace(bench, segments=tuple(segments))
