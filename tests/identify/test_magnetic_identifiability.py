"""Issue 18: identifiability names the saturation coefficients a plan cannot see, why, and the segment that would show them."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc
from drivecal.identify import assess_identifiability, current_levels, magnetic_reasons
from drivecal.model import model_experiment
from drivecal.physics import MAGNETIC, from_hinkkanen

#: Hinkkanen et al. 2017's 6.7-kW SyRM (doi 10.1109/TIA.2016.2644624), as in tests/selection.
HINKKANEN_SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)
NAMES = ("R", "Ld", "Lq") + MAGNETIC
#: Seven locked steps of 10 ms at 5 kHz, (v_d, v_q) (V) each: every plan here has this layout, so all share
#: one compiled Jacobian (30 V on d gives ~5 A, 20 V on q ~21 A on the SyRM below).
SINGLE = ((30.0, 0.0), (0.0, 20.0)) * 3 + ((30.0, 0.0),)  # the same d and q levels again and again
LEVELS = ((15.0, 0.0), (30.0, 0.0), (45.0, 0.0), (0.0, 10.0), (0.0, 20.0), (0.0, 30.0))
GENERIC = "no effect on the measured currents in this plan"


def _experiment(steps: tuple[tuple[float, float], ...]) -> dc.Experiment:
    segments = tuple(dc.Segment(f"step {k}", 0.01, True, v_d=v_d, v_q=v_q) for k, (v_d, v_q) in enumerate(steps))
    return dc.Experiment.from_plan(dc.Plan(segments, sample_rate=5000.0, v_dc=540.0, current_limit=80.0))


@pytest.fixture(scope="module")
def syrm() -> dc.MotorParams:
    return from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=20.0, **HINKKANEN_SYRM)


def test_single_level_steps_hide_every_coefficient_with_its_reason(syrm):
    experiment = _experiment(SINGLE)
    linear = syrm.replace(**{n: 0.0 * getattr(syrm, n) for n in MAGNETIC})  # same dtypes: the same compiled code
    for motor in (syrm, linear):  # the verdict is the plan's, whether the prior saturates or not
        ident = assess_identifiability(experiment, motor, names=NAMES)
        assert not ident.identifiable
        assert set(ident.dead_params) == set(MAGNETIC) and ident.fit_names == ("R", "Ld", "Lq")
        assert ident.weak_params == () and ident.confounded_params == ()  # sat_q no longer drags Lq down
        for axis in "dq":
            reason = ident.reasons[f"sat_{axis}"]
            assert f"one {axis}-axis current level only" in reason and "linear range" in reason
            assert "cannot separate a falling inductance from a constant one" in reason
            assert f"add locked {axis}-axis steps at two or more levels up to the current limit" in reason
            assert "1/3, 2/3 and the full limit" in reason
        cross = ident.reasons["sat_dq"]
        assert "no sample with d- and q-axis current at the same time" in cross and "combined d+q step" in cross
        assert set(ident.reasons) == set(MAGNETIC) and GENERIC not in " ".join(ident.reasons.values())
        assert all(np.isnan(ident.predicted_ci95[NAMES.index(n)]) for n in MAGNETIC)


def test_levels_without_a_combined_step_show_self_saturation_only(syrm):
    ident = assess_identifiability(_experiment(LEVELS + ((30.0, 0.0),)), syrm, names=NAMES)  # a level again
    assert not ident.identifiable
    assert ident.dead_params == ("sat_dq",) and ident.fit_names == ("R", "Ld", "Lq", "sat_d", "sat_q")
    assert set(ident.reasons) == {"sat_dq"}
    assert "no sample with d- and q-axis current at the same time" in ident.reasons["sat_dq"]
    assert "combined d+q step (both axes energised together" in ident.reasons["sat_dq"]
    assert all(np.isfinite(ident.predicted_ci95[NAMES.index(n)]) for n in ("sat_d", "sat_q"))


def test_levels_and_a_combined_step_identify_the_whole_law(syrm):
    ident = assess_identifiability(_experiment(LEVELS + ((20.0, 20.0),)), syrm, names=NAMES)  # d+q at once
    assert ident.identifiable and ident.rank == len(NAMES)
    assert ident.dead_params == ident.weak_params == ident.confounded_params == () and ident.reasons == {}
    assert ident.fit_names == NAMES and all(np.isfinite(ident.predicted_ci95))


def test_an_axis_without_current_is_named(syrm):
    """q-axis levels alone: no d-axis current at all, so sat_d is hidden for that reason; sat_q is seen."""
    experiment = model_experiment(_experiment(LEVELS[3:] * 2 + ((0.0, 40.0),)), syrm, NAMES)
    reasons = magnetic_reasons(experiment, syrm, NAMES)
    assert set(reasons) == {"sat_d", "sat_dq"}
    assert reasons["sat_d"].startswith("no d-axis current (i_d stays at zero)")
    assert "d-axis steps at two or more levels" in reasons["sat_d"]
    assert magnetic_reasons(experiment, syrm, ("R", "Ld", "Lq")) == {}


def test_current_levels_count_distinct_segment_peaks():
    start = np.zeros(40, dtype=bool)
    start[::10] = True  # four segments of ten samples
    currents = np.zeros((40, 2))
    currents[0:10, 0] = np.linspace(0.0, 3.0, 10)  # d-axis steps at 1/3, 2/3 and the full 9 A
    currents[10:20, 0] = -np.linspace(0.0, 6.0, 10)  # a negative step is a level by its magnitude
    currents[20:30, 0] = np.linspace(0.0, 9.0, 10)
    currents[30:40, 1] = np.linspace(0.0, 10.0, 10)  # one q-axis step ...
    currents[0:10, 1] = 0.5  # ... and a remnant below a tenth of it: no level
    currents[20:30, 1] = 9.0  # within 80 % of 10 A: the same level
    d_levels, q_levels = current_levels(currents, start)
    np.testing.assert_allclose(d_levels, (9.0, 6.0, 3.0))
    np.testing.assert_allclose(q_levels, (10.0,))
    assert current_levels(np.zeros((40, 2)), start) == ((), ())
