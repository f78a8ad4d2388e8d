"""The saturating fit's intervals are honest: Monte Carlo coverage over 200 noise seeds in one batched call.

Hinkkanen et al. 2017's 6.7-kW SyRM (doi 10.1109/TIA.2016.2644624; published coefficients, as in Aalto's
motulator) on the Jaxonomy engine's flux-state block, the multi-level locked plan that identifies the whole
law, 20 mA noise. The law's exponents are the published ones (the selection's choice on this bench,
tests/selection/test_magnetics_selection.py); R, the small-signal Ld, Lq and the three coefficients are fitted.
"""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.physics import from_hinkkanen

SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)
S = dc.Segment
PLAN = dc.Plan((S("d 15 V", 0.01, True, v_d=15.0), S("d 30 V", 0.01, True, v_d=30.0),
                S("d 45 V", 0.01, True, v_d=45.0), S("q 10 V", 0.01, True, v_q=10.0),
                S("q 20 V", 0.01, True, v_q=20.0), S("q 30 V", 0.01, True, v_q=30.0),
                S("d+q", 0.01, True, v_d=20.0, v_q=20.0), S("d-q", 0.01, True, v_d=30.0, v_q=-30.0)),
               sample_rate=10000.0, v_dc=540.0, current_limit=80.0)
NAMES = ("R", "Ld", "Lq", "sat_d", "sat_q", "sat_dq")


@pytest.mark.slow
def test_saturating_fit_coverage():
    truth = from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=40.0, **SYRM)
    clean = engine_bench(PLAN, truth)
    n = 200
    rng = np.random.default_rng(2026)
    currents = clean.currents[None] + rng.normal(0.0, 0.02, size=(n,) + clean.currents.shape)
    start = truth.replace(R=0.5, Ld=1.1 * float(truth.Ld), Lq=0.9 * float(truth.Lq),
                          sat_d=0.5 * float(truth.sat_d), sat_q=0.5 * float(truth.sat_q),
                          sat_dq=0.5 * float(truth.sat_dq))
    batch = dc.fit_currents(clean.experiment(), currents, start, names=NAMES)
    assert np.all(batch.converged)
    true = np.array([float(getattr(truth, name)) for name in NAMES])
    covered = (batch.ci95[..., 0] <= true) & (true <= batch.ci95[..., 1])
    coverage = covered.mean(axis=0)
    # 200 seeds: a correct 95 % interval covers 92-98 % (binomial, +-2.2 SE); 90-99 % is the bar.
    assert np.all((coverage >= 0.90) & (coverage <= 0.99)), dict(zip(NAMES, coverage))
    spread = batch.estimate.std(axis=0, ddof=1) / batch.se.mean(axis=0)
    assert np.all(np.abs(spread - 1.0) <= 0.20), dict(zip(NAMES, spread))
