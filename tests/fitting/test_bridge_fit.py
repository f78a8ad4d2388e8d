"""A PM-assisted motor's iron bridge (Lelli et al., ICEM 2024, doi 10.1109/ICEM60801.2024.10700403) in drivecal's law:
the engine bench of the law a motor file states agrees with the independent plant of ``helpers.blocks`` (the
published equations, written apart), and a fit that names the bridge's coefficient follows that plant to the noise,
with every coefficient, the bridge's shape included, within 3 standard errors of the published motor's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.fitting import fit
from helpers.blocks import lelli_bench, lelli_levels

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
#: The PM-SyRM's multi-level locked plan (helpers.blocks.lelli_levels): to 18 A and -12 A on d, 18 A on q.
LEVELS = lelli_levels()
NOISE = 0.02  # A
#: The law's every coefficient: the motor's small-signal values, the three terms about zero flux, and the bridge with
#: its shape (its own saturation, the q flux's weight in it and the magnet flux it carries).
NAMES = ("R", "Ld", "Lq", "lambda_m", "sat_d", "sat_q", "sat_dq", "sat_b", "sat_bp", "k_q", "psi_n")


@pytest.fixture(scope="module")
def plant():
    """The independent plant's noise-free run of LEVELS."""
    return lelli_bench(LEVELS)


@pytest.mark.slow  # two engine runs (~40 s)
def test_engine_bench_of_the_motor_file_s_law_is_the_published_plant(plant):
    truth = dc.load_motor(EXAMPLES / "pm_syrm_motor.toml").motor
    ours = engine_bench(LEVELS, truth)
    assert np.abs(plant.currents).max() > 15.0  # well into the bridge's and the q axis's saturation
    np.testing.assert_allclose(ours.currents, plant.currents, rtol=0, atol=1e-10)


@pytest.mark.slow  # the independent plant (~10 s) and a flux-state fit (~30 s, compiling)
def test_fit_naming_the_bridge_and_its_shape_follows_the_published_plant_within_3_se(plant):
    truth = dc.load_motor(EXAMPLES / "pm_syrm_motor.toml").motor
    # A start far from the published motor: the law's shape from its exponents and terms about zero flux only.
    prior = truth.replace(R=0.55, Ld=0.033, Lq=0.135, lambda_m=0.45, sat_d=0.003, sat_q=2.0, sat_dq=0.3, sat_b=0.3,
                          sat_bp=0.2, k_q=0.2, psi_n=1.0)
    cal = fit(plant.add_noise(NOISE, 3), prior, names=NAMES)
    assert bool(cal.converged) and all(cal.identifiable)
    # sigma_hat is the noise within 3 of its SE (~1/sqrt(2 dof)): the law follows the plant (drivecal's law
    # without the bridge leaves 32 times the noise on this bench)
    assert float(cal.sigma_hat) == pytest.approx(NOISE, rel=3.0 / np.sqrt(2.0 * cal.dof))
    z = {n: (float(cal.estimate[i]) - float(getattr(truth, n))) / float(cal.se[i]) for i, n in enumerate(cal.names)}
    assert all(abs(v) < 3.0 for v in z.values()), z
