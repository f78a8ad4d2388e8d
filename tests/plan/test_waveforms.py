"""Excitation waveforms: each has the property its name promises."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.plan import waveforms as wf

FS = 20_000.0


@pytest.mark.parametrize("order", [3, 5, 7, 9, 11, 16])
def test_prbs_is_maximal_length(order):
    bits = wf.maximal_length_sequence(order)
    # A maximal-length LFSR visits every non-zero state once: 2^(n-1) ones, 2^(n-1)-1 zeros,
    # and its +/-1 autocorrelation is -1 at every non-zero circular lag.
    assert bits.size == 2**order - 1
    assert bits.sum() == 2 ** (order - 1)
    s = 2.0 * bits - 1.0
    lags = [1, 2, 3, bits.size // 2] if order == 16 else range(1, bits.size)
    for lag in lags:
        assert np.dot(s, np.roll(s, lag)) == -1.0


def test_prbs_levels_and_bit_length():
    v = wf.prbs(400, FS, amplitude=6.0, offset=2.0, order=5, bit_rate=2_000.0)
    assert set(np.unique(v)) == {-4.0, 8.0}
    runs = np.diff(np.flatnonzero(np.diff(v) != 0))
    assert np.all(runs % 10 == 0)  # 20 kHz / 2 kHz = 10 samples per bit


def test_chirp_matches_scipy_reference():
    from scipy.signal import chirp as scipy_chirp

    n = 4000
    t = np.arange(n) / FS
    for sweep, method in (("linear", "linear"), ("log", "logarithmic")):
        v = wf.chirp(n, FS, amplitude=3.0, offset=1.0, f_start=50.0, f_stop=2_000.0, sweep=sweep)
        # scipy's chirp is a cosine; phi = -90 degrees turns it into our sine.
        reference = 1.0 + 3.0 * scipy_chirp(t, 50.0, n / FS, 2_000.0, method=method, phi=-90.0)
        np.testing.assert_allclose(v, reference, atol=1e-9)


def test_multisine_peak_and_schroeder_crest():
    n = 400
    v = wf.multisine(n, FS, amplitude=8.0, f_min=50.0, f_max=3_000.0, num_tones=16)
    assert np.max(np.abs(v)) == pytest.approx(8.0)
    spectrum = np.abs(np.fft.rfft(v))
    tones = np.flatnonzero(spectrum > 0.1 * spectrum.max())
    assert 10 <= tones.size <= 16 and (tones * FS / n).min() >= 50.0 and (tones * FS / n).max() <= 3_000.0
    # Schroeder phases keep the crest factor well below that of the same tones in phase.
    t = np.arange(n) / FS
    in_phase = np.cos(2 * np.pi * np.outer(t, tones * FS / n)).sum(axis=1)

    def crest(x):
        return np.max(np.abs(x)) / np.sqrt(np.mean(x**2))

    assert crest(v) < 0.75 * crest(in_phase)


def test_step_and_samples():
    v = wf.step(10, FS, level=5.0, initial=1.0, delay=3 / FS)
    assert v.tolist() == [1.0] * 3 + [5.0] * 7
    with pytest.raises(dc.PlanError, match="one value per sample"):
        wf.samples(5, FS, values=[1.0, 2.0])


def test_chirp_above_nyquist_is_refused():
    with pytest.raises(dc.PlanError, match="Nyquist"):
        wf.chirp(100, FS, amplitude=1.0, f_start=10.0, f_stop=15_000.0)


def test_prbs_with_a_bit_far_longer_than_the_segment_costs_nothing():
    """A bit rate far below the sample rate (a fuzzed plan found 1e-300 Hz) holds one level; O(n) memory."""
    from drivecal.plan import waveforms

    levels = waveforms.prbs(100, 20e3, amplitude=2.0, bit_rate=1e-300)
    assert levels.shape == (100,) and np.all(levels == levels[0]) and abs(levels[0]) == 2.0
