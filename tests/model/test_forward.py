"""drivecal's RK4 rollout against the Jaxonomy engine bench: exact, not 'within the noise'."""

from __future__ import annotations

import numpy as np

import drivecal as dc


def test_forward_model_matches_engine_bench_on_default_plan(clean_default, truth):
    predicted = np.asarray(dc.predict_currents(truth, clean_default.experiment()))
    assert predicted.shape == clean_default.currents.shape == (1400, 2)
    assert np.max(np.abs(predicted - clean_default.currents)) < 1e-6
    # the comparison is not trivial: currents of several amperes flow
    assert np.max(np.abs(clean_default.currents)) > 5.0


def test_bench_samples_sit_on_the_sample_grid(clean_default):
    for seg in clean_default.segments:
        np.testing.assert_allclose(seg.t, np.arange(seg.num_samples) / 20_000.0, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(seg.currents[0], [0.0, 0.0])  # every segment starts from rest


def test_forward_model_matches_engine_on_time_varying_voltage(truth):
    """Per-sample (held) voltages go through the engine's hold exactly like the rollout."""
    fs = 20_000.0
    n = 300
    t = np.arange(n) / fs
    plan = dc.Plan(
        segments=(
            dc.Segment("locked d-chirp", n / fs, locked=True, v_d=8.0 * np.sin(2 * np.pi * (50 + 4e4 * t) * t)),
            dc.Segment("free ramp", n / fs, locked=False, v_d=1.0, v_q=np.linspace(0.0, 15.0, n)),
        ),
        sample_rate=fs,
    )
    bench = dc.engine_bench(plan, truth)
    predicted = np.asarray(dc.predict_currents(truth, bench.experiment()))
    assert np.max(np.abs(predicted - bench.currents)) < 1e-6


def test_segments_restart_from_rest():
    """A segment after a free spin-up starts again at zero current and speed."""
    plan = dc.Plan(segments=(dc.Segment("spin", 0.01, False, v_q=12.0), dc.Segment("step", 0.005, True, v_d=5.0)))
    states = np.asarray(dc.simulate_states(dc.DEFAULT_MOTOR, dc.Experiment.from_plan(plan)))
    assert np.abs(states[199, 2]) > 1.0
    np.testing.assert_array_equal(states[200], np.zeros(4))
    assert np.all(states[200:, 2] == 0.0)
