"""How exact a measured speed is (issue 22, item 3): the steps of an encoder's difference, the update
period of a held speed, its noise, and what a fit makes of it (``drivecal.data._speed``).

Detection is exact arithmetic on the samples, so the tests are too: a lattice is found to float
rounding, and never in a continuous speed however noisy (400 noisy series, four noise levels).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal.data import choose_speed, load_bench, speed_lattice, speed_resolution, update_period

COUNTS = 4096
STEP = 2 * math.pi / COUNTS * 1000.0  # one count per 1 ms: 1.534 rad/s


def _angle(fs: float, duration: float = 0.05, tau: float = 0.01, top: float = 45.0, phase: float = 0.0):
    """A spin-up's angle (rad) at fs: speed top * (1 - exp(-t / tau))."""
    t = np.arange(int(round(duration * fs))) / fs
    return top * (t - tau * (1 - np.exp(-t / tau))) + phase


def _encoder_speed(fs: float, hold: int = 1, **kw) -> np.ndarray:
    """The count difference over each update of ``hold`` samples at fs, held in between."""
    count = np.floor(_angle(fs, **kw) / (2 * math.pi / COUNTS))
    at = (np.arange(count.size) // hold) * hold
    earlier = np.clip(at - hold, 0, None)
    return (count[at] - count[earlier]) * (2 * math.pi / COUNTS) * fs / hold


def test_a_4096_count_encoder_differenced_at_1_khz_is_found_to_its_step():
    w = _encoder_speed(1000.0)
    res = speed_resolution([w], 1000.0)
    assert res.step == pytest.approx(STEP, rel=1e-9) and res.hold == 1 and res.counts_per_rev == COUNTS
    assert res.describe() == "steps of 1.534 rad/s: one count of a 4096-count encoder per 1 ms, new every sample"
    # a count difference holds two rounding errors: step / sqrt(6) RMS, what the fit weighs it by
    assert res.quantisation == pytest.approx(STEP / math.sqrt(6)) and res.sigma == pytest.approx(res.quantisation,
                                                                                                   rel=0.05)
    # as stored in float32 (MDF4, TDMS), logged in rpm and converted, or shifted by an offset: the same lattice
    assert speed_lattice(w.astype(np.float32)) == pytest.approx(STEP, rel=1e-7)
    assert speed_lattice(np.round(w * 30 / math.pi) * math.pi / 30) == pytest.approx(math.pi / 30, rel=1e-9)
    assert speed_lattice(w + 0.3) == pytest.approx(STEP, rel=1e-9)


def test_a_speed_updated_at_1_khz_and_logged_at_20_khz_is_found_held():
    w = _encoder_speed(20_000.0, hold=20)
    res = speed_resolution([w], 20_000.0)
    assert update_period([w]) == 20 and res.hold == 20
    assert res.step == pytest.approx(STEP, rel=1e-9) and res.counts_per_rev == COUNTS
    assert res.describe().endswith("per 1 ms, each held 20 samples")
    assert res.sigma == pytest.approx(STEP / math.sqrt(6) * math.sqrt(20))  # one error repeated 20 times


def test_no_lattice_in_a_continuous_speed_however_noisy():
    rng = np.random.default_rng(22)
    for fs in (1000.0, 20_000.0):
        smooth = np.diff(_angle(fs), prepend=0.0) * fs
        assert speed_lattice(smooth) is None
        for sigma in (1e-4, 1e-2, 0.05, 1.0):
            for _ in range(50):
                noisy = smooth + rng.normal(0.0, sigma, smooth.shape)
                assert speed_lattice(noisy) is None
                assert speed_lattice(noisy.astype(np.float32)) is None
                res = speed_resolution([noisy], fs)
                assert res.step is None and res.hold == 1
        # a resolution finer than a 10 000th of the span is no quantisation worth the name
        assert speed_lattice(np.round(smooth + rng.normal(0.0, 0.05, smooth.shape), 3)) is None
    # too few distinct values to tell: a rotor at rest, or one step
    assert speed_lattice(np.zeros(100)) is None and speed_lattice(np.r_[np.zeros(50), np.ones(50)]) is None


def test_the_noise_of_a_continuous_speed_is_its_sigma():
    rng = np.random.default_rng(3)
    smooth = np.diff(_angle(20_000.0, duration=0.2), prepend=0.0) * 20_000.0
    res = speed_resolution([smooth + rng.normal(0.0, 0.05, smooth.shape)], 20_000.0)
    assert res.step is None and res.quantisation == 0.0
    assert res.sigma == pytest.approx(0.05, rel=0.1)  # the robust level's scatter at 4000 samples is ~2 %


def test_an_exact_speed_stays_the_input():
    """The shipped bench (default plan at 20 kHz, the engine's exact speed, 20 mA): nothing flagged."""
    bench = load_bench(Path(__file__).resolve().parents[2] / "examples" / "bench.csv")
    choice = choose_speed(bench, dc.DEFAULT_MOTOR, dc.ESTIMATED)
    assert choice.mode == "input" and not choice.flagged and choice.reason == ""
    assert bench.speed_resolution().step is None and choice.ratio < 1e-3
