"""The backward step (selection/_backward.py): a saturation term that entered for what a bench effect does is
dropped once that effect is modelled, and a bench effect far beyond its level is kept without a refit.

The bench is test_select.py's realistic inverter (switching-level plant, 10 kHz, 48 V, 1 us dead time, one
sample of delay, 20 mA noise, seed 5) with a linear motor. Under the selection's earlier order (the machine's
law first) the q-axis and cross-saturation terms entered there before the dead time and stayed, at 0.08 % and
0.07 % of the flux: this test starts from that model.
"""

from __future__ import annotations

import pytest

import drivecal as dc
from drivecal.bench import pwm_bench
from drivecal.fitting import FitOptions, fit_currents
from drivecal.selection import MATERIAL_SATURATION, EffectChoice, saturation_size
from drivecal.selection._backward import drop_effects

MOTOR = dc.DEFAULT_MOTOR


@pytest.mark.slow
@pytest.mark.long
def test_saturation_terms_standing_in_for_the_dead_time_are_dropped():
    plan = dc.Plan(dc.default_plan().segments, sample_rate=10_000.0)
    bench = pwm_bench(plan, MOTOR, delay_samples=1, t_dead=1e-6, substeps=16).add_noise(0.02, 5)
    experiment = bench.experiment(measured_speed=True)
    prior = MOTOR.replace(i_ref=12.0, exp_q=6.0, exp_dq_d=2.0, exp_dq_q=0.0)  # the terms as they had entered
    names = dc.ESTIMATED + ("delay", "v_dead", "sat_q", "sat_dq")
    cal = fit_currents(experiment, bench.currents, prior, names=names,
                       initial=prior.replace(delay=1.0, v_dead=0.48, sat_q=0.01, sat_dq=0.01))
    assert bool(cal.converged)
    for term in ("sat_q", "sat_dq"):  # fitted beside the dead time, each is far below the modelled 2 %
        assert saturation_size(cal.motor, term, bench.currents) < 0.1 * MATERIAL_SATURATION, term
    decided = {e: EffectChoice(e, True, "selected", p_threshold=1e-3 / 6)
               for e in ("delay", "dead_time", "saturation_q", "cross_saturation")}
    final, refits, dropped = drop_effects(experiment, bench.currents, MOTOR, cal, decided, FitOptions(),
                                          bench.source)
    assert set(dropped) == {"saturation_q", "cross_saturation"}
    assert not set(final.fit_names) & {"sat_q", "sat_dq"} and {"delay", "v_dead"} <= set(final.fit_names)
    assert all(decided[e].how == "too small" and not decided[e].included for e in dropped)
    assert decided["dead_time"].included and decided["delay"].included
    # The delay and the dead time are far beyond their level (Wald z of 70 and 290): kept without a refit, so
    # the refits are the two saturation terms' (twice for the one left after the first is dropped).
    assert refits == 3, refits
