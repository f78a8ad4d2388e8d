"""Pass/fail against the motor file's [tolerance]: the forms, the judgement with the interval, fit's and
batch's exit statuses and the inconclusive case's advice."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from drivecal.data import Tolerance, motor_from_dict
from drivecal.fleet import BatchSummary, spec_checks
from drivecal.results import FAIL, INCONCLUSIVE, PASS, Spec, Status, judge_arrays, judge_spec
from drivecal.cli import main
from tests.helpers.cli import assert_one_sentence, run_cli


def run_cli_output(args, capsys) -> tuple[int, str, str]:
    """``drivecal ARGS`` in-process: ``(exit status, stderr, stdout)``, whether it returned or exited."""
    try:
        code = main([str(a) for a in args])
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err, captured.out

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BASE = {"R": 0.45, "Ld": "3.2 mH", "Lq": "5.8 mH", "lambda_m": 0.0533, "pole_pairs": 4}


# --------------------------------------------------------------------------- the forms

def test_each_form_gives_its_limits():
    tol = motor_from_dict({**BASE, "tolerance": {
        "R": "5 %", "Ld": "0.2 mH", "lambda_m": "-3 %", "Lq": "+10 %", "J": ["-5 %", "+20 %"],
        "B": {"min": "5e-5 N*m*s", "max": "1.2e-4 N*m*s"}, "T_load": {"max": "0.01 N*m"}}}).tolerance
    assert list(tol) == ["R", "Ld", "Lq", "lambda_m", "J", "B", "T_load"]  # drivecal's order
    assert tol["R"][:2] == pytest.approx((0.4275, 0.4725))
    assert tol["Ld"][:2] == pytest.approx((3.0e-3, 3.4e-3))
    assert tol["lambda_m"].low == pytest.approx(0.97 * 0.0533) and tol["lambda_m"].high is None
    assert tol["Lq"].low is None and tol["Lq"].high == pytest.approx(1.1 * 5.8e-3)
    assert tol["J"][:2] == pytest.approx((0.95 * 1.2e-3, 1.2 * 1.2e-3))
    assert tol["B"][:2] == pytest.approx((5e-5, 1.2e-4))
    assert tol["T_load"].low is None and tol["T_load"].high == pytest.approx(0.01)
    assert motor_from_dict({**BASE, "tolerance": {"R": "±5 %"}}).tolerance["R"][:2] == tol["R"][:2]


@pytest.mark.parametrize("table, needles", [
    ({"pole_pairs": "5 %"}, ["'pole_pairs'", "does not estimate"]),
    ({"R": "5 mH"}, ["'R'", "resistance in ohm"]),
    ({"R": "0 %"}, ["'R'", "not a positive width"]),
    ({"R": ["+3 %", "-5 %"]}, ["'R'", "'-' first"]),
    ({"R": {"min": 1.0, "max": 0.5}}, ["'R'", "must be below max"]),
    ({"R": {"low": 1.0}}, ["'R'", "min and/or max"]),
    ({"offset_d": "5 %"}, ["'offset_d'", "nominal offset_d is 0", "absolute width"]),
])
def test_a_bad_tolerance_is_one_sentence_with_exit_2(tmp_path, capsys, table, needles):
    lines = [f"{k} = {json.dumps(v)}" for k, v in BASE.items()] + ["[tolerance]"]
    for k, v in table.items():
        value = "{ " + ", ".join(f"{a} = {json.dumps(b)}" for a, b in v.items()) + " }" if isinstance(v, dict) \
            else json.dumps(v)
        lines.append(f"{k} = {value}")
    motor = tmp_path / "m.toml"
    motor.write_text("\n".join(lines) + "\n")
    code, err = run_cli(["fit", EXAMPLES / "bench.csv", "--motor", motor], capsys)
    assert_one_sentence(code, err, str(motor), "tolerance", *needles)


# --------------------------------------------------------------------------- the judgement

def test_pass_only_when_the_whole_interval_is_inside_and_fail_only_when_it_is_outside():
    tol = Tolerance(1.0, 2.0, "")
    estimate = np.array([1.5, 1.05, 2.5, 0.9, 1.5, 1.5, 0.5])
    half = np.array([0.1, 0.1, 0.2, 0.2, 0.6, 0.1, 0.1])
    identifiable = np.array([True, True, True, True, True, False, True])
    outcome, factor = judge_arrays(estimate, estimate - half, estimate + half, identifiable, tol)
    assert outcome.tolist() == [PASS, INCONCLUSIVE, FAIL, INCONCLUSIVE, INCONCLUSIVE, INCONCLUSIVE, FAIL]
    # 1.05 is 0.05 from the limit with a half-width of 0.1: (0.1 / 0.05)^2 = 4 times the samples decide it.
    assert factor[1] == pytest.approx(4.0) and factor[3] == pytest.approx(4.0)
    assert factor[4] == pytest.approx((0.6 / 0.5) ** 2)
    assert math.isnan(factor[5]) and factor[0] == 1.0
    # one-sided: no upper limit
    upper_free = Tolerance(1.0, None, "")
    outcome, _ = judge_arrays([5.0, 0.5], [4.9, 0.4], [5.1, 0.6], [True, True], upper_free)
    assert outcome.tolist() == [PASS, FAIL]


def test_the_advice_factor_is_the_samples_that_shrink_the_interval_to_a_decision():
    """Shrink the interval by 1/sqrt(factor) (the samples times factor): it then just touches the limit."""
    tol = Tolerance(None, 0.47, "")
    e, half = 0.468, 0.004
    _, factor = judge_arrays([e], [e - half], [e + half], [True], tol)
    shrunk = half / math.sqrt(factor[0])
    assert e + shrunk == pytest.approx(0.47)
    a, _ = judge_arrays([e], [e - 0.99 * shrunk], [e + 0.99 * shrunk], [True], tol)
    assert a[0] == PASS


def test_a_motor_is_judged_by_its_worst_parameter_and_not_at_all_without_a_calibration():
    tol = {"R": Tolerance(0.4, 0.5, "x"), "Ld": Tolerance(3e-3, 3.4e-3, "y")}
    names = ("R", "Ld", "Lq", "lambda_m")
    est = np.array([0.45, 3.5e-3, 5.8e-3, 0.053])
    ci = np.stack([est * 0.999, est * 1.001], axis=1)
    judged = judge_spec(names, est, ci, [True] * 4, tol)
    assert judged.status is Spec.FAIL and judged.failed == ("Ld",)
    assert judged.to_dict()["parameters"][0]["outcome"] == "pass"
    assert judge_spec(names, est, ci, [True, False, True, True], tol).status is Spec.INCONCLUSIVE
    assert judge_spec(names, est, ci, [True] * 4, tol, Status.MISMATCH).status is Spec.NOT_CALIBRATED
    assert judge_spec(names, est, ci, [True] * 4, tol, Status.INVALID).status is Spec.INVALID
    not_estimated = judge_spec(names, est, ci, [True] * 4, {"J": Tolerance(1e-3, 2e-3, "z")})
    assert not_estimated.status is Spec.INCONCLUSIVE and "not identified" in not_estimated.advice()[0]


# --------------------------------------------------------------------------- drivecal fit

def _motor_with(tmp_path, tolerance: str) -> Path:
    path = tmp_path / "motor.toml"
    path.write_text((EXAMPLES / "motor.toml").read_text() + "\n[tolerance]\n" + tolerance + "\n")
    return path


@pytest.mark.parametrize("tolerance, code, status", [
    ('R = "5 %"\nLd = "5 %"\nLq = "+10 %"\nlambda_m = ["-2 %", "+2 %"]', 0, "pass"),
    ('R = { min = "0.46 ohm" }\nlambda_m = "2 %"', 6, "fail"),
    # the example's R is 0.45004 +- 0.00008: an upper limit at 0.45 ohm cuts its interval
    ('R = { max = "0.45 ohm" }\nlambda_m = "2 %"', 7, "inconclusive"),
])
def test_fit_exits_with_the_judgement(tmp_path, capsys, tolerance, code, status):
    motor = _motor_with(tmp_path, tolerance)
    got, err, out = run_cli_output(["fit", EXAMPLES / "bench.csv", "--motor", motor, "--json"], capsys)
    assert got == code, err
    spec = json.loads(out)["spec"]
    assert spec["status"] == status
    if status == "fail":
        assert spec["failed"] == ["R"] and spec["headline"] == "fail: out of specification: R"
    if status == "inconclusive":
        (advice,) = spec["advice"]
        factor = spec["parameters"][0]["samples_factor"]
        assert 1 < factor < 100 and f"{factor:.2g}x the samples" in advice and "0.45" in advice


def test_fit_without_a_calibration_is_not_judged_and_keeps_the_verdicts_status(tmp_path, capsys):
    motor = _motor_with(tmp_path, 'R = "5 %"')
    got, err, out = run_cli_output(["fit", EXAMPLES / "inverter_bench.csv", "--motor", motor, "--effects", "none",
                                    "--json"], capsys)
    doc = json.loads(out)
    assert doc["verdict"]["status"] == "mismatch" and got == Status.MISMATCH.exit_code
    assert doc["spec"]["status"] == "not_calibrated" and doc["spec"]["parameters"] == []


def test_fit_without_tolerances_has_no_spec_section(capsys):
    got, _, out = run_cli_output(["fit", EXAMPLES / "bench.csv", "--json"], capsys)
    assert got == 0 and "spec" not in json.loads(out)


# --------------------------------------------------------------------------- drivecal batch

def _table() -> pd.DataFrame:
    rows = []
    for serial, r, status, mismatch in [("SN1", 0.45, "calibrated", False), ("SN2", 0.52, "calibrated", False),
                                        ("SN3", 0.4725, "calibrated", False), ("SN4", 0.45, "calibrated", True),
                                        ("SN5", np.nan, "not converged", False), ("SN6", np.nan, "invalid file", False)]:
        rows.append({"serial": serial, "file": serial, "status": status, "mismatch": mismatch, "R": r,
                     "R_ci_low": r - 0.001, "R_ci_high": r + 0.001, "R_identifiable": status == "calibrated"})
    return pd.DataFrame(rows)


def test_the_batch_table_gets_a_judgement_per_motor():
    tol = motor_from_dict({**BASE, "tolerance": {"R": "5 %"}}).tolerance
    judged = spec_checks(_table(), tol)
    assert judged["spec"].tolist() == ["pass", "fail", "inconclusive", "not calibrated", "not calibrated",
                                       "invalid file"]
    assert judged["spec_failed"].tolist() == ["", "R", "", "", "", ""]
    assert judged["spec_inconclusive"].tolist() == ["", "", "R", "", "", ""]
    assert spec_checks(_table(), {}) is not None and "spec" not in spec_checks(_table(), {})


@pytest.mark.parametrize("counts, code", [
    ({"pass": 3}, 0), ({"pass": 3, "inconclusive": 1}, 7), ({"pass": 3, "invalid file": 1, "inconclusive": 1}, 1),
    ({"pass": 3, "fail": 1, "not calibrated": 1}, 6), (None, 0)])
def test_the_batch_exit_status_is_the_most_serious_judgement(counts, code):
    summary = BatchSummary(out=Path("x.parquet"), total=4, done_before=0, calibrated=4, partial=0, failed=0,
                           outliers=(), mismatch=(), seconds=1.0, spec=counts)
    assert summary.exit_code == code


def test_batch_writes_the_spec_column_and_exits_6_on_a_failed_motor(tmp_path, capsys):
    from drivecal import fleet

    fleet.synthetic_fleet(tmp_path / "in", 3, seed=3, spread=0.0, outliers={1: {"R": 1.2}})
    motor = tmp_path / "m.toml"
    motor.write_text('R = "0.45 ohm"\nLd = "3.2 mH"\nLq = "5.8 mH"\nlambda_m = "0.0533 Wb"\npole_pairs = 4\n'
                     '[tolerance]\nR = "5 %"\nlambda_m = "2 %"\n')
    code, err, out = run_cli_output(["batch", tmp_path / "in", "--out", tmp_path / "r.parquet", "--motor", motor,
                                     "--workers", "1", "--json"], capsys)
    assert code == 6, err
    table = pd.read_parquet(tmp_path / "r.parquet").set_index("serial")
    assert table["spec"].to_dict() == {"SN000000": "pass", "SN000001": "fail", "SN000002": "pass"}
    assert table.loc["SN000001", "spec_failed"] == "R"
    assert json.loads(out)["spec"] == {"pass": 2, "fail": 1, "inconclusive": 0, "not calibrated": 0,
                                       "invalid file": 0}
    # when each bench file was written: the fleet report's trends may follow it
    assert str(table["tested_at"].dtype) == "datetime64[ns, UTC]" and table["tested_at"].notna().all()
    code, err, _ = run_cli_output(["fleet-report", tmp_path / "r.parquet", "--html", tmp_path / "f.html", "--motor",
                                   motor, "--trend-by", "tested_at"], capsys)
    page = (tmp_path / "f.html").read_text()
    assert code == 0 and "SN000001" in page and "Pass/fail against the specification" in page, err


def test_the_html_report_shows_the_judgement_and_the_advice():
    from drivecal.report import spec_html

    tol = {"R": Tolerance(None, 0.45, "R max")}
    judged = judge_spec(("R",), np.array([0.44996]), np.array([[0.44988, 0.45004]]), [True], tol).to_dict()
    page = spec_html({"spec": judged})
    assert 'data-spec="inconclusive"' in page and "x the samples" in page and "R [mΩ]" in page
    assert spec_html({}) == ""


def test_the_example_spec_motor_file_passes_the_example_bench(capsys):
    code, err, out = run_cli_output(["fit", EXAMPLES / "bench.csv", "--motor", EXAMPLES / "motor_spec.toml", "--json"],
                                    capsys)
    spec = json.loads(out)["spec"]
    assert code == 0 and spec["status"] == "pass", err
    assert [p["name"] for p in spec["parameters"]] == ["R", "Ld", "Lq", "lambda_m"]
