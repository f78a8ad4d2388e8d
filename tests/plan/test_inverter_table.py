"""A plan file's `[inverter]` table (what `drivecal simulate` runs the plan on): defaults, round trip, refusals."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest
from helpers.cli import assert_plan_refused

from drivecal.errors import PlanError
from drivecal.plan import (Inverter, Plan, default_plan, load_plan, plan_from_dict, plan_to_dict, plan_toml,
                           write_plan)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SEGMENTS = [{"name": "a", "duration": "10 ms", "locked": True, "v_d": "8 V"}]
TABLE = {"model": "switching", "modulation": "sine", "dead_time": "1 us", "device_drop": "0.7 V"}


def test_no_table_is_the_averaged_ideal_inverter_and_is_not_written():
    plan = load_plan(EXAMPLES / "default_plan.toml")
    assert plan.inverter == Inverter() == Inverter("averaged", "svpwm", 0.0, 0.0) and plan.inverter.is_default
    assert default_plan().inverter.is_default
    # Existing plans write back as before: no [inverter] table, no "inverter" in the JSON.
    assert "[inverter]" not in plan_toml(plan) and "inverter" not in plan_to_dict(plan)
    with pytest.raises(Exception):  # immutable
        plan.inverter.model = "switching"


def test_table_loads_in_si_and_round_trips(tmp_path):
    plan = plan_from_dict({"inverter": TABLE, "segment": SEGMENTS}, source="p.toml")
    assert plan.inverter == Inverter("switching", "sine", pytest.approx(1e-6), pytest.approx(0.7))
    text = plan_toml(plan)
    assert text.count("[inverter]") == 1
    assert plan_from_dict(tomllib.loads(text)).inverter == plan.inverter
    written = write_plan(tmp_path / "plan.toml", plan)
    again = load_plan(written)
    assert again.inverter == plan.inverter
    assert plan_toml(again) == text  # byte-identical the second time round
    assert plan_to_dict(plan)["inverter"] == {"model": "switching", "modulation": "sine",
                                             "dead_time": plan.inverter.dead_time, "device_drop": 0.7}
    # A partial table takes the defaults for the rest.
    partial = plan_from_dict({"inverter": {"model": "switching"}, "segment": SEGMENTS})
    assert partial.inverter == Inverter(model="switching")


@pytest.mark.parametrize("table, needles", [
    ({"deadtime": "1 us"}, ["unknown key 'inverter.deadtime'", "in [inverter]: model, modulation, dead_time"]),
    ({"model": "pwm"}, ["'inverter.model'", "'averaged' or 'switching'"]),
    ({"modulation": "spwm"}, ["'inverter.modulation'", "'svpwm' or 'sine'"]),
    ({"dead_time": "1 V"}, ["'inverter.dead_time'", "has unit 'V' but a time in s"]),
    ({"dead_time": -1e-6}, ["'inverter.dead_time' must be >= 0", "dead_time = \"1 us\""]),
    ({"dead_time": "30 us"}, ["'inverter.dead_time'", "shorter than half the carrier period (2.5e-05 s at 20000 Hz)"]),
    ({"device_drop": -0.5}, ["'inverter.device_drop' must be >= 0", "device_drop = \"0.7 V\""]),
    ("switching", ["'inverter'", "as an [inverter] table"]),
])
def test_bad_table_is_one_sentence_naming_the_file_and_field(table, needles):
    assert_plan_refused({"inverter": table, "segment": SEGMENTS}, *needles)


def test_a_plan_built_in_python_checks_its_inverter():
    segments = plan_from_dict({"segment": SEGMENTS}).segments
    with pytest.raises(PlanError, match=r"inverter model must be \"averaged\" or \"switching\", got 'pwm'"):
        Plan(segments, inverter=Inverter(model="pwm")).check_feasible()
    with pytest.raises(PlanError, match=r"inverter dead_time must be a number of s >= 0"):
        Plan(segments, inverter=Inverter(dead_time=-1.0)).check_feasible()
