"""The verdict on a measured speed too coarse or noisy for an exact input (issue 22, item 3): with mismatch
it names the speed input first, with ``--simulated-speed`` / ``--speed output`` as the fix, and the effect
tests' findings as signatures the speed leaves too (no 'raise delay_samples'); without, a note."""

from __future__ import annotations

import math

from drivecal.data import SpeedResolution
from drivecal.diagnose import verdict

STEP = 2 * math.pi / 4096 * 1000.0  # one count of a 4096-count encoder per 1 ms: 1.534 rad/s


def _result(mode: str, *, white: bool = True, delay_suspected: bool = False) -> dict:
    """A converged fit's result JSON with a flagged speed used as ``mode``."""
    delay = {"effect": "delay", "suspected": delay_suspected, "p_value": 1e-9, "statistic": 40.0, "dof": 1,
             "message": "the residuals carry the signature of more PWM/computation delay than the 0 sample(s) "
                        "assumed (score test p = 1e-09); raise 'delay_samples' (motor file) or --delay, or use "
                        "--effects auto"}
    res = SpeedResolution(step=STEP, hold=1, noise=0.9, sample_rate=1000.0, span=45.0)
    return {"converged": True, "parameters": {"lambda_m": {"identifiable": True}},
            "residuals": {"white": white, "per_segment": [], "whiteness_p_threshold": 1e-3, "sigma_stated": 0.02,
                          "noise_consistent": True, "sigma_ratio": 1.0, "unmodelled_effects": [delay]},
            "speed": {"mode": mode, "flagged": True, "input_error_ratio": 126.0, "input_error_ratio_max": 0.1,
                      "resolution": res.to_dict()}}


def test_the_verdict_puts_mismatch_down_to_a_coarse_speed_input_and_advises_its_fix():
    judged = verdict(_result("input", delay_suspected=True))
    assert judged["status"] == "mismatch"
    assert judged["headline"] == ("model mismatch suspected: most likely the measured speed input (see the first "
                                  "detail for the fix)")
    first = judged["details"][0]
    assert "4096-count encoder" in first and "--simulated-speed" in first and "--speed output" in first
    text = " ".join(judged["details"])
    assert "delay_samples" not in text and "signature like that of delay" in text  # not 'raise delay_samples'
    # an effect the selection fitted to the speed's errors is marked as possibly theirs
    fitted = {"effect": "dead_time", "included": True, "how": "selected", "p_value": 1e-16,
              "estimate": {"v_dead": {"value": -0.19, "se": 0.02}}}
    judged = verdict({**_result("input", white=False), "effects": {"effects": [fitted]}})
    assert judged["details"][-1].endswith("the speed input's errors can leave its signature too")


def test_a_coarse_speed_taken_as_an_output_is_a_note_not_a_mismatch():
    judged = verdict(_result("output"))
    assert judged["status"] == "calibrated"
    assert any("it was a second measured output" in d for d in judged["details"])
    # used as an input without any sign of mismatch: a note, the fix named
    judged = verdict(_result("input"))
    assert judged["status"] == "calibrated" and "--simulated-speed" in judged["details"][-1]
