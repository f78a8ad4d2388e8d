"""Plans: the default plan and the feasibility check."""

from __future__ import annotations

import numpy as np
import pytest

import drivecal as dc


def test_default_plan_is_the_standard_three_segments():
    plan = dc.default_plan().check_feasible()
    assert [s.name for s in plan.segments] == ["locked d-step", "locked q-step", "free spin-up"]
    assert [s.locked for s in plan.segments] == [True, True, False]
    assert plan.sample_rate == 20_000.0
    assert plan.num_samples == 200 + 200 + 1000
    assert plan.voltage_limit == pytest.approx(48.0 / np.sqrt(3.0))


def test_voltage_outside_the_circle_names_the_segment():
    plan = dc.Plan(segments=(dc.Segment("ok", 0.01, True, v_d=8.0), dc.Segment("too hot", 0.01, True, v_d=20, v_q=20)))
    with pytest.raises(dc.PlanError, match=r"segment 'too hot'.*28\.28 V.*27\.71 V"):
        plan.check_feasible()


def test_sequence_of_wrong_length_is_refused():
    plan = dc.Plan(segments=(dc.Segment("seq", 0.001, True, v_d=[1.0, 2.0, 3.0]),))
    with pytest.raises(dc.PlanError, match="segment 'seq': v_d has 3 values but the segment holds 20 samples"):
        plan.check_feasible()


def test_per_sample_sequence_is_held():
    seg = dc.Segment("seq", 0.0002, True, v_d=[1.0, 2.0, 3.0, 4.0], v_q=0.5)
    np.testing.assert_array_equal(seg.voltages(20_000.0), [[1, 0.5], [2, 0.5], [3, 0.5], [4, 0.5]])


@pytest.mark.parametrize(
    "plan, message",
    [
        (dc.Plan(segments=()), "no segments"),
        (dc.Plan(segments=(dc.Segment("a", 1e-5, True, v_d=1.0),)), "at least two sample periods"),
        (dc.Plan(segments=(dc.Segment("a", 0.01, True), dc.Segment("a", 0.01, True))), "unique"),
        (dc.Plan(segments=(dc.Segment("a", 0.01, True, v_d=float("nan")),)), "finite"),
        (dc.Plan(segments=(dc.Segment("a", 0.01, True),), v_dc=-1.0), "v_dc"),
    ],
)
def test_malformed_plans_are_refused(plan, message):
    with pytest.raises(dc.PlanError, match=message):
        plan.check_feasible()
