"""The Python API without traps (issue 22, item 6): ``dc.fit`` returns a judged Calibration whose
``to_dict()`` is the result JSON (verdict and residual diagnostics included), ``from_dict`` reads it back,
``print(cal)`` leads with the verdict, and the reprs show values with units."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.errors import DataError
from drivecal.report import build_result
from drivecal.fitting import fit as fit_only
from drivecal.results import NOT_JUDGED, Status, Verdict


def _via_json(d):
    return json.loads(json.dumps(d, allow_nan=False))


@pytest.fixture(scope="module")
def unjudged(default_bench, guess):
    """The same fit as ``default_fit`` from ``drivecal.fitting.fit``: not judged (its kernels are compiled)."""
    return fit_only(default_bench, guess)


def test_fit_carries_the_verdict_and_diagnostics_of_the_result_json(default_fit, default_bench, unjudged):
    np.testing.assert_array_equal(default_fit.estimate, unjudged.estimate)  # the fit itself is unchanged
    np.testing.assert_array_equal(default_fit.covariance, unjudged.covariance)
    doc = _via_json(build_result(unjudged, default_bench))  # what `drivecal fit` builds for this fit
    d = default_fit.to_dict()
    assert d["verdict"] == doc["verdict"] and d["residuals"] == doc["residuals"]
    assert d["verdict"]["status"] == "calibrated" and default_fit.verdict.status is Status.CALIBRATED
    assert default_fit.diagnostics["white"] and default_fit.diagnostics["noise_consistent"]
    assert default_fit.verdict.ok and default_fit.verdict.exit_code == 0
    assert dc.judge_fit(unjudged, default_bench).verdict == default_fit.verdict


def test_print_leads_with_the_verdict(default_fit, poor_fit, unjudged):
    assert str(default_fit).splitlines()[0] == "[[Verdict]] calibrated (status: calibrated)"
    lines = str(poor_fit).splitlines()
    assert lines[0] == ("[[Verdict]] partially calibrated: Ld, lambda_m not identifiable by this plan "
                        "(status: partial)")
    assert "    Ld, lambda_m not identifiable by this plan: held at the prior, not calibrated" in lines
    assert lines.index("[[Fit Statistics]]") == len(poor_fit.verdict.details) + 1
    assert str(unjudged).splitlines()[0] == NOT_JUDGED and "drivecal.judge_fit(cal, bench)" in NOT_JUDGED
    assert unjudged.verdict is None and unjudged.to_dict()["verdict"] is None
    assert "; verdict calibrated; " in repr(default_fit) and "verdict" not in repr(unjudged)
    assert default_fit._repr_html_().startswith('<p class="verdict calibrated"><b>calibrated</b></p><table')


@pytest.mark.parametrize("which", ["default_fit", "poor_fit", "unjudged"])
def test_from_dict_round_trips_the_verdict_and_diagnostics(which, request):
    cal = request.getfixturevalue(which)
    back = dc.Calibration.from_dict(_via_json(cal.to_dict()))
    assert back.verdict == cal.verdict and back.diagnostics == cal.diagnostics
    assert back.to_dict() == cal.to_dict() and str(back) == str(cal) and repr(back) == repr(cal)
    np.testing.assert_array_equal(back.estimate, cal.estimate)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    d = cal.to_dict()  # a copy: changing it leaves the Calibration as it was
    if d["residuals"] is not None:
        d["residuals"]["white"] = "changed"
        d["verdict"]["details"].append("changed")
        assert cal.to_dict() == back.to_dict()


def test_a_saved_result_reads_back_with_its_verdict(default_fit, default_bench):
    """The result JSON of `drivecal fit` (its verdict computed afresh, the keys in their order) reads back
    into the same judged Calibration."""
    doc = _via_json(build_result(default_fit, default_bench))
    assert list(doc)[list(doc).index("delay_samples") + 1:][:3] == ["segments", "residuals", "verdict"]
    back = dc.Calibration.from_dict(doc)
    assert back.verdict == default_fit.verdict and back.diagnostics == default_fit.diagnostics


@pytest.mark.parametrize("edit, field", [
    (lambda v: v.update(status="great"), "verdict.status is great, not a drivecal status (calibrated, partial"),
    (lambda v: v.update(status=3), "verdict.status is a number, not a string"),
    (lambda v: v.pop("headline"), "verdict.headline is missing"),
    (lambda v: v.update(details="all good"), "verdict.details is a string, not a list"),
    (lambda v: v["details"].append(None), "verdict.details[1] is null, not a string"),
])
def test_a_malformed_verdict_is_refused_in_one_sentence(default_fit, edit, field):
    d = copy.deepcopy(default_fit.to_dict())
    edit(d["verdict"])
    with pytest.raises(DataError) as exc:
        dc.Calibration.from_dict(d, "cal.json")
    message = str(exc.value)
    assert message.startswith(f"cal.json: {field}") and "\n" not in message and message.endswith("wrote it.")
    with pytest.raises(DataError, match="cal.json: verdict is a string, not an object"):
        dc.Calibration.from_dict({**default_fit.to_dict(), "verdict": "calibrated"}, "cal.json")


def test_a_stated_noise_is_judged_against(default_fit, default_bench, guess):
    """sigma_hat 20 mA against a stated 5 mA sensor: model mismatch, as `drivecal fit --noise 0.005` says."""
    cal = dc.fit(default_bench, guess, noise=0.005)
    assert cal.verdict.status is Status.MISMATCH and cal.diagnostics["sigma_source"] == "the noise argument"
    assert dc.fit(default_bench, guess, noise=NOISE).verdict.status is Status.CALIBRATED
    with pytest.raises(dc.DrivecalError, match="noise is -1.0; give the current sensor's noise"):
        dc.fit(default_bench, guess, noise=-1.0)


def test_verdict_record():
    v = Verdict("partial", "partially calibrated: Ld not identifiable by this plan", ["Ld held at the prior"])
    assert v.status is Status.PARTIAL and v.details == ("Ld held at the prior",) and v.exit_code == 3
    assert Verdict.from_dict(v.to_dict()) == v
    assert repr(v) == "Verdict(partial: 'partially calibrated: Ld not identifiable by this plan'; 1 detail)"
    assert str(v) == ("[[Verdict]] partially calibrated: Ld not identifiable by this plan (status: partial)\n"
                      "    Ld held at the prior")


def test_the_jaxonomy_block_shows_its_parameters_with_units(default_fit):
    block = default_fit.to_jaxonomy(locked=True)
    text = repr(block)
    assert text.startswith("PMSM('pmsm': R = 450 mΩ, Ld = 3.2 mH, Lq = 5.801 mH, lambda_m = 53.3 mWb, pole_pairs = 4")
    assert text.endswith("; rotor locked)") and "system_id" not in text
    from jaxonomy.library.drives import PMSM

    assert isinstance(block, PMSM) and type(block).__name__ == "PMSM"
