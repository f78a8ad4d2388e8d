"""The published PM-SyRM plant of ``helpers.blocks`` (Lelli et al., ICEM 2024, doi 10.1109/ICEM60801.2024.10700403,
as in Aalto's motulator): its law's magnet point and inverse, and its block at rest and in a locked step."""

from __future__ import annotations

import numpy as np
import pytest

from drivecal.bench import run_held_voltages
from helpers.blocks import (LELLI_PM_SYRM_MACHINE, lelli_currents, lelli_flux, lelli_pm_syrm_block,
                            lelli_small_signal)


def test_magnet_point_is_the_published_one():
    lam, ld, lq = lelli_small_signal()
    assert lam == pytest.approx(0.477, abs=5e-4)  # motulator's example solves psi_s0 = 0.477 Vs
    i_d, i_q = (float(x) for x in lelli_currents(lam, 0.0))
    assert abs(i_d) < 1e-12 and i_q == 0.0
    # The small-signal inductances are the inverse slopes of the law there (finite differences, 1e-6 Wb).
    h = 1e-6
    assert ld == pytest.approx(2 * h / float(lelli_currents(lam + h, 0.0)[0] - lelli_currents(lam - h, 0.0)[0]),
                               rel=1e-6)
    assert lq == pytest.approx(h / float(lelli_currents(lam, h)[1]), rel=1e-6)
    assert 0.02 < ld < 0.04 and 0.12 < lq < 0.18  # a PM-SyRM: q reluctance path much the larger


def test_flux_of_currents_inverts_the_law():
    i = np.array([[-12.0, 0.0], [12.0, 0.0], [0.0, 12.0], [-8.0, 15.0], [10.0, -10.0]])
    psi_d, psi_q = lelli_flux(i[:, 0], i[:, 1])
    np.testing.assert_allclose(np.stack([np.asarray(x) for x in lelli_currents(psi_d, psi_q)], -1), i, atol=1e-9)


@pytest.mark.slow  # the block's engine run compiles (~10 s)
def test_locked_step_settles_at_v_over_r():
    v = np.tile([6.3, 0.0], (10000, 1))  # 10 A on d at steady state (1 s, over 20 L/R), whatever the iron
    _, x = run_held_voltages(lelli_pm_syrm_block(locked=True), v, 10000.0)
    assert x[0, 0] == pytest.approx(0.0, abs=1e-12) and np.all(x[:, 2:] == 0.0)
    assert x[-1, 0] == pytest.approx(6.3 / LELLI_PM_SYRM_MACHINE["R"], rel=1e-6) and abs(x[-1, 1]) < 1e-9
