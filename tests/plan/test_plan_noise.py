"""A plan file's `current_noise`: the current-sensor noise [A] the plan was designed for (issue 22 item 2).

Absent, nothing changes (no key written, none in the JSON, existing plans round-trip byte-identical);
present, it round-trips in SI and is refused in one sentence when it is no positive current.
"""

from __future__ import annotations

import dataclasses
import tomllib
from pathlib import Path

import pytest
from helpers.cli import assert_plan_refused

from drivecal.errors import PlanError
from drivecal.plan import default_plan, load_plan, plan_from_dict, plan_to_dict, plan_toml, write_plan

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SEGMENTS = [{"name": "a", "duration": "10 ms", "locked": True, "v_d": "8 V"}]


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*plan*.toml")))
def test_plans_without_it_write_back_as_before(name, tmp_path):
    plan = load_plan(EXAMPLES / name)
    assert plan.current_noise is None
    text = plan_toml(plan)
    assert "current_noise" not in text and "current_noise" not in plan_to_dict(plan)
    written = {"sample_rate", "v_dc", "current_limit", "segment"} | ({"max_speed"} if plan.max_speed else set()) | (
        set() if plan.inverter.is_default else {"inverter"})
    assert set(tomllib.loads(text)) == written
    again = load_plan(write_plan(tmp_path / name, plan))
    assert plan_toml(again) == text


def test_it_loads_in_si_and_round_trips(tmp_path):
    plan = plan_from_dict({"current_noise": "60 mA", "segment": SEGMENTS}, source="p.toml")
    assert plan.current_noise == pytest.approx(0.06, rel=1e-12)
    text = plan_toml(plan)
    assert text.count("current_noise = 0.06") == 1
    assert tomllib.loads(text)["current_noise"] == pytest.approx(0.06, rel=1e-12)
    again = load_plan(write_plan(tmp_path / "plan.toml", plan))
    assert again.current_noise == plan.current_noise
    assert plan_toml(again) == text  # byte-identical the second time round
    assert plan_to_dict(again)["current_noise"] == plan.current_noise
    # Only the key is new: the rest of the file is that of the same plan without it.
    without = plan_toml(dataclasses.replace(plan, current_noise=None)).splitlines()
    assert [line for line in text.splitlines() if not line.startswith("current_noise")] == without


@pytest.mark.parametrize("value, needles", [
    (-0.02, ["'current_noise' must be positive", "current_noise = \"20 mA\""]),
    (0.0, ["'current_noise' must be positive"]),
    ("20 mV", ["'current_noise'", "a current in A"]),
    ("lots", ["'current_noise'"]),
])
def test_a_bad_value_is_one_sentence_naming_the_file_and_key(value, needles):
    assert_plan_refused({"current_noise": value, "segment": SEGMENTS}, *needles)


def test_a_plan_built_in_python_checks_it():
    with pytest.raises(PlanError, match="current_noise must be a positive number of amperes"):
        dataclasses.replace(default_plan(), current_noise=float("nan")).check_feasible()
    assert dataclasses.replace(default_plan(), current_noise=0.02).check_feasible().current_noise == 0.02
