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
from drivecal.data import choose_speed, inspect_log, load_bench, speed_lattice, speed_resolution, update_period

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


def _bench(w: np.ndarray, noise: float = 0.02) -> dc.BenchData:
    """A free segment with speed ``w`` and currents of 5 A on q plus ``noise`` (no engine: choose_speed reads
    only the speed, the currents' noise and their flux)."""
    n = w.size
    currents = np.stack([np.zeros(n), np.full(n, 5.0)], axis=1) + np.random.default_rng(1).normal(0, noise, (n, 2))
    seg = dc.SegmentData("free spin-up", False, np.arange(n) / 1000.0, np.zeros((n, 2)), currents, w_m=w)
    return dc.BenchData((seg,), 1000.0, "b.csv")


def test_choose_speed_takes_a_coarse_speed_as_an_output_where_j_and_b_are_known_and_says_why():
    coarse, names = _bench(_encoder_speed(1000.0)), dc.ESTIMATED
    choice = choose_speed(coarse, dc.DEFAULT_MOTOR, names)
    assert choice.mode == "output" and choice.flagged and choice.requested is None
    assert choice.ratio > 10 and "a second measured output instead" in choice.reason
    kept = choose_speed(coarse, dc.DEFAULT_MOTOR, names, mechanics_given=False)
    assert kept.mode == "input" and kept.flagged and "states no J and B" in kept.reason
    asked = choose_speed(coarse, dc.DEFAULT_MOTOR, names, speed="input")
    assert asked.mode == "input" and "--simulated-speed" in asked.reason
    assert choose_speed(coarse, dc.DEFAULT_MOTOR, names, speed="output").reason == ""
    # noise-free currents leave nothing to weigh the speed against: not judged
    clean = choose_speed(_bench(_encoder_speed(1000.0), noise=0.0), dc.DEFAULT_MOTOR, names)
    assert clean.mode == "input" and clean.ratio is None and not clean.flagged
    # a motor file states J and B or not
    assert dc.motor_from_dict({"R": 0.45, "J": 1e-3, "B": 1e-4}).mechanics_given
    assert not dc.motor_from_dict({"R": 0.45}).mechanics_given


def test_inspect_names_the_steps_of_a_quantised_speed_channel(tmp_path):
    w = _encoder_speed(1000.0)
    log = tmp_path / "run.csv"
    rows = "".join(f"{k / 1000.0!r},0,12,0,5,{float(x)!r}\n" for k, x in enumerate(w))
    log.write_text("time,Ud,Uq,Id,Iq,n_mech\n" + rows)  # speed in rad/s (no unit stated: taken as SI)
    found = inspect_log(log)
    assert found.columns["w_m"] == "n_mech"
    assert found.speed == "steps of 1.534 rad/s: one count of a 4096-count encoder per 1 ms, new every sample"
