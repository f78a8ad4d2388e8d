"""Saturation: a motor whose Ld falls with current (on the engine) is detected; a linear one is not."""

from __future__ import annotations

import pytest

import drivecal as dc
from drivecal.bench import run_held_voltages
from helpers.blocks import saturating_pmsm_block
from drivecal.bench import pmsm_block

#: Locked steps at two current levels per axis (about 5 A and 25 A on d, 3.6 A and 14 A on q).
LEVELS = dc.Plan((dc.Segment("d 3 V", 0.01, True, v_d=3.0), dc.Segment("d 12 V", 0.01, True, v_d=12.0),
                  dc.Segment("q 3 V", 0.01, True, v_q=3.0), dc.Segment("q 12 V", 0.01, True, v_q=12.0)))


def _bench(block_for, seed):
    segments = []
    for seg in LEVELS.segments:
        v = seg.voltages(LEVELS.sample_rate)
        t, x = run_held_voltages(block_for(), v, LEVELS.sample_rate)
        segments.append(dc.SegmentData(seg.name, True, t, v, x[:, :2].copy()))
    return dc.BenchData(tuple(segments), LEVELS.sample_rate).add_noise(0.02, seed)


@pytest.fixture(scope="module")
def benches(truth):
    saturating = _bench(lambda: saturating_pmsm_block(truth, d_saturation_current=20.0, locked=True), 1)
    linear = _bench(lambda: pmsm_block(truth, locked=True), 1)
    return saturating, linear


@pytest.mark.slow
def test_saturating_d_axis_is_detected(benches, guess):
    check = dc.check_saturation(benches[0], guess)
    assert check.saturating == ("Ld",)
    assert check.largest_z["Ld"] > 10 * check.z_limit
    assert check.largest_z["Lq"] < check.z_limit  # the q axis is linear in this motor
    low, high = sorted((x for x in check.levels if x.parameter == "Ld"), key=lambda x: x.current)
    assert high.estimate < 0.85 * low.estimate  # less inductance at 25 A than at 5 A
    assert any("Ld changes with current" in f and "saturates" in f and "average" in f for f in check.findings)
    # With a saturating law fitted, the same finding says the law models it, not to average it away.
    modelled = dc.check_saturation(benches[0], guess, modelled=True)
    assert modelled.levels == check.levels
    assert any("the fitted saturating law models" in f and "average" not in f for f in modelled.findings)


@pytest.mark.slow
def test_linear_motor_is_not_flagged(benches, guess, truth):
    check = dc.check_saturation(benches[1], guess)
    assert check.saturating == () and set(check.tested) == {"Ld", "Lq"}
    for level in check.levels:
        assert abs(level.estimate - float(getattr(truth, level.parameter))) < 3.5 * level.se


def test_one_level_is_not_tested(clean_default, guess):
    check = dc.check_saturation(clean_default.add_noise(0.02, 1), guess)
    assert check.tested == () and check.findings == ()
