"""The saturating magnetic law (physics._magnetics): Hinkkanen's published model exactly, its inverse, and the
linear machine as its special case."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import drivecal as dc
from drivecal.physics import (currents_of_flux, dq_derivatives, flux_derivatives, flux_of_currents, from_hinkkanen,
                              from_lelli, hinkkanen_coefficients, incremental_inductances)

#: The 6.7-kW synchronous reluctance motor of Hinkkanen et al., "Sensorless self-commissioning of synchronous
#: reluctance motors at standstill without rotor locking", IEEE Trans. Ind. Appl. 53(3), 2017
#: (doi 10.1109/TIA.2016.2644624), as published in Aalto's motulator examples (SI units).
SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)


def _published(psi_d, psi_q, a_d0, a_dd, S, a_q0, a_qq, T, a_dq, U, V):
    """The published law, written out as the paper gives it."""
    g_d = a_d0 + a_dd * np.abs(psi_d) ** S + a_dq / (V + 2) * np.abs(psi_d) ** U * np.abs(psi_q) ** (V + 2)
    g_q = a_q0 + a_qq * np.abs(psi_q) ** T + a_dq / (U + 2) * np.abs(psi_d) ** (U + 2) * np.abs(psi_q) ** V
    return g_d * psi_d, g_q * psi_q


@pytest.fixture(scope="module")
def syrm():
    return from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=20.0, **SYRM)


def test_hinkkanen_synchronous_reluctance_model_exactly(syrm):
    rng = np.random.default_rng(0)
    psi = rng.uniform(-1.0, 1.0, size=(2, 500))
    got = np.asarray(currents_of_flux(jnp.asarray(psi[0]), jnp.asarray(psi[1]), syrm))
    want = np.asarray(_published(psi[0], psi[1], **SYRM))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    back = hinkkanen_coefficients(syrm)
    for name, value in SYRM.items():
        assert back[name] == pytest.approx(value, rel=1e-12)


def test_flux_of_currents_inverts_the_law(syrm):
    rng = np.random.default_rng(1)
    i = jnp.asarray(rng.uniform(-40.0, 40.0, size=(2, 200)))
    psi = flux_of_currents(i[0], i[1], syrm)
    np.testing.assert_allclose(np.asarray(currents_of_flux(*psi, syrm)), np.asarray(i), rtol=0, atol=1e-9)


def test_newton_steps_as_a_loop_are_the_unrolled_steps(syrm):
    """``loop=True`` (the score tests' kernels) takes the same Newton steps, compiled as a loop: the same flux to
    rounding, also where Newton has not converged yet (3 steps from the linear machine's flux, at 40 A)."""
    rng = np.random.default_rng(2)
    i = jnp.asarray(rng.uniform(-40.0, 40.0, size=(2, 200)))
    for iterations in (3, 12):
        unrolled = np.asarray(flux_of_currents(i[0], i[1], syrm, iterations=iterations))
        looped = np.asarray(flux_of_currents(i[0], i[1], syrm, iterations=iterations, loop=True))
        np.testing.assert_allclose(looped, unrolled, rtol=1e-14, atol=0)
    assert np.asarray(flux_of_currents(jnp.zeros(()), 5.0, syrm, loop=True)).shape == (2,)


def test_small_signal_values_at_zero_current_whatever_the_saturation():
    motor = dc.MotorParams().replace(sat_d=0.4, sat_q=0.8, sat_dq=0.3, i_ref=10.0, exp_d=3.0, exp_q=2.0)
    psi = flux_of_currents(jnp.zeros(()), jnp.zeros(()), motor)
    assert float(psi[0]) == pytest.approx(float(motor.lambda_m), abs=1e-15) and float(psi[1]) == 0.0
    l_dd, l_dq, l_qq = (float(x) for x in incremental_inductances(*psi, motor))
    assert l_dd == pytest.approx(float(motor.Ld), rel=1e-12) and l_qq == pytest.approx(float(motor.Lq), rel=1e-12)
    assert l_dq == 0.0
    # Saturation: at 10 A on q the incremental Lq has fallen; cross-saturation couples the axes (reciprocal).
    psi = flux_of_currents(jnp.asarray(5.0), jnp.asarray(10.0), motor)
    l_dd, l_dq, l_qq = (float(x) for x in incremental_inductances(*psi, motor))
    assert l_qq < 0.6 * float(motor.Lq) and l_dq != 0.0


def test_linear_machine_is_the_special_case():
    """With no saturation the flux equations are drivecal's dq equations (psi = L i + lambda_m)."""
    motor = dc.MotorParams(B=2e-4, T_load=0.01)
    rng = np.random.default_rng(2)
    for _ in range(20):
        i_d, i_q, w_m, theta = rng.normal(size=4) * (3.0, 3.0, 50.0, 1.0)
        v = rng.normal(size=2) * 10.0
        psi = (float(motor.lambda_m) + float(motor.Ld) * i_d, float(motor.Lq) * i_q)
        (dpsi_d, dpsi_q, dw, dth), currents = flux_derivatives((psi[0], psi[1], w_m, theta), v, motor, False)
        di_d, di_q, dw_lin, dth_lin = dq_derivatives((i_d, i_q, w_m, theta), v, motor, False)
        np.testing.assert_allclose([float(c) for c in currents], [i_d, i_q], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose([float(dpsi_d), float(dpsi_q)],
                                   [float(motor.Ld) * float(di_d), float(motor.Lq) * float(di_q)], rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose([float(dw), float(dth)], [float(dw_lin), float(dth_lin)], rtol=1e-10, atol=1e-9)


def test_flux_derivatives_with_another_law_s_currents(syrm):
    """``currents=`` puts another current-of-flux law (an independent plant's) in the same flux equations; given the
    motor's own currents it is the motor's derivative exactly, and the currents it returns are the ones given."""
    state, v = (0.3, -0.2, 40.0, 0.1), (12.0, -5.0)
    own = currents_of_flux(state[0], state[1], syrm)
    assert flux_derivatives(state, v, syrm, False, currents=own) == flux_derivatives(state, v, syrm, False)
    other, frictionless = (1.5, -2.5), syrm.replace(B=0.0, T_load=0.0, T_coulomb=0.0)
    (dpsi_d, dpsi_q, dw, _), currents = flux_derivatives(state, v, frictionless, False, currents=other)
    w_e = float(syrm.pole_pairs) * state[2]
    assert currents == other
    assert float(dpsi_d) == pytest.approx(v[0] - float(syrm.R) * other[0] + w_e * state[1], rel=1e-14)
    assert float(dpsi_q) == pytest.approx(v[1] - float(syrm.R) * other[1] - w_e * state[0], rel=1e-14)
    torque = 1.5 * float(syrm.pole_pairs) * (state[0] * other[1] - state[1] * other[0])
    assert float(dw) == pytest.approx(torque / float(syrm.J), rel=1e-12)


def test_published_pm_syrm_law_is_drivecal_s_law_exactly():
    """Lelli et al.'s PM-SyRM law (ICEM 2024, doi 10.1109/ICEM60801.2024.10700403; motulator's 5.5-kW
    coefficients), written independently in ``helpers.blocks``, is drivecal's law with the iron bridge, and
    its Ld, Lq, lambda_m are still the small-signal values at zero current."""
    from helpers.blocks import LELLI_PM_SYRM, lelli_currents, lelli_small_signal

    motor = from_lelli(dc.MotorParams(), i_ref=10.0, **{k: float(v) for k, v in LELLI_PM_SYRM.items()})
    lam, ld, lq = lelli_small_signal()
    assert (float(motor.lambda_m), float(motor.Ld), float(motor.Lq)) == pytest.approx((lam, ld, lq), rel=1e-12)
    rng = np.random.default_rng(2)
    psi = rng.uniform([0.0, -1.3], [1.0, 1.3], size=(300, 2)).T  # currents up to ~50 A on either axis
    got = np.asarray(currents_of_flux(jnp.asarray(psi[0]), jnp.asarray(psi[1]), motor))
    np.testing.assert_allclose(got, np.asarray(lelli_currents(psi[0], psi[1])), rtol=0, atol=1e-12)
    at_rest = flux_of_currents(jnp.zeros(()), jnp.zeros(()), motor)
    assert float(at_rest[0]) == pytest.approx(lam, abs=1e-14) and float(at_rest[1]) == 0.0
    l_dd, l_dq, l_qq = (float(x) for x in incremental_inductances(*at_rest, motor))
    assert (l_dd, l_dq, l_qq) == pytest.approx((ld, 0.0, lq), rel=1e-12, abs=1e-15)
    # The bridge saturates asymmetrically in i_d: the incremental Ld at -12 A differs from that at +12 A.
    lower, upper = (float(incremental_inductances(*flux_of_currents(jnp.asarray(i), jnp.zeros(()), motor), motor)[0])
                    for i in (-12.0, 12.0))
    assert abs(lower - upper) > 0.02 * ld


@pytest.mark.parametrize("motor", [
    dc.MotorParams().replace(sat_d=0.4, sat_q=0.8, sat_dq=0.3, i_ref=10.0, exp_d=3.0, exp_dq_q=0.0),
    from_hinkkanen(dc.MotorParams(lambda_m=0.0), i_ref=20.0, **SYRM)])
def test_without_a_bridge_the_law_about_the_magnet_is_unchanged_to_the_last_bit(motor):
    """With sat_b = 0 and sat_at_zero = 0 the bridge's terms and the centre's correction are exact zeros: the
    currents are the self- and cross-saturation terms alone, bit for bit (the results of earlier releases)."""
    rng = np.random.default_rng(3)
    psi = jnp.asarray(rng.uniform([0.0, -0.1], [0.2, 0.1], size=(200, 2)).T)
    got = currents_of_flux(psi[0], psi[1], motor)
    terms = currents_of_flux(psi[0], psi[1], motor, bridge=False)  # the terms alone, as before the bridge
    assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(got, terms))
    # and about zero flux without any saturation term it is the linear machine about the magnet
    linear = dc.MotorParams(sat_at_zero=1.0)
    i_d, i_q = currents_of_flux(psi[0], psi[1], linear)
    np.testing.assert_allclose(np.asarray(i_d), np.asarray((psi[0] - linear.lambda_m) / linear.Ld), rtol=1e-12)
    np.testing.assert_allclose(np.asarray(i_q), np.asarray(psi[1] / linear.Lq), rtol=1e-12)
