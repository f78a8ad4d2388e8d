"""Mechanics from the bench run (issue 20, item 1): J, B, Coulomb friction and load torque as estimable parameters.

Truth is the Jaxonomy engine, whose PMSM block has J, B and a load-torque port: the engine bench
feeds the Coulomb friction to that port from ``physics.coulomb_friction``, drivecal's model has it in
``dq_derivatives_from``. The run is the default plan's locked steps and one free segment: the
spin-up (12 V on q, 50 ms) followed by a short-circuit coast-down (0 V, 100 ms), in which the rotor's
deceleration (J, B, T_coulomb against the braking torque of the known electrical parameters) shows
in the currents. No speed column: the mechanics are identified from the currents alone.

Tolerances are the statistics': 3 standard errors (fixed seeds), and Monte Carlo coverage of the
95 % intervals in [0.90, 0.99] over 224 seeds (binomial standard error 0.015 at 0.95).
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.fitting import fit_currents
from drivecal.identify import assess_identifiability, check_requested
from drivecal.model import simulate_states
from drivecal.physics import coulomb_friction

NOISE = 0.02  # A
#: The issue's mechanics: J = 1.2e-3 kg m^2, B = 8e-5 N m s, T_coulomb = 2e-3 N m.
TRUE = dc.DEFAULT_MOTOR.replace(J=1.2e-3, B=8e-5, T_coulomb=2e-3)
NAMES = dc.ESTIMATED + ("J", "B", "T_coulomb")


def _coast_down_plan() -> dc.Plan:
    d = dc.default_plan()
    fs = d.sample_rate
    v_q = np.concatenate([np.full(int(0.05 * fs), 12.0), np.zeros(int(0.10 * fs))])
    return dc.Plan(d.segments[:2] + (
        dc.Segment("spin-up, short-circuit coast-down", 0.15, locked=False, v_d=0.0, v_q=v_q),))


@pytest.fixture(scope="module")
def coast_clean():
    return dc.engine_bench(_coast_down_plan(), TRUE)


@pytest.fixture(scope="module")
def prior():
    """The datasheet guess of the electrical parameters; J and B 33 % and 50 % high, no friction known."""
    return dc.datasheet_guess(TRUE).replace(J=1.6e-3, B=1.2e-4, T_coulomb=0.0)


def test_coulomb_friction_is_a_smooth_sign():
    w = np.array([-100.0, -1.0, 0.0, 1.0, 100.0])
    t = np.asarray(coulomb_friction(w, 2e-3, 1.0))
    assert t[2] == 0.0 and np.allclose(t[[0, 4]], [-2e-3, 2e-3]) and np.allclose(t[3], 2e-3 * np.tanh(1.0))


def test_model_matches_the_engine_with_friction_and_load():
    motor = TRUE.replace(T_load=1e-3)
    bench = dc.engine_bench(_coast_down_plan(), motor)
    predicted = np.asarray(simulate_states(motor, bench.experiment(measured_speed=True), keep=2))
    assert np.max(np.abs(predicted - bench.currents)) < 1e-8
    # ... and the friction is there to be seen: the currents without it differ by far more than that.
    without = np.asarray(simulate_states(motor.replace(T_coulomb=0.0, T_load=0.0),
                                         bench.experiment(measured_speed=True), keep=2))
    assert np.max(np.abs(without - bench.currents)) > 1e-2


def test_mechanics_from_the_currents_alone(coast_clean, prior):
    bench = coast_clean.add_noise(NOISE, 3)
    experiment = bench.experiment(measured_speed=True)  # no speed column: the speed is simulated
    # The plan identifies all seven at the true motor (at the prior, with no friction assumed, B looks weak).
    assert assess_identifiability(experiment, TRUE, names=NAMES).identifiable
    ident = assess_identifiability(experiment, prior, names=NAMES)
    cal = fit_currents(experiment, bench.currents, prior, names=NAMES, identifiability=ident)
    assert bool(cal.converged)
    assert 0.8 * NOISE < float(cal.sigma_hat) < 1.2 * NOISE
    for name in NAMES:
        i = cal.names.index(name)
        z = (float(cal.estimate[i]) - float(getattr(TRUE, name))) / float(cal.se[i])
        assert abs(z) < 3.0, (name, z)


def test_measured_speed_hides_the_mechanics(truth):
    bench = dc.engine_bench(dc.default_plan(), truth, record_speed=True)
    experiment = bench.experiment(measured_speed=True)
    with pytest.raises(dc.DrivecalError, match=r"J is requested .* measured speed as the model's input.*--speed output"):
        check_requested(("R", "J"), experiment, "bench.csv")
    ident = assess_identifiability(experiment, truth, names=dc.ESTIMATED + ("J", "B"))
    assert set(ident.dead_params) == {"J", "B"} and "measured speed" in ident.reasons["J"]


@pytest.mark.slow
def test_coverage_of_the_mechanics(coast_clean, prior):
    """Monte Carlo over 224 noise seeds, one batched fit: coverage of J and B (and the rest) in [0.90, 0.99]."""
    seeds = 224  # >= 200, a whole number of the solver's tiles of 32 fits
    rng = np.random.default_rng(2020)
    currents = coast_clean.currents[None] + NOISE * rng.standard_normal((seeds,) + coast_clean.currents.shape)
    experiment = coast_clean.experiment(measured_speed=True)
    ident = assess_identifiability(experiment, prior, names=NAMES)
    cal = fit_currents(experiment, currents, prior, names=NAMES, identifiability=ident)
    assert np.all(cal.converged)
    for name in NAMES:
        i = NAMES.index(name)
        truth = float(getattr(TRUE, name))
        covered = float(np.mean((cal.ci95[:, i, 0] <= truth) & (truth <= cal.ci95[:, i, 1])))
        print(f"coverage {name}: {covered:.3f}")
        assert 0.90 <= covered <= 0.99, (name, covered)
