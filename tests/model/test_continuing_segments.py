"""Continuing segments and inverter-off coast-downs (issue 20, item 3).

A segment that continues the previous one starts where the model's rollout arrived (currents, speed,
angle and the delayed command carry over); an inverter-off segment holds the currents at zero while the
rotor coasts on its friction. Truth: the Jaxonomy engine runs a chain of continuing segments as one run,
and the coast-down by scipy's adaptive Runge-Kutta (the PMSM block cannot hold its currents at zero), so
neither shares drivecal's RK4. Bench files keep the chain: a segment one sample period after the previous
one's last sample, not at rest, continues it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import drivecal as dc
from drivecal.data import bench_from_frame
from drivecal.model import Experiment, simulate_states
from drivecal.plan import Plan, Segment

MOTOR = dc.DEFAULT_MOTOR.replace(T_coulomb=2e-3)


def _plan(braking_continues: bool = True) -> Plan:
    return Plan((Segment("locked d-step", 0.01, True, v_d=8.0),
                 Segment("spin-up", 0.05, False, v_q=12.0),
                 Segment("braking", 0.005, False, v_q=0.0, continues=braking_continues),
                 Segment("coast-down", 0.1, False, continues=True, inverter="off")))


@pytest.fixture(scope="module")
def chain_bench():
    return dc.engine_bench(_plan(), MOTOR, record_speed=True)


def test_a_continuing_segment_is_the_same_rollout_as_one_segment():
    merged = Plan((Segment("spin", 0.1, False, v_q=np.r_[np.full(1000, 12.0), np.zeros(1000)]),))
    split = Plan((Segment("spin", 0.05, False, v_q=12.0), Segment("brake", 0.05, False, v_q=0.0, continues=True)))
    for delay in (0.0, 1.0, 1.5):
        experiments = [dataclasses.replace(Experiment.from_plan(p, delay_samples=int(delay)),
                                           fractional_delay=delay != int(delay)) for p in (merged, split)]
        a, b = (np.asarray(simulate_states(MOTOR.replace(delay=delay), e)) for e in experiments)
        assert experiments[1].carried == (1,)
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-12)


def test_model_matches_the_engine_through_braking_and_an_inverter_off_coast_down(chain_bench):
    experiment = chain_bench.experiment(measured_speed=False)
    assert experiment.carried == (2, 3) and [k for *_, k in experiment.segments] == ["locked", "free", "free", "coast"]
    states = np.asarray(simulate_states(MOTOR, experiment))
    speed = np.concatenate([s.w_m for s in chain_bench.segments])
    assert np.max(np.abs(states[:, :2] - chain_bench.currents)) < 1e-8
    assert np.max(np.abs(states[:, 2] - speed)) < 1e-8
    coast = chain_bench.segments[3]
    assert np.all(coast.currents == 0.0) and coast.w_m[0] > 10.0 and np.all(np.diff(coast.w_m) < 0)


def test_a_bench_file_keeps_the_chain_and_a_segment_at_rest_starts_from_rest(chain_bench, tmp_path):
    path = chain_bench.save(tmp_path / "chain.csv")
    again = dc.load_bench(path)
    assert [(s.continues, s.inverter_off) for s in again.segments] == [(False, False), (False, False),
                                                                       (True, False), (True, True)]
    np.testing.assert_allclose(again.currents, chain_bench.currents, atol=1e-12)
    # the locked step and the spin-up lie one sample apart too, but the spin-up starts at rest
    frame = chain_bench.to_frame()
    assert np.isclose(frame["t"][frame["segment"] == "braking"].iloc[0],
                      frame["t"][frame["segment"] == "spin-up"].iloc[-1] + 1 / chain_bench.sample_rate)
    # the same samples with the braking's clock restarted at 0: no longer one time axis, no longer a chain
    frame.loc[frame["segment"] == "braking", "t"] -= frame["t"][frame["segment"] == "braking"].iloc[0]
    assert not bench_from_frame(frame, "restarted").segments[2].continues


def test_an_inverter_column_that_changes_within_a_segment_is_refused(chain_bench, capsys, tmp_path):
    from tests.helpers.cli import assert_one_sentence, run_cli

    frame = chain_bench.to_frame()
    frame.loc[frame.index[-1], "inverter"] = 1
    frame.to_csv(tmp_path / "bad.csv", index=False)
    code, err = run_cli(["fit", tmp_path / "bad.csv"], capsys)
    assert_one_sentence(code, err, "segment 'coast-down'", "column 'inverter'", "split the segment")


def test_spin_up_and_braking_recorded_as_two_segments_calibrate_like_one():
    """The issue's report: recorded as two segments on one time axis the run was refused as model mismatch;
    now the braking continues the spin-up, and the fit is the one-segment recording's (the same samples)."""
    d, q = Segment("locked d-step", 0.01, True, v_d=8.0), Segment("locked q-step", 0.01, True, v_q=8.0)
    one = Plan((d, q, Segment("spin-up", 0.15, False, v_q=np.r_[np.full(1000, 12.0), np.zeros(2000)])))
    two = Plan((d, q, Segment("spin-up", 0.05, False, v_q=12.0), Segment("braking", 0.1, False, v_q=0.0,
                                                                          continues=True)))
    prior = dc.datasheet_guess(MOTOR).replace(J=1.6e-3, B=1.2e-4, T_coulomb=0.0)
    names = dc.ESTIMATED + ("J", "B", "T_coulomb")
    noise = np.random.default_rng(7).normal(0.0, 0.02, (one.num_samples, 2))
    fits = []
    for plan in (one, two):
        clean = dc.engine_bench(plan, MOTOR)
        fits.append(dc.fit(clean.with_currents(clean.currents + noise), prior, names=names, measured_speed=False))
    assert all(bool(c.converged) for c in fits)
    assert np.all(np.abs(fits[1].estimate - fits[0].estimate) < 1e-3 * fits[0].se)  # the same optimum
    z = (fits[1].estimate - np.asarray(MOTOR.vector(names))) / fits[1].se
    assert np.all(np.abs(z) < 3), dict(zip(names, z))
    assert 0.018 < float(fits[1].sigma_hat) < 0.022  # the noise, not amperes of an unmodelled restart


def test_a_steady_run_without_a_speed_column_still_continues_the_spin_up(tmp_path):
    """A steady free run carries only the friction's few mA, which look like rest; without a speed column a free
    segment that follows a free one on the same clock continues it (a free rotor does not stop between samples)."""
    plan = Plan((Segment("spin-up", 0.4, False, v_q=12.0), Segment("steady run", 0.02, False, v_q=12.0,
                                                                   continues=True)))
    bench = dc.engine_bench(plan, MOTOR).add_noise(0.02, 3)
    assert np.max(np.abs(bench.segments[1].currents[0])) < 0.1  # within the at-rest threshold's reach
    again = dc.load_bench(bench.save(tmp_path / "steady.csv"))
    assert [s.continues for s in again.segments] == [False, True]
