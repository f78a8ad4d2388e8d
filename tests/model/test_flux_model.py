"""The flux-state forward model (model._flux) against the linear model and against the Jaxonomy engine's
flux-state block, which integrates the same law with its own adaptive solver."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.model import model_experiment, predicted_currents
from drivecal.physics import MAGNETIC, from_hinkkanen

S = dc.Segment
#: Locked steps at three levels per axis, combined d+q steps, and a free run (the cross-saturation's torque).
LEVELS = dc.Plan((S("d 30 V", 0.01, True, v_d=30.0), S("d 90 V", 0.01, True, v_d=90.0),
                  S("q 8 V", 0.01, True, v_q=8.0), S("q 20 V", 0.01, True, v_q=20.0),
                  S("d+q", 0.01, True, v_d=60.0, v_q=15.0), S("d-q", 0.01, True, v_d=60.0, v_q=-15.0),
                  S("free", 0.02, False, v_d=40.0, v_q=20.0)),
                 sample_rate=10000.0, v_dc=540.0, current_limit=60.0)


def test_linear_machine_through_the_flux_model_is_the_linear_model(clean_default):
    experiment = clean_default.experiment()
    motor = dc.MotorParams()
    linear = predicted_currents(motor, experiment)
    flux = predicted_currents(motor, dataclasses.replace(experiment, saturating=True))
    np.testing.assert_allclose(flux, linear, rtol=0, atol=1e-12)
    np.testing.assert_allclose(flux, clean_default.currents, rtol=0, atol=1e-8)  # and the engine's PMSM block


@pytest.mark.parametrize("motor", ["syrm", "pm"])
def test_engine_flux_block_agrees_with_the_model(motor):
    if motor == "syrm":  # Hinkkanen et al. 2017's 6.7-kW SyRM (see tests/physics/test_magnetics.py)
        truth = from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), a_d0=17.4,
                               a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0, i_ref=20.0)
    else:  # a PM machine with all three terms
        truth = dc.MotorParams(R=0.5, Ld=0.02, Lq=0.06, lambda_m=0.3, pole_pairs=2.0, J=0.01).replace(
            sat_d=0.3, sat_q=1.5, sat_dq=0.5, i_ref=20.0, exp_d=2.0, exp_q=2.0)
    bench = engine_bench(LEVELS, truth)
    assert np.abs(bench.currents).max() > 10.0  # well into saturation
    experiment = model_experiment(bench.experiment(), truth, MAGNETIC)
    assert experiment.saturating
    # RK4 with one step per sample: at 10 kHz, with the law's curvature at 50 A, ~1e-8 of the peak current.
    peak = float(np.abs(bench.currents).max())
    np.testing.assert_allclose(predicted_currents(truth, experiment), bench.currents, rtol=0, atol=2e-8 * peak)
