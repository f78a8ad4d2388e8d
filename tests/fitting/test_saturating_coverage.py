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
from drivecal.bench import SATURATION_LEVELS_PLAN, engine_bench, hinkkanen_syrm

NAMES = ("R", "Ld", "Lq", "sat_d", "sat_q", "sat_dq")


@pytest.mark.slow
def test_saturating_fit_coverage():
    truth = hinkkanen_syrm(i_ref=40.0)
    clean = engine_bench(SATURATION_LEVELS_PLAN, truth)
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
