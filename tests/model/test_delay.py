"""The inverter's delay in the forward model: whole and fractional, against the engine and the switching plant.

A delay d = n + f samples applies, in the period [t_k, t_k+1), the command of
sample k - n - 1 for its first f and that of k - n for the rest; the rollout
integrates the two sub-intervals (model/_steps.py). Agreement measured when
these tests were written (default motor and plan, 20 kHz):

* against the Jaxonomy engine run on a grid k times finer (engine_bench with
  delay 0.5 or 1.5, k = 2): ~1e-9 A -> asserted < 1e-6 A (the engine's own tolerance);
* against the independent plant's averaged inverter (drivecal.bench.pwm_bench,
  duty loaded at the carrier valley): ~5e-11 A -> asserted < 1e-8 A;
* the prediction is continuous in d across a whole sample (the two
  sub-intervals meet the one-interval step).
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import pwm_bench
from drivecal.model import model_experiment, predicted_currents

PLAN = dc.Plan((
    dc.Segment("locked d-step", 0.004, locked=True, v_d=8.0),
    dc.Segment("locked q-sine", 0.004, locked=True,
               v_q=6.0 * np.sin(2 * np.pi * 500 * np.arange(80) / 20000.0)),
    dc.Segment("free spin-up", 0.008, locked=False, v_q=12.0),
))


def _predict(motor, bench, delay, estimate_delay=True):
    experiment = bench.experiment(measured_speed=False, delay_samples=delay)
    motor = motor.replace(delay=delay)
    return predicted_currents(motor, model_experiment(experiment, motor, ("delay",) if estimate_delay else ()))


@pytest.mark.parametrize("delay", [0.5, 1.5])
def test_fractional_delay_matches_the_engine(truth, delay):
    clean = dc.engine_bench(PLAN, truth, delay_samples=delay)
    assert np.abs(_predict(truth, clean, delay) - clean.currents).max() < 1e-6


def test_fractional_delay_matches_the_switching_plants_averaged_inverter(truth):
    plant = pwm_bench(PLAN, truth, switching=False, delay_samples=0.5, substeps=8)
    assert np.abs(_predict(truth, plant, 0.5) - plant.currents).max() < 1e-8


def test_whole_delay_is_the_same_either_way(truth):
    """A whole delay baked into the experiment, or applied by the fractional model: the same currents."""
    clean = dc.engine_bench(PLAN, truth, delay_samples=1)
    baked = _predict(truth, clean, 1.0, estimate_delay=False)
    modelled = predicted_currents(truth.replace(delay=1.0),
                                  model_experiment(clean.experiment(measured_speed=False), truth.replace(delay=1.0),
                                                   ("delay",)))
    assert np.abs(baked - modelled).max() < 1e-12
    assert np.abs(baked - clean.currents).max() < 1e-6


def test_prediction_is_continuous_in_the_delay(truth):
    clean = dc.engine_bench(PLAN, truth, delay_samples=1)
    experiment = clean.experiment(measured_speed=False)
    at = {d: predicted_currents(truth.replace(delay=d), model_experiment(experiment, truth, ("delay",)))
          for d in (1.0 - 1e-9, 1.0, 1.0 + 1e-9)}
    # A 1e-9 sample change moves the currents by ~1e-8 A (the slope at a step's edge, ~10 A/sample); a jump
    # at the whole sample would be the size of a sample's worth of response, ~0.1 A.
    assert np.abs(at[1.0 - 1e-9] - at[1.0]).max() < 1e-6
    assert np.abs(at[1.0 + 1e-9] - at[1.0]).max() < 1e-6
