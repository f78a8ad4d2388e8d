"""The score tests' sensitivity columns (diagnose/_mismatch.py): probes beyond one kernel's columns run in
further kernels and give the same columns."""

from __future__ import annotations

import numpy as np

import drivecal as dc
from drivecal.diagnose import _mismatch
from drivecal.model import model_experiment, with_experiment_delay


def test_probes_split_over_kernels_give_the_columns_of_one(monkeypatch, clean_default, truth):
    experiment = clean_default.experiment()
    names = dc.ESTIMATED
    motor = with_experiment_delay(truth.with_vector(names, truth.vector(names)), experiment)
    modelled = model_experiment(experiment, motor, names)
    effects = ("delay", "dead_time", "offsets")  # 4 fitted + 4 probed columns: one kernel
    fitted, columns = _mismatch.effect_signatures(motor, names, modelled, effects)
    monkeypatch.setattr(_mismatch, "_MAX_COLUMNS", 6)  # two probes per kernel: two kernels
    fitted_split, columns_split = _mismatch.effect_signatures(motor, names, modelled, effects)
    assert fitted.shape == fitted_split.shape == (2 * experiment.num_samples, 4)
    np.testing.assert_allclose(fitted_split, fitted, rtol=1e-12, atol=1e-15)
    for effect in effects:
        assert columns_split[effect].shape == columns[effect].shape
        np.testing.assert_allclose(columns_split[effect], columns[effect], rtol=1e-12, atol=1e-15)


def test_magnetic_scores_from_the_bench_effects_columns_equal_their_own(clean_default, truth):
    """The magnetic score tests take the fitted columns the bench effects' tests computed (one kernel fewer):
    the same statistics as with the columns computed for them alone."""
    bench = clean_default.add_noise(0.02, 11)
    experiment = bench.experiment()
    names = dc.ESTIMATED
    motor = truth.with_vector(names, truth.vector(names))
    magnetic = tuple(_mismatch.MAGNETIC_EFFECTS)
    joint = _mismatch.unmodelled_effects(motor, names, experiment, bench.currents, 0.02,
                                         effects=("delay", "dead_time", *magnetic))
    alone = _mismatch.unmodelled_effects(motor, names, experiment, bench.currents, 0.02, effects=magnetic)
    by_effect = {e["effect"]: e for e in joint}
    for effect in alone:
        assert np.isfinite(effect["statistic"]), effect["effect"]
        np.testing.assert_allclose(by_effect[effect["effect"]]["statistic"], effect["statistic"], rtol=1e-9)
