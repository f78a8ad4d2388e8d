"""`drivecal fleet-report` for a production engineer: pass/fail first, the checks' false-alarm rates, the motor
file's nominal and limits, engineering units, trends along the serial or the test time, robust axes.

The batch tables are built without fits (tests/helpers/fleet_table.py); the browser test of the same page
is tests/report/test_fleet_report_browser.py.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from drivecal.cli import main
from drivecal.diagnose import WHITENESS_ALPHA
from drivecal.errors import DrivecalError
from drivecal.fleet import fleet_histograms, fleet_trends, render_fleet_html, residual_diagnostics
from drivecal.plan import default_plan
from helpers.fleet_table import DRIFTING, PLANTED, nominal, planted_table, tolerances

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def page_data(page: str) -> dict:
    found = re.search(r'<script type="application/json" id="fleet-data">(.*?)</script>', page, re.S)
    assert found, "no embedded fleet data"
    return json.loads(found.group(1))


def headings(page: str) -> list[str]:
    return re.findall(r"<h2>(.*?)</h2>", page)


@pytest.fixture(scope="module")
def table():
    return planted_table(600, seed=11)


def test_cli_draws_the_motor_files_nominal_and_limits(tmp_path, capsys, table):
    results, out = tmp_path / "results.parquet", tmp_path / "fleet.html"
    table.to_parquet(results, index=False)
    assert main(["fleet-report", str(results), "--html", str(out), "--motor", str(EXAMPLES / "motor_spec.toml")]) == 0
    said = capsys.readouterr().out
    assert f"{len(PLANTED)} outlier(s)" in said and f"{len(PLANTED)} fail" in said and "pass" in said
    data = page_data(out.read_text(encoding="utf-8"))
    params = data["parameters"]
    assert params["R"]["nominal"] == pytest.approx(0.45) and params["R"]["unit"] == "mΩ"
    assert params["R"]["tolerance"] == pytest.approx([0.45 * 0.95, 0.45 * 1.05])
    assert params["Ld"]["tolerance"] == pytest.approx([3.0e-3, 3.4e-3]) and params["Ld"]["unit"] == "mH"
    assert params["lambda_m"]["tolerance"][1] is None and params["lambda_m"]["unit"] == "mWb"
    assert params["lambda_m"]["tolerance"][0] == pytest.approx(0.0533 * 0.97)
    page = out.read_text(encoding="utf-8")
    assert "427.5 .. 472.5 (95.0 .. 105.0 %)" in page  # R's limits in mΩ and % of nominal
    assert "≥51.701 (97.0 %)" in page  # lambda_m's one-sided limit


def test_without_a_motor_file_there_is_no_nominal_and_no_percent(table):
    data = page_data(render_fleet_html(table, "t.parquet"))
    for p in data["parameters"].values():
        assert p["nominal"] is None and p["tolerance"] == [None, None] and p["off_scale"] == {}


def test_a_motor_file_without_a_parameter_draws_no_nominal_for_it(tmp_path, capsys, table):
    results, out, motor = tmp_path / "r.parquet", tmp_path / "f.html", tmp_path / "m.toml"
    table.to_parquet(results, index=False)
    motor.write_text('R = "0.45 ohm"\nLd = "3.2 mH"\nLq = "5.8 mH"\npole_pairs = 4\n')
    assert main(["fleet-report", str(results), "--html", str(out), "--motor", str(motor)]) == 0
    assert "lambda_m not in the file; no nominal line for it" in capsys.readouterr().err
    params = page_data(out.read_text(encoding="utf-8"))["parameters"]
    assert params["lambda_m"]["nominal"] is None and params["R"]["nominal"] == pytest.approx(0.45)


def test_pass_fail_counts_come_first_and_the_status_counts_without_a_specification(table):
    judged = render_fleet_html(table, "t.parquet", nominal=nominal(), tolerances=tolerances())
    assert headings(judged)[:2] == ["Pass/fail against the specification", "Calibration status"]
    counts = page_data(judged)["spec_counts"]
    assert list(counts) == ["pass", "fail", "inconclusive", "not calibrated", "invalid file"]
    assert counts == table["spec"].value_counts().reindex(list(counts)).fillna(0).astype(int).to_dict()
    assert "Out of specification (5)" in judged

    plain = render_fleet_html(table.drop(columns=["spec", "spec_failed", "spec_inconclusive"]), "t.parquet")
    assert headings(plain)[0] == "Calibration status"
    assert "spec-counts" not in plain and "data-check='spec'" not in plain
    assert page_data(plain)["spec_counts"] is None


def test_each_check_states_its_false_alarm_rate_from_its_threshold(table):
    data = page_data(render_fleet_html(table, "t.parquet", nominal=nominal(), tolerances=tolerances()))
    checks = data["checks"]
    assert checks["mismatch"]["rate"] == WHITENESS_ALPHA  # the level the whiteness rule runs at
    per_parameter = math.erfc(5.0 / math.sqrt(2.0))  # P(|Z| > 5)
    assert checks["outlier"]["rate"] == pytest.approx(1 - (1 - per_parameter) ** 4, rel=1e-9)
    assert checks["spec"]["rate"] == pytest.approx(0.025)
    usable = int(table["status"].isin(["calibrated", "partially calibrated"]).sum())
    assert checks["mismatch"]["expected"] == pytest.approx(usable * WHITENESS_ALPHA)
    assert checks["outlier"]["flagged"] == len(PLANTED) and checks["mismatch"]["flagged"] == 2
    assert checks["spec"]["flagged"] == len(PLANTED)

    # the threshold the table records is the one stated
    strict = table.assign(outlier_z=3.0)
    assert page_data(render_fleet_html(strict, "t"))["checks"]["outlier"]["rate"] == pytest.approx(
        1 - (1 - math.erfc(3.0 / math.sqrt(2.0))) ** 4, rel=1e-9)


def test_the_mismatch_alarm_on_white_residuals_fires_at_its_stated_rate():
    """The stated rate is the real one: white Gaussian residuals of the default plan's segments, 10 000 motors,
    through the fleet's own check (the textbook chi-squared p-values gave 0.25 %, 2.5 times the level)."""
    plan = default_plan()
    lengths = [s.num_samples(plan.sample_rate) for s in plan.segments]
    starts = np.zeros(sum(lengths), bool)
    starts[np.cumsum([0, *lengths[:-1]])] = True
    rng = np.random.default_rng(2024)
    alarms = sum(int(residual_diagnostics(rng.standard_normal((2000, len(starts), 2)), starts)["mismatch"].sum())
                 for _ in range(5))
    assert alarms <= 2 * WHITENESS_ALPHA * 10_000  # Poisson(<= 10): 20 or more has probability 0.003


