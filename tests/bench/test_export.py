"""Hand-off to simulation: the calibrated Jaxonomy PMSM block reproduces the fit's predictions."""

from __future__ import annotations

import numpy as np

import drivecal as dc
from drivecal.bench import run_held_voltages


def test_to_jaxonomy_block_on_the_engine_reproduces_the_fit(default_fit, default_bench):
    predicted = np.asarray(dc.predict_currents(default_fit.motor, default_bench.experiment()))
    k = 0
    for seg in default_bench.segments:
        block = default_fit.to_jaxonomy(locked=seg.locked)
        assert type(block).__name__ == "PMSM"
        _, states = run_held_voltages(block, seg.voltages, default_bench.sample_rate, label=seg.name)
        err = np.max(np.abs(states[:, :2] - predicted[k : k + seg.num_samples]))
        assert err < 1e-6, (seg.name, err)
        k += seg.num_samples
