"""A quantised-encoder bench through the default `drivecal fit` (issue 22, item 3).

The default plan at 1 kHz on the engine, DEFAULT_MOTOR, 20 mA of current noise (seed 1), the speed as a
4096-count encoder gives it differenced at 1 kHz (`drivecal simulate --encoder-counts 4096`): steps of
1.534 rad/s, each the mean speed over the sample before. Taken as an exact input it put lambda_m 2.8 %
(10 SE) off with a dead time fitted to the speed's errors. The default fit finds the steps, takes the
speed as a second measured output weighed by them, says so, and covers lambda_m (|z| < 3); asked to
take it as an input anyway, its verdict names the speed input and the fix.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from drivecal.cli import main
from drivecal.data import load_bench
from drivecal.physics import DEFAULT_MOTOR

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture(scope="module")
def encoder_bench(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("encoder")
    plan = folder / "plan.toml"
    plan.write_text((EXAMPLES / "default_plan.toml").read_text().replace('sample_rate = "20 kHz"',
                                                                         'sample_rate = "1 kHz"'))
    out = folder / "bench.csv"
    assert main(["simulate", str(plan), "--encoder-counts", "4096", "--noise", "0.02", "--seed", "1",
                 "--out", str(out)]) == 0
    return out


def test_simulate_records_the_speed_as_a_4096_count_encoder_differenced_at_the_sample_rate(encoder_bench):
    res = load_bench(encoder_bench).speed_resolution()
    assert res.step == pytest.approx(2 * math.pi / 4096 * 1000.0, rel=1e-9)
    assert res.counts_per_rev == 4096 and res.hold == 1


def test_the_default_fit_takes_a_quantised_speed_as_an_output_says_why_and_covers_lambda_m(encoder_bench, tmp_path,
                                                                                           capsys):
    code = main(["fit", str(encoder_bench), "--out", str(tmp_path / "out")])
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "out" / "report.json").read_text())
    speed = doc["speed"]
    assert speed["mode"] == "output" and speed["requested"] is None and speed["flagged"]
    assert speed["resolution"]["counts_per_rev"] == 4096 and speed["input_error_ratio"] > 10
    assert doc["measured_speed"] is False
    line = next(x for x in printed.splitlines() if x.startswith("speed: "))
    assert "steps of 1.534 rad/s" in " ".join(printed.split())
    assert "measured output instead" in " ".join(printed.split()) and line
    p = doc["parameters"]["lambda_m"]
    z = (p["estimate"] - float(DEFAULT_MOTOR.lambda_m)) / p["se"]
    assert abs(z) < 3, (z, p)
    assert code == 0 and doc["verdict"]["status"] == "calibrated", doc["verdict"]
    assert "delay_samples" not in " ".join(doc["verdict"]["details"])


def test_the_speed_taken_as_an_input_anyway_is_named_by_the_verdict_with_its_fix(encoder_bench, capsys):
    code = main(["fit", str(encoder_bench), "--speed", "input", "--effects", "none", "--json"])
    doc = json.loads(capsys.readouterr().out)
    verdict = doc["verdict"]
    assert code == 4 and verdict["status"] == "mismatch"
    assert verdict["headline"].endswith("most likely the measured speed input (see the first detail for the fix)")
    assert "--simulated-speed" in verdict["details"][0] and "4096-count encoder" in verdict["details"][0]
    assert "delay_samples" not in " ".join(verdict["details"])
    assert doc["speed"]["mode"] == "input" and doc["speed"]["requested"] == "input" and doc["measured_speed"]
