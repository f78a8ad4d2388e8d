"""--magnetics auto: the data choose the saturating law on a saturating machine, and the linear one on a linear
machine; the saturating fit recovers the published coefficients within their standard errors."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.physics import from_hinkkanen
from drivecal.selection import select_effects

#: Hinkkanen et al. 2017's 6.7-kW SyRM (doi 10.1109/TIA.2016.2644624; coefficients as in Aalto's motulator).
HINKKANEN_SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)
S = dc.Segment
#: Locked steps at three levels per axis and combined d+q steps (to about 10 A on d and 39 A on q).
LEVELS = dc.Plan((S("d 15 V", 0.01, True, v_d=15.0), S("d 30 V", 0.01, True, v_d=30.0), S("d 45 V", 0.01, True, v_d=45.0),
                  S("q 10 V", 0.01, True, v_q=10.0), S("q 20 V", 0.01, True, v_q=20.0), S("q 30 V", 0.01, True, v_q=30.0),
                  S("d+q", 0.01, True, v_d=20.0, v_q=20.0), S("d-q", 0.01, True, v_d=30.0, v_q=-30.0)),
                 sample_rate=10000.0, v_dc=540.0, current_limit=80.0)


@pytest.fixture(scope="module")
def syrm_selection():
    truth = from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=20.0, **HINKKANEN_SYRM)
    bench = engine_bench(LEVELS, truth).add_noise(0.02, 3)
    prior = dc.MotorParams(R=0.5, Ld=0.05, Lq=0.02, lambda_m=0.0, pole_pairs=2.0, J=0.015)
    return truth, select_effects(bench.experiment(), bench.currents, prior, names=("R", "Ld", "Lq"), magnetics="auto")


@pytest.mark.slow
def test_saturating_synchronous_reluctance_motor_is_found_and_fitted(syrm_selection):
    truth, sel = syrm_selection
    cal = sel.calibration
    assert sel.magnetic_model == "saturating" and bool(cal.converged)
    # The truth at the fit's reference current, to compare coefficients in its units.
    at = from_hinkkanen(truth, i_ref=float(cal.motor.i_ref), **HINKKANEN_SYRM)
    for name in ("R", "Ld", "Lq"):
        i = cal.names.index(name)
        assert abs(float(cal.estimate[i]) - float(getattr(at, name))) < 3 * float(cal.se[i]), name
    exponents = {"sat_d": ("exp_d",), "sat_q": ("exp_q",), "sat_dq": ("exp_dq_d", "exp_dq_q")}
    for name, which in exponents.items():
        if name in cal.fit_names and all(float(getattr(cal.motor, e)) == float(getattr(at, e)) for e in which):
            i = cal.names.index(name)
            assert abs(float(cal.estimate[i]) - float(getattr(at, name))) < 3 * float(cal.se[i]), name
    assert "magnetic saturation" in " ".join(c.note for c in sel.choices if c.included)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 18 open: a delay and sensor offsets are still added beside the "
                                       "saturating law on this bench (each within ~1.3 SE of zero at the end): "
                                       "the selection needs a backward step that drops what the law explains")
def test_no_bench_effect_stands_in_for_the_iron(syrm_selection):
    _, sel = syrm_selection
    assert not set(sel.included) & {"delay", "dead_time", "offsets"}


def test_linear_seed_motor_stays_linear(truth):
    bench = dc.engine_bench(dc.default_plan(), truth).add_noise(0.02, 5)
    sel = select_effects(bench.experiment(), bench.currents, truth, names=dc.ESTIMATED, magnetics="auto")
    assert sel.magnetic_model == "linear" and sel.included == ()
    choices = {c.effect: c for c in sel.choices}
    for term in ("saturation_d", "saturation_q", "cross_saturation"):
        assert not choices[term].included and np.isfinite(choices[term].p_value)
