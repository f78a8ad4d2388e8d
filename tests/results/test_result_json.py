"""The result JSON's one validation layer: every reader (report, gains, the Python API) refuses a bad result
in one sentence naming the file and the field, exit 2, nothing written; what drivecal writes is accepted."""

from __future__ import annotations

import copy
import json
import math
import warnings

import numpy as np
import pytest

from conftest import NOISE
from drivecal.cli import main
from helpers.cli import assert_one_sentence, run_cli_output
from drivecal.errors import DrivecalError
from drivecal.report import build_result, design_current_loop
from drivecal.results import Calibration, load_result


@pytest.fixture(scope="module")
def good(default_fit, default_bench):
    return json.loads(json.dumps(build_result(default_fit, default_bench, noise_sigma=NOISE)))


@pytest.fixture(scope="module")
def partial(poor_fit, poor_bench):
    """Ld and lambda_m not identifiable: their se and ci95 are null."""
    return json.loads(json.dumps(build_result(poor_fit, poor_bench, noise_sigma=NOISE)))


def _write(tmp_path, doc, name="result.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _edit(doc, fn):
    doc = copy.deepcopy(doc)
    fn(doc)
    return doc


def _set_corr(doc, i, j, r):
    cov = doc["covariance"]
    cov[i][j] = cov[j][i] = r * math.sqrt(cov[i][i] * cov[j][j])


def test_null_lq_estimate_is_refused_by_gains(good, tmp_path, capsys):
    """Before: exit 0, RuntimeWarnings, NaN loop figures and '4000 of 4000 Monte Carlo draws dropped'."""
    path = _write(tmp_path, _edit(good, lambda d: d["parameters"]["Lq"].update(estimate=None)))
    code, err, out = run_cli_output(["gains", path, "--bandwidth", "1000"], capsys)
    assert_one_sentence(code, err, str(path), "parameters.Lq.estimate is null", "refit")
    assert out == ""


def test_a_correlation_beyond_one_is_refused_by_every_reader(good, tmp_path, capsys):
    """Before: full gain tables and no warning for a covariance whose Ld-Lq correlation is 3."""
    path = _write(tmp_path, _edit(good, lambda d: _set_corr(d, 1, 2, 3.0)))
    html = tmp_path / "report.html"
    for args in (["gains", path, "--bandwidth", "1000"], ["report", path, "--html", html]):
        code, err, out = run_cli_output(args, capsys)
        assert_one_sentence(code, err, str(path), "covariance", "positive semi-definite", "smallest eigenvalue")
        assert out == ""
    assert not html.exists()
    with pytest.raises(DrivecalError, match="covariance is not positive semi-definite"):
        load_result(path)
    with pytest.raises(DrivecalError, match="covariance is not positive semi-definite"):
        Calibration.from_dict(json.loads(path.read_text()))


def test_an_asymmetric_covariance_is_refused(good, tmp_path):
    doc = _edit(good, lambda d: d["covariance"][0].__setitem__(1, -d["covariance"][1][0]))
    with pytest.raises(DrivecalError, match="covariance is not symmetric"):
        load_result(_write(tmp_path, doc))


@pytest.mark.parametrize("edit, field", [
    (lambda d: d.pop("iterations"), "no 'iterations' field"),
    (lambda d: d["parameters"]["R"].update(estimate="0.45"), "parameters.R.estimate is a string, not a number"),
    (lambda d: d["parameters"]["Ld"].update(ci95=[1.0]), "parameters.Ld.ci95 has 1 entries where 2 are needed"),
    (lambda d: d["parameters"]["Ld"].update(identifiable=None), "parameters.Ld.identifiable is null"),
    (lambda d: d["covariance"].pop(), "covariance has 3 entries where 4 are needed"),
    (lambda d: d["covariance"][2].append(0.0), "covariance[2] has 5 entries where 4 are needed"),
    (lambda d: d["covariance"][1].__setitem__(1, -1e-9), "covariance[1][1] (the variance of Ld) is negative"),
    (lambda d: d.update(names=["R", "Ld", "Lq", "bogus"]), "names[3] is bogus, which is not in parameters"),
    (lambda d: d.update(num_residuals=True), "num_residuals is a boolean"),
    (lambda d: d["identifiability"].update(rank="4"), "identifiability.rank is a string"),
    (lambda d: d["prior"].update(R=None), "prior.R is null"),
    (lambda d: d["history"]["values"][1].pop(), "history.values[1] has 3 entries"),
    (lambda d: d["segments"][0].update(i_q=[0.0]), "segments[0].i_q has 1 entries"),
    (lambda d: d.update(verdict=["calibrated"]), "verdict is a list, not an object"),
])
def test_a_bad_field_is_named_by_report_and_gains(good, tmp_path, capsys, edit, field):
    path = _write(tmp_path, _edit(good, edit))
    html = tmp_path / "out.html"
    for args in (["report", path, "--html", html], ["gains", path, "--bandwidth", "1000"]):
        code, err, out = run_cli_output(args, capsys)
        assert_one_sentence(code, err, str(path), field)
        assert out == ""
    assert not html.exists()


def test_a_demo_document_names_the_design(good, tmp_path, capsys):
    demo = {"noise_sigma": NOISE, "seed": 1, "designs": {"default": good,
                                                         "other": _edit(good, lambda d: d.update(sigma_hat="x"))}}
    path = _write(tmp_path, demo)
    code, err, _ = run_cli_output(["gains", path, "--bandwidth", "1000"], capsys)
    assert_one_sentence(code, err, str(path), "designs.other.sigma_hat is a string")


def test_legitimate_nulls_are_accepted_and_gains_use_the_prior(partial, tmp_path, capsys):
    """A parameter the data cannot identify has null se and ci95; the gains hold it at its prior (as before)."""
    assert partial["parameters"]["Ld"]["se"] is None and partial["parameters"]["Ld"]["ci95"] is None
    path = _write(tmp_path, partial)
    cal = Calibration.from_dict(load_result(path))
    assert not cal.identifiable[cal.names.index("Ld")]
    assert main(["gains", str(path), "--bandwidth", "1000", "--samples", "200", "--json"]) in (0, None)
    doc = json.loads(capsys.readouterr().out)
    d = doc["axes"]["d"]
    assert d["calibrated"] is False and d["inductance"] == partial["parameters"]["Ld"]["prior"]
    assert d["kp_se_first_order"] is None and doc["axes"]["q"]["calibrated"] is True
    assert any("Ld not identified" in w for w in doc["warnings"])
    # a null estimate of a parameter that was not fitted also falls back to its prior
    held = _edit(partial, lambda x: x["parameters"]["Ld"].update(estimate=None))
    design = design_current_loop(Calibration.from_dict(held), 1000.0, num_samples=200)
    assert design.axes[0].inductance == partial["parameters"]["Ld"]["prior"]


def test_a_very_wide_covariance_drops_draws_without_numpy_warnings(good, tmp_path, capsys):
    def widen(d):
        d["covariance"] = (np.array(d["covariance"]) * 1e12).tolist()

    path = _write(tmp_path, _edit(good, widen))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert main(["gains", str(path), "--bandwidth", "1000", "--samples", "200", "--json"]) in (0, None)
    doc = json.loads(capsys.readouterr().out)
    assert any("were dropped" in w for w in doc["warnings"])


def test_what_drivecal_writes_round_trips(good, partial, tmp_path):
    for doc in (good, partial):
        loaded = load_result(_write(tmp_path, doc))
        assert Calibration.from_dict(loaded).to_dict() == {k: doc[k] for k in Calibration.from_dict(doc).to_dict()}
