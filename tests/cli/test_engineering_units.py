"""What a person reads is in engineering units (issue 22 item 4): the fit table, the HTML summary and the
predicted intervals of `design` show mΩ, mH, mWb with the digits their interval supports; the JSON stays SI."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from drivecal.cli import main
from drivecal.results import summary_html

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _rows(text: str) -> dict[str, list[str]]:
    """The cells of each table row printed by rich, by their first cell."""
    rows = ([c.strip() for c in re.split("[\u2502\u2503]", line)[1:-1]] for line in text.splitlines())
    return {cells[0]: cells for cells in rows if cells}


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    out = tmp_path_factory.mktemp("units") / "out"
    capture = pytest.MonkeyPatch()
    import io
    import sys

    stdout = io.StringIO()
    capture.setattr(sys, "stdout", stdout)
    try:
        code = main(["fit", str(EXAMPLES / "bench.csv"), "--out", str(out)])
    finally:
        capture.undo()
    return code, stdout.getvalue(), out


def test_the_fit_table_shows_milliohms_and_millihenries(fitted):
    code, text, _ = fitted
    assert code == 0
    rows = _rows(text)
    header = rows["parameter"]
    assert header == ["parameter", "unit", "prior", "estimate", "std err", "95 % CI", "rel. CI [%]"]
    units = {n: rows[n][1] for n in ("R", "Ld", "Lq", "lambda_m")}
    assert units == {"R": "mΩ", "Ld": "mH", "Lq": "mH", "lambda_m": "mWb"}
    _, _, prior, estimate, se, ci, _ = rows["R"]
    assert prior == "450" and re.fullmatch(r"4[45]\d\.\d{3}", estimate), rows["R"]  # 450.039 ± 0.043 mΩ
    assert re.fullmatch(r"0\.0\d\d", se), rows["R"]  # the SE: two significant digits
    low, high = ci.strip("[]").split(", ")
    assert len(low.split(".")[1]) == len(estimate.split(".")[1]) == len(high.split(".")[1])  # one digit rule
    _, _, prior, estimate, se, _, _ = rows["Ld"]
    assert prior == "3.2" and re.fullmatch(r"3\.2\d{4}", estimate) and re.fullmatch(r"0\.000\d\d", se), rows["Ld"]
    assert " ohm" not in text and "0.0032" not in text  # no SI numbers of seven digits


def test_the_html_report_uses_engineering_units(fitted):
    _, _, out = fitted
    page = (out / "report.html").read_text(encoding="utf-8")
    summary = re.search(r'<table class="summary">.*?</table>', page).group(0)
    cells = re.findall(r"<td[^>]*>(.*?)</td>", summary)
    assert cells[:3] == ["R", "mΩ", "450"] and re.fullmatch(r"4[45]\d\.\d{3}", cells[3]), cells[:8]  # prior, estimate
    assert "mH" in cells and "mWb" in cells and "SI unit" not in summary
    # the JSON written beside it stays SI
    doc = json.loads((out / "report.json").read_text())
    assert doc["parameters"]["R"]["unit"] == "ohm" and abs(doc["parameters"]["R"]["estimate"] - 0.45) < 1e-3


def test_the_summary_of_a_traction_motor_reads_in_milliohms_and_microhenries():
    fit = {"parameters": {
        "R": {"estimate": 0.00429944, "se": 2.57e-08, "ci95": [0.00429939, 0.00429949], "unit": "ohm",
              "identifiable": True},
        "Ld": {"estimate": 0.000450932, "se": 3.1e-7, "ci95": [0.000450324, 0.00045154], "unit": "H",
               "identifiable": True},
        "lambda_m": {"estimate": 0.0533, "se": 0.0, "ci95": None, "unit": "Wb", "identifiable": False,
                     "reason": "the rotor never turns"}}}
    cells = re.findall(r"<td[^>]*>(.*?)</td>", summary_html(fit))
    # parameter, unit, prior, estimate, SE, CI low, CI high, relative half-width, change against the prior
    assert cells[:7] == ["R", "mΩ", "-", "4.299440", "0.000026", "4.299390", "4.299490"]
    assert cells[10:17] == ["Ld", "µH", "-", "450.93", "0.31", "450.32", "451.54"]
    assert cells[20:25] == ["lambda_m", "mWb", "-", "53.3", "-"]


def test_the_summary_shows_the_prior_and_the_change_against_it_in_the_rows_unit():
    fit = {"parameters": {"Ld": {"estimate": 0.000450932, "se": 3.1e-7, "ci95": [0.000450324, 0.00045154],
                                 "unit": "H", "identifiable": True, "prior": 0.000451}}}
    cells = re.findall(r"<td[^>]*>(.*?)</td>", summary_html(fit))
    assert cells[:3] == ["Ld", "µH", "451"]
    # (450.932 - 451) / 451 = -0.0151 %, to the decimals of the relative half-width beside it (0.13 %)
    assert cells[7] == "0.13" and cells[8] == "-0.02", cells


def test_fit_json_stays_si(capsys):
    assert main(["fit", str(EXAMPLES / "bench.csv"), "--json"]) == 0
    text = capsys.readouterr().out
    doc = json.loads(text)
    assert {n: p["unit"] for n, p in doc["parameters"].items()} == {"R": "ohm", "Ld": "H", "Lq": "H",
                                                                     "lambda_m": "Wb"}
    assert abs(doc["parameters"]["Ld"]["estimate"] - 0.0032) < 1e-5 and doc["parameters"]["Ld"]["se"] < 1e-5
    assert "mΩ" not in text and "mH" not in text and "µ" not in text


def test_design_predicts_intervals_in_engineering_units(capsys):
    assert main(["design", str(EXAMPLES / "default_plan.toml")]) == 0
    rows = _rows(capsys.readouterr().out)
    assert [rows[n][1] for n in ("R", "Ld", "Lq", "lambda_m")] == ["mΩ", "mH", "mH", "mWb"]
    _, _, nominal, half, relative, _ = rows["Ld"]
    assert nominal == "3.2" and re.fullmatch(r"0\.00\d\d", half) and re.fullmatch(r"0\.0\d\d", relative), rows["Ld"]