def test_trends_go_by_serial_or_by_the_test_time(table, capsys, tmp_path):
    timed = planted_table(600, seed=11, test_time=True)
    by_serial = render_fleet_html(timed, "t")
    assert "--trend-by test_time" in by_serial  # offered
    data = page_data(render_fleet_html(timed, "t", trend_by="test_time"))
    assert data["trend_by"] == "test_time"
    x = data["parameters"][DRIFTING]["band"]["x"]
    assert x[0].startswith("2024-05-06T06:") and x == sorted(x)
    assert data["parameters"][DRIFTING]["drift_visible"]  # the line's time order is its serial order here

    with pytest.raises(DrivecalError, match="--trend-by nope: t has no such column; give one of: serial"):
        render_fleet_html(table, "t", trend_by="nope")
    results = tmp_path / "r.parquet"
    table.to_parquet(results, index=False)
    with pytest.raises(SystemExit) as info:
        main(["fleet-report", str(results), "--html", str(tmp_path / "f.html"), "--trend-by", "nope"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and "--trend-by nope" in err
    assert not (tmp_path / "f.html").exists()


def test_parameters_are_in_engineering_units_with_percent_of_nominal(table):
    page = render_fleet_html(table, "t", nominal=nominal(), tolerances=tolerances())
    for label in ("R [mΩ]", "Ld [mH]", "Lq [mH]", "lambda_m [mWb]"):
        assert f"<td class='l'>{label}</td>" in page
    row = re.search(r"<tr data-param='R'>(.*?)</tr>", page).group(1)
    cells = re.findall(r"<td[^>]*>(.*?)</td>", row)
    assert cells[1] == "450"  # nominal, mΩ
    median = table.loc[table["status"] == "calibrated", "R"].median()
    assert cells[3] == f"{median * 1e3:.5g} ({100 * median / 0.45:.1f} %)"


def test_the_old_figure_functions_use_the_robust_range_and_cost_the_same_for_more_motors():
    import matplotlib.pyplot as plt

    small, large = planted_table(600, seed=1), planted_table(3000, seed=1)
    fig = fleet_histograms(large, ["R"])
    lo, hi = fig.axes[0].get_xlim()
    r = large["R"].dropna()
    assert lo > r.min() and hi < r.max()  # the planted faults lie beyond the axis ...
    healthy = r[~large["outlier"]]
    assert lo < healthy.min() and healthy.max() < hi  # ... the population within it
    plt.close(fig)
    artists = []
    for t in (small, large):
        fig = fleet_trends(t)
        artists.append([len(ax.get_children()) for ax in fig.axes])
        plt.close(fig)
    assert artists[0] == artists[1]  # whole-array drawing: no artist per motor


# `drivecal fleet-report` as a fresh process runs it: the page drawn, then what the process had loaded.
_REPORT_PROGRAM = """
import sys
from drivecal.cli import main

assert main(["fleet-report", sys.argv[1], "--html", sys.argv[2], *sys.argv[3:]]) == 0
print(sorted(m for m in ("jax", "jaxlib", "equinox", "drivecal.physics", "drivecal.model", "drivecal.fitting")
             if m in sys.modules))
"""


@pytest.mark.parametrize("motor", [(), ("--motor", "examples/motor_spec.toml")], ids=["alone", "motor file"])
def test_the_fleet_report_loads_nothing_of_jax_or_the_fitting_stack(table, tmp_path, motor):
    """The page is pandas and matplotlib: JAX and the model (~0.6 s of imports) are not loaded for it, nor for
    a plain motor file's nominal values and limits (``--motor``)."""
    import subprocess
    import sys

    results, out = tmp_path / "results.parquet", tmp_path / "fleet.html"
    table.to_parquet(results, index=False)
    motor = tuple(str(Path(__file__).resolve().parents[2] / m) if m.endswith(".toml") else m for m in motor)
    proc = subprocess.run([sys.executable, "-c", _REPORT_PROGRAM, str(results), str(out), *motor],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "[]"
    assert "fleet-data" in out.read_text(encoding="utf-8")
