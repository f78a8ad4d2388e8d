"""The iron bridge's search (``selection._bridge``): the locked steps' flux linkages read from the voltages, and
the static regression of the law on them that starts the bridged fit."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal.physics import BRIDGE, EXPONENTS, MAGNETIC
from drivecal.selection._bridge import EXPONENT_GRID, PSI_N_START, SHAPE_START, locked_flux_data, flux_law_fit
from helpers.blocks import lelli_bench, lelli_levels, lelli_small_signal


def test_locked_flux_linkages_are_the_linear_motor_s(clean_default, truth):
    """On the seed motor's locked steps (the engine bench, noise-free), lambda_m + Ld i_d(0) + int(v - R i) dt is
    Ld i_d + lambda_m at every sample, and likewise on q. The trapezoids' error on the current's integral is
    below R*T*h^2*max|i''|/12, about 1e-6 of the flux swing here; 1e-4 of it is asserted."""
    volt, amp, start, measured = locked_flux_data(clean_default.experiment(), clean_default.currents)
    assert len(volt) > 100
    r, ld, lq, lam = (float(getattr(truth, n)) for n in ("R", "Ld", "Lq", "lambda_m"))
    psi_d = lam + ld * start[:, 0] + volt[:, 0] - r * amp[:, 0]
    psi_q = lq * start[:, 1] + volt[:, 1] - r * amp[:, 1]
    swing = max(ld * np.abs(measured[:, 0]).max(), lq * np.abs(measured[:, 1]).max())
    np.testing.assert_allclose(psi_d, lam + ld * measured[:, 0], rtol=0, atol=1e-4 * swing)
    np.testing.assert_allclose(psi_q, lq * measured[:, 1], rtol=0, atol=1e-4 * swing)


def test_no_locked_step_no_static_fit(truth):
    plan = dc.Plan((dc.Segment("spin", 0.05, False, v_q=10.0),), sample_rate=10000.0, v_dc=48.0, current_limit=30.0)
    bench = dc.engine_bench(plan, truth)
    assert locked_flux_data(bench.experiment(), bench.currents) is None
    assert flux_law_fit(bench.experiment(), bench.currents, truth, dc.ESTIMATED) is None


@pytest.mark.slow  # the independent plant (~10 s)
def test_static_regression_ranks_the_published_exponents_first_and_lands_near_the_law():
    """Lelli's PM-SyRM (the independent plant of helpers.blocks), 20 mA noise, from the search's generic start:
    of the exponent grid, the published (4, 6, 1, 1) fits best, and its estimates are a start the rollout
    converges from (R, lambda_m, Ld, Lq within 15 %, psi_n within 10 %: what the dynamic fit then corrects)."""
    bench = lelli_bench(lelli_levels()).add_noise(0.02, 3)
    lam, ld, lq = lelli_small_signal()
    prior = dc.MotorParams(R=0.63, Ld=ld, Lq=lq, lambda_m=lam, pole_pairs=2.0, J=0.015, i_ref=18.0)
    start = prior.replace(sat_at_zero=1.0, psi_n=PSI_N_START * lam, **SHAPE_START)
    names = dc.ESTIMATED + MAGNETIC + BRIDGE
    fits = {ex: flux_law_fit(bench.experiment(), bench.currents, start.replace(**dict(zip(EXPONENTS, ex))), names)
            for ex in EXPONENT_GRID}
    ranked = sorted((f[1], ex) for ex, f in fits.items() if f is not None)
    assert ranked[0][1] == (4.0, 6.0, 1.0, 1.0)
    motor = fits[ranked[0][1]][0]
    truth = dc.load_motor(Path(__file__).resolve().parents[2] / "examples" / "pm_syrm_motor.toml").motor
    for name, tol in (("R", 0.15), ("lambda_m", 0.15), ("Ld", 0.15), ("Lq", 0.15), ("psi_n", 0.10)):
        assert float(getattr(motor, name)) == pytest.approx(float(getattr(truth, name)), rel=tol), name
    assert float(motor.sat_b) > 0.0
