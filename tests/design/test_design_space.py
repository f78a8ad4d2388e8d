"""The D-optimal search's design space (``drivecal.design._design_space``): its parameters map back to a
plan and waveform tables that say what they are."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from drivecal.design import load_plan_waveforms
from drivecal.design._design_space import build_param

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_a_multisine_the_optimum_empties_is_written_and_named_as_the_step_it_is():
    plan, specs = load_plan_waveforms(EXAMPLES / "multisine_plan.toml")
    par = build_param(plan, specs, 0.1)
    ax = par.axes[0][0]  # the d-multisine: u = (peak, phi, f_min, f_max); phi = pi/2 puts the whole peak in the offset
    u = np.array(par.u0)
    u[ax.start + 1] = math.pi / 2
    after, written = par.to_plan(u)
    assert after.segments[0].name == "locked d-step" and after.segments[1].name == "locked q-multisine"
    assert isinstance(written[("locked d-step", "v_d")], float) and np.ptp(after.segments[0].v_d) == 0
    assert written[("locked q-multisine", "v_q")]["kind"] == "multisine"
