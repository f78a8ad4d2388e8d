"""Result object, saved-result JSON, verdicts and the HTML report."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.cli import main
from drivecal.report import build_result
from drivecal.diagnose import residual_checks

TIME_STAMP = re.compile(r'<time id="generated">[^<]*</time>')


def _via_json(d):
    return json.loads(json.dumps(d, allow_nan=False))


@pytest.mark.parametrize("which", ["default_fit", "poor_fit"])
def test_to_dict_json_from_dict_reproduces_the_result(which, request):
    cal = request.getfixturevalue(which)
    back = dc.Calibration.from_dict(_via_json(cal.to_dict()))
    assert back.to_dict() == cal.to_dict()
    np.testing.assert_array_equal(back.estimate, cal.estimate)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    np.testing.assert_array_equal(back.history, cal.history)
    assert back.names == cal.names and back.fit_names == cal.fit_names and back.identifiable == cal.identifiable
    assert back.prior == cal.prior and back.motor == cal.motor
    assert str(back) == str(cal)


def test_printed_report_is_lmfit_style(poor_fit):
    text = str(poor_fit)
    for section in ("[[Fit Statistics]]", "[[Parameters]]", "[[Correlations]]", "[[Warnings]]"):
        assert section in text
    assert "degrees of freedom = 398" in text and "# data points      = 400" in text
    assert "C(R, Lq)" in text  # |r| > 0.1 shown
    assert "Ld is not identifiable" in text and "lambda_m is not identifiable" in text
    assert "<table" in poor_fit._repr_html_()


def test_to_pandas_has_one_row_per_parameter(default_fit, poor_fit):
    df = default_fit.to_pandas()
    assert list(df.index) == list(dc.ESTIMATED)
    np.testing.assert_allclose(df["rel_ci95_percent"], 100 * default_fit.t_factor * default_fit.se
                               / default_fit.estimate)
    assert list(poor_fit.to_pandas()["identifiable"]) == [True, False, True, False]


def test_verdicts_of_the_two_demo_designs(default_fit, default_bench, poor_fit, poor_bench):
    good = build_result(default_fit, default_bench, noise_sigma=NOISE)
    assert good["verdict"]["headline"] == "calibrated"
    assert good["residuals"]["white"] and good["residuals"]["noise_consistent"]
    poor = build_result(poor_fit, poor_bench, noise_sigma=NOISE)
    assert poor["verdict"]["headline"] == "partially calibrated: Ld, lambda_m not identifiable by this plan"
    # the new sections carry what the figures need
    seg = good["segments"][2]
    assert seg["name"] == "free spin-up" and len(seg["i_q_pred"]) == len(seg["i_q"]) == len(seg["t"])
    assert len(good["input"]["sha256"]) == 64 and set(good["versions"]) >= {
        "drivecal", "jax", "jaxonomy", "jaxterity", "optimistix", "numpy", "python"}


def test_understated_noise_and_unmodelled_effects_are_flagged(default_fit, default_bench, guess):
    # sigma_hat 20 mA against a stated 5 mA sensor: the model does not explain the data to the noise level
    doc = build_result(default_fit, default_bench, noise_sigma=0.005)
    assert doc["verdict"]["status"] == "mismatch" and doc["verdict"]["headline"] == "model mismatch suspected"
    # an unmodelled effect (a slow 0.1 A ripple on i_q, e.g. an uncompensated sensor offset drift) leaves
    # autocorrelated residuals: the fit absorbs what it can, the Ljung-Box test sees the rest
    t = np.arange(default_bench.num_samples) / default_bench.sample_rate
    bent = default_bench.with_currents(default_bench.currents + np.stack([0 * t, 0.1 * np.sin(2 * np.pi * 300 * t)], 1))
    cal = dc.fit(bent, guess)
    doc = build_result(cal, bent, noise_sigma=NOISE)
    assert not doc["residuals"]["white"] and doc["verdict"]["status"] == "mismatch"
    # pure white noise passes the whiteness test
    rng = np.random.default_rng(0)
    ok = residual_checks([("a", rng.normal(0, NOISE, (1000, 2)))], NOISE, NOISE)
    assert ok["white"] and ok["noise_consistent"]


def test_poor_design_sensitivity_figure_marks_the_dead_parameters(poor_fit):
    from drivecal.report import plots

    fig = plots.identifiability_figure({"locked q-step only": poor_fit.identifiability})
    ax = fig.axes[1]
    dead_x = sorted(round(t.get_position()[0]) for t in ax.texts if t.get_text() == "dead")
    assert [poor_fit.names[i] for i in dead_x] == ["Ld", "lambda_m"]


def test_demo_html_leads_with_verdicts_and_is_self_contained(demo_run):
    proc, out = demo_run
    assert proc.returncode == 0, proc.stderr
    page = (out / "report.html").read_text()
    assert not re.search(r'(src|href)="(https?:)?//', page)  # nothing fetched from the network
    assert "<script" not in page
    poor = page[page.index('id="fit-locked_q_step"'):]
    after_heading = poor[poor.index("</h2>") + 5:]
    assert after_heading.startswith('<div class="verdict partial"')
    assert "partially calibrated: Ld, lambda_m not identifiable by this plan" in after_heading[:400]
    assert page.count("data:image/png;base64,") == page.count("<figure>") == 12
    doc = json.loads((out / "report.json").read_text())
    assert doc["designs"]["default"]["input"]["sha256"] in page


def test_report_of_saved_json_reproduces_the_html(demo_run, tmp_path, capsys):
    _, out = demo_run
    again = tmp_path / "again.html"
    assert main(["report", str(out / "report.json"), "--html", str(again)]) == 0
    text = capsys.readouterr().out
    assert ("== locked_q_step\n[[Verdict]] partially calibrated: Ld, lambda_m not identifiable by this plan "
            "(status: partial)\n") in text
    assert "[[Fit Statistics]]" in text
    first = TIME_STAMP.sub("", (out / "report.html").read_text())
    second = TIME_STAMP.sub("", again.read_text())
    assert first == second


@pytest.mark.parametrize("content, fragment", [(None, "no such file"), ("{not json", "not valid JSON"),
                                               ('{"hello": 1}', "not a drivecal result")])
def test_report_refuses_bad_input_in_one_line(content, fragment, tmp_path, capsys):
    path = tmp_path / "result.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(SystemExit) as exc:
        main(["report", str(path), "--html", str(tmp_path / "r.html")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("drivecal: error:") and str(path) in err
    assert fragment in err and not (tmp_path / "r.html").exists()


def test_fresh_result_and_its_saved_json_render_the_same_page(poor_fit, poor_bench):
    """What the `fit` command will do: build_result -> write_json and write_html_report."""
    from drivecal.report import render_html

    doc = build_result(poor_fit, poor_bench, noise_sigma=NOISE)
    page = render_html(doc, generated="T")
    assert page == render_html(_via_json(doc), generated="T")
    assert page.count("<figure>") == 6 and '<div class="verdict partial"' in page


def test_report_and_gains_have_help(capsys):
    for command in ("report", "gains"):
        assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert "--html" in out and "--bandwidth" in out and "[Hz]" in out


def test_the_sections_an_engineer_reads_from_a_result_with_a_plan(default_fit, default_bench):
    """The plan as recorded, a fitted delay, a flagged speed and a specification: each shown as the JSON says
    (the bench-file case, without a plan, is the browser test's)."""
    from drivecal.report._sections import checks_html, plan_html, setup_html

    doc = json.loads(json.dumps(build_result(default_fit, default_bench, plan=dc.default_plan(), noise_sigma=NOISE)))
    plan = plan_html(doc)
    assert plan.startswith("<p>The plan as recorded: sample rate 20 kHz, DC link 48 V, current limit")
    assert plan.count("<tr>") == 1 + len(dc.default_plan().segments)
    doc["parameters"]["delay"] = {"estimate": 1.002, "se": 0.021, "ci95": [0.961, 1.043], "unit": "samples",
                                  "identifiable": True, "prior": 1.0}
    doc["speed"] = {"mode": "output", "requested": None, "flagged": True, "input_error_ratio": 126.0,
                    "input_error_ratio_max": 0.1, "resolution": {"summary": "steps of 1.534 rad/s"}, "reason": "x"}
    doc["measured_speed"] = True
    doc["spec"] = {"status": "fail", "headline": "fail: Lq outside its tolerance", "parameters": [], "advice": []}
    setup = setup_html(doc)
    assert "fitted: 1.002 ± 0.041 samples (95 %; started from 0)" in setup
    assert "a second measured output" in setup and "steps of 1.534 rad/s" in setup
    checks = re.findall(r'<tr class="(\w+)"><td class="l">([^<]*)</td>', checks_html(doc))
    states = {name: state for state, name in checks}
    assert states["resolution of the measured speed"] == "done"
    assert states["specification (the motor file&#x27;s tolerances)"] == "failed"
    assert states["noise level of the residuals"] == "done" and states["convergence of the fit"] == "done"
