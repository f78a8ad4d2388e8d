"""Plan keys for coast-downs: `continue = true` (a segment starts where the previous one ended) and
`inverter = "off"` (no current flows, the rotor coasts); each misuse refused in one sentence."""

from __future__ import annotations

import tomllib

import pytest

from drivecal.errors import DrivecalError
from drivecal.plan import plan_from_dict, plan_to_dict, plan_toml

HEAD = {"sample_rate": "20 kHz", "v_dc": "48 V"}
SPIN = {"name": "spin-up", "duration": "50 ms", "locked": False, "v_q": "12 V"}
BRAKE = {"name": "braking", "duration": "20 ms", "locked": False, "continue": True}
COAST = {"name": "coast-down", "duration": "100 ms", "locked": False, "continue": True, "inverter": "off"}


def test_continuing_and_inverter_off_segments_load_and_round_trip():
    plan = plan_from_dict({**HEAD, "segment": [SPIN, BRAKE, COAST]})
    assert [(s.continues, s.inverter) for s in plan.segments] == [(False, "on"), (True, "on"), (True, "off")]
    again = plan_from_dict(tomllib.loads(plan_toml(plan)))
    assert [(s.continues, s.inverter) for s in again.segments] == [(False, "on"), (True, "on"), (True, "off")]
    segments = plan_to_dict(plan)["segments"]
    assert "continue" not in segments[0] and segments[1]["continue"] is True and segments[2]["inverter"] == "off"


@pytest.mark.parametrize("segments, needles", [
    ([BRAKE], ["'braking'", "first segment cannot continue"]),
    ([SPIN, {**BRAKE, "locked": True}], ["'braking'", "locked and the other free"]),
    ([SPIN, {**COAST, "continue": False}], ["'coast-down'", "continue = true"]),
    ([{**SPIN, "locked": True}, {**COAST, "locked": True}], ["'coast-down'", "locked = false"]),
    ([SPIN, {**COAST, "v_q": "3 V"}], ["'coast-down'", "no voltage is applied"]),
    ([SPIN, {**COAST, "inverter": "open"}], ["inverter"]),
    ([SPIN, {**BRAKE, "continues": True}], ["unknown key", "continue"]),
])
def test_misused_keys_are_refused_naming_the_segment(segments, needles):
    with pytest.raises(DrivecalError) as info:
        plan_from_dict({**HEAD, "segment": segments}, "p.toml")
    message = str(info.value)
    assert message.startswith("p.toml") and "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)
