"""The score tests' sensitivity columns (diagnose/_mismatch.py): the fitted parameters' from the fit's own kernel
and each effect's from a kernel of its own equal the columns of one kernel differentiating along them all."""

from __future__ import annotations

import numpy as np

import drivecal as dc
from drivecal.diagnose import _mismatch
from drivecal.identify import sensitivity_jacobian
from drivecal.model import model_experiment, with_experiment_delay


def test_columns_kernel_by_kernel_equal_one_kernel_of_them_all(clean_default, truth):
    experiment = clean_default.experiment()
    names = dc.ESTIMATED
    motor = with_experiment_delay(truth.with_vector(names, truth.vector(names)), experiment)
    modelled = model_experiment(experiment, motor, names)
    effects = ("delay", "dead_time", "offsets")
    fitted, columns = _mismatch.effect_signatures(motor, names, modelled, effects)
    probes = tuple(n for e in effects for n in _mismatch.EFFECTS[e][1])
    # One program with every effect switched on (the dead time's sequential rollout, the delay's two sub-intervals)
    # and every column: at the nominal values the other effects add nothing, so the columns are the same derivatives.
    joint = _mismatch._one_substep(model_experiment(modelled, motor, names + probes))
    expected = np.asarray(sensitivity_jacobian(motor, joint, names + probes))[: 2 * experiment.num_samples]
    found = np.concatenate([fitted] + [columns[e] for e in effects], axis=1)
    assert found.shape == expected.shape == (2 * experiment.num_samples, len(names) + len(probes))
    # float64 rounding along two rollouts that sum in other orders (measured: at most 16 ulps of a column's scale
    # on examples/bench.csv); 1000 ulps, as the probing kernel is held to (tests/identify/test_identify.py)
    scale = np.abs(expected).max(axis=0)
    assert np.all(scale > 0)
    assert np.all(np.abs(found - expected).max(axis=0) <= 1000 * np.finfo(float).eps * scale)


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
