"""Gains at an operating point: the plant's inductances are the calibrated flux law's incremental L_dd, L_qq there.

The calibrations are built directly (no fit): a motor, its covariance, and ``Calibration.from_dict`` of their
``to_dict`` (what `drivecal gains` reads), so the saturating law's coefficients, exponents and ``i_ref`` must
round-trip through the result JSON.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivecal.cli import main
from drivecal.errors import DrivecalError
from drivecal.identify import Identifiability
from drivecal.physics import MAGNETIC, MotorParams, flux_of_currents, incremental_inductances
from drivecal.report import design_current_loop
from drivecal.results import Calibration

BW = 1000.0  # Hz
W_C = 2 * math.pi * BW
#: A saturating 48 V IPM: coefficients per unit at i_ref = 20 A (the "data's peak current").
SATURATING = MotorParams(sat_d=0.4, sat_q=0.9, sat_dq=0.3, exp_d=2.0, exp_q=1.0, exp_dq_d=1.0, exp_dq_q=1.0,
                         i_ref=20.0)
OP = (-10.0, 20.0)  # A, within the data (max |i| = i_ref)
#: Standard errors: 1 % on R, Ld, Lq, 0.5 % on lambda_m, absolute on the per-unit coefficients.
SE = {"R": 0.0045, "Ld": 3.2e-5, "Lq": 5.8e-5, "lambda_m": 2.7e-4, "sat_d": 0.03, "sat_q": 0.04, "sat_dq": 0.03}


def _calibration(motor: MotorParams, names: tuple[str, ...], fit_names: tuple[str, ...] | None = None) -> Calibration:
    """A converged calibration of ``motor`` estimating ``names`` (fitting ``fit_names``), correlated errors, via JSON."""
    fit_names = names if fit_names is None else fit_names
    n = len(fit_names)
    mix = np.random.default_rng(7).normal(size=(n, n)) + 2.0 * np.eye(n)
    cov_unit = mix @ mix.T
    corr = cov_unit / np.sqrt(np.outer(np.diag(cov_unit), np.diag(cov_unit)))
    sd = np.array([SE[p] for p in fit_names])
    cov = corr * np.outer(sd, sd)
    estimate = np.array([float(getattr(motor, p)) for p in names])
    se = np.array([SE[p] if p in fit_names else math.nan for p in names])
    ident = Identifiability(names=names, rank=n, condition_number=10.0, identifiable=True, weak_params=(),
                            dead_params=(), confounded_params=(),
                            reasons={p: "held at its prior" for p in names if p not in fit_names},
                            singular_values=(1.0,) * n, sensitivity=(1.0,) * len(names), fit_names=fit_names,
                            noise_sigma=0.02, num_residuals=4000, predicted_se=tuple(se),
                            predicted_ci95=tuple(1.96 * se))
    cal = Calibration(names=names, estimate=estimate, se=se, ci95=np.stack([estimate - 1.96 * se,
                                                                            estimate + 1.96 * se], axis=1),
                      identifiable=tuple(p in fit_names for p in names), fit_names=fit_names, covariance=cov,
                      sigma_hat=np.float64(0.02), rss=np.float64(1.6), iterations=np.int64(6),
                      converged=np.bool_(True), result_code=np.int64(0), initial=estimate, prior=motor,
                      identifiability=ident, num_residuals=4000, t_factor=1.96)
    return Calibration.from_dict(json.loads(json.dumps(cal.to_dict())), "test")


@pytest.fixture(scope="module")
def saturating():
    return _calibration(SATURATING, ("R", "Ld", "Lq", "lambda_m") + MAGNETIC)


@pytest.fixture(scope="module")
def linear():
    return _calibration(MotorParams(), ("R", "Ld", "Lq", "lambda_m"))


def _incremental(motor: MotorParams, op) -> tuple[float, float]:
    l_dd, _, l_qq = incremental_inductances(*flux_of_currents(op[0], op[1], motor), motor)
    return float(l_dd), float(l_qq)


def test_the_saturating_law_round_trips_through_the_result_json(saturating):
    for name in MAGNETIC + ("exp_d", "exp_q", "exp_dq_d", "exp_dq_q", "i_ref", "Ld", "Lq", "lambda_m"):
        assert float(getattr(saturating.motor, name)) == float(getattr(SATURATING, name)), name
    assert _incremental(saturating.motor, OP) == _incremental(SATURATING, OP)


@pytest.mark.parametrize("sample_rate", [None, 20e3])
def test_a_linear_calibration_gives_the_same_gains_at_any_operating_point(linear, sample_rate):
    plain = design_current_loop(linear, BW, sample_rate_hz=sample_rate)
    at = design_current_loop(linear, BW, sample_rate_hz=sample_rate, operating_point=(-40.0, 60.0))
    assert at.operating_point == (-40.0, 60.0) and not at.extrapolated and at.warnings == plain.warnings
    for a, b in zip(plain.axes, at.axes):
        assert b.inductance_name == {"Ld": "L_dd", "Lq": "L_qq"}[a.inductance_name]
        for field in ("inductance", "kp", "ki", "kp_se", "ki_se", "kp_sd_mc", "ki_sd_mc"):
            assert getattr(b, field) == pytest.approx(getattr(a, field), rel=1e-12, abs=0), field
        assert b.bandwidth.nominal == pytest.approx(a.bandwidth.nominal, rel=1e-9)
        assert b.phase_margin.mean == pytest.approx(a.phase_margin.mean, rel=1e-9)


@pytest.fixture(scope="module")
def at_op(saturating):
    return design_current_loop(saturating, BW, operating_point=OP)


def test_gains_use_the_incremental_inductances_at_the_operating_point(saturating, at_op):
    zero = design_current_loop(saturating, BW)
    l_op = _incremental(saturating.motor, OP)
    r = float(saturating.motor.R)
    for ax, ax0, ind in zip(at_op.axes, zero.axes, l_op):
        assert ax.inductance == pytest.approx(ind, rel=1e-10)
        assert ax.kp == pytest.approx(ind * W_C, rel=1e-10) and ax.ki == pytest.approx(r * W_C, rel=1e-12)
        assert ax.kp < 0.9 * ax0.kp  # saturated: the incremental inductance is well below its zero-current value
        assert ax.inductance_at_zero_current == ax0.inductance
        assert ax.calibrated
    assert at_op.warnings == ()


def test_first_order_propagates_through_every_parameter_of_the_law(saturating, at_op):
    """kp_se = w_c * sqrt(g Cov g^T), g = dL/dtheta over all fitted names (central differences here)."""
    names = saturating.fit_names
    theta = np.array([float(getattr(saturating.motor, p)) for p in names])
    grads = np.zeros((2, len(names)))
    for j, p in enumerate(names):
        h = 1e-6 * max(abs(theta[j]), 1e-3)
        hi, lo = (saturating.motor.replace(**{p: theta[j] + s}) for s in (h, -h))
        grads[:, j] = (np.array(_incremental(hi, OP)) - np.array(_incremental(lo, OP))) / (2 * h)
    assert np.all(np.abs(grads[:, [names.index(p) for p in ("sat_d", "sat_q", "sat_dq")]]) > 0)
    for a, ax in enumerate(at_op.axes):
        expected = W_C * math.sqrt(grads[a] @ saturating.covariance @ grads[a])
        assert ax.kp_se == pytest.approx(expected, rel=1e-5)
        # the saturation coefficients' uncertainty is most of it: more than Ld's or Lq's 1 % alone
        assert ax.kp_se > 1.5 * 0.01 * ax.kp


def test_first_order_and_monte_carlo_agree(at_op):
    """4000 draws: the Monte Carlo SD's own relative error is ~1/sqrt(2*4000) = 1.1 %; 5 % is ~4.5 of it."""
    for ax in at_op.axes:
        assert abs(ax.kp_sd_mc / ax.kp_se - 1) < 0.05
        assert abs(ax.ki_sd_mc / ax.ki_se - 1) < 0.05
        # the true motors' incremental inductances spread the achieved bandwidth about the specification
        assert ax.bandwidth.p025 < BW < ax.bandwidth.p975


def test_beyond_the_data_is_an_extrapolation(saturating):
    inside = design_current_loop(saturating, BW, operating_point=(0.0, 1.05 * 20.0), num_samples=4000)
    assert not inside.extrapolated and inside.warnings == ()
    beyond = design_current_loop(saturating, BW, operating_point=(-25.0, 0.0), num_samples=4000)
    assert beyond.extrapolated and beyond.data_peak_current == 20.0
    assert any("beyond the currents" in w and "extrapolate" in w for w in beyond.warnings)
    doc = beyond.to_dict()
    assert doc["operating_point"] == {"i_d": -25.0, "i_q": 0.0, "unit": "A", "extrapolated": True,
                                      "data_peak_current": 20.0}
    assert doc["axes"]["d"]["operating_point_a"] == {"i_d": -25.0, "i_q": 0.0}
    assert doc["axes"]["d"]["inductance_name"] == "L_dd"
    assert doc["axes"]["q"]["inductance_at_zero_current"] == float(SATURATING.Lq)
    assert design_current_loop(saturating, BW, num_samples=4000).to_dict()["operating_point"] is None


def test_a_law_parameter_held_at_its_prior_leaves_the_uncertainty_unknown():
    names = ("R", "Ld", "Lq", "lambda_m") + MAGNETIC
    cal = _calibration(SATURATING, names, fit_names=tuple(p for p in names if p != "sat_q"))
    design = design_current_loop(cal, BW, operating_point=OP)
    d, q = design.axes
    assert math.isnan(q.kp_se) and math.isnan(q.kp_sd_mc) and not q.calibrated
    assert any(w.startswith("q axis: sat_q not identified") for w in design.warnings)
    assert q.kp == pytest.approx(_incremental(cal.motor, OP)[1] * W_C, rel=1e-10)


@pytest.mark.parametrize("point", [(1.0,), (1.0, 2.0, 3.0), (math.nan, 1.0), ("a", "b")])
def test_an_operating_point_that_is_not_two_currents_is_refused(linear, point):
    with pytest.raises(DrivecalError, match="--operating-point .* two finite currents"):
        design_current_loop(linear, BW, operating_point=point)


@pytest.fixture(scope="module")
def saved(saturating, tmp_path_factory):
    path = tmp_path_factory.mktemp("gains_op") / "result.json"
    path.write_text(json.dumps(saturating.to_dict()))
    return path


def test_gains_command_at_an_operating_point(saved, saturating, capsys):
    assert main(["gains", str(saved), "--bandwidth", "1000", "--operating-point", "-10,20", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    l_dd, l_qq = _incremental(saturating.motor, OP)
    assert doc["operating_point"]["i_d"] == -10.0 and doc["operating_point"]["unit"] == "A"
    assert doc["axes"]["d"]["inductance"] == pytest.approx(l_dd, rel=1e-10)
    assert doc["axes"]["q"]["kp"] == pytest.approx(l_qq * W_C, rel=1e-10)
    assert main(["gains", str(saved), "--bandwidth", "1000", "--operating-point", "-10,20"]) == 0
    out = " ".join(capsys.readouterr().out.split())  # rich wraps the titles
    assert "L_qq (q) [H] at the operating point i_d = -10 A, i_q = 20 A" in out
    # in engineering units (mH), as every table a person reads
    assert f"L_dd = {l_dd * 1e3:.4g} mH" in out and f"(Lq = {float(SATURATING.Lq) * 1e3:.4g} mH at 0 A)" in out
    assert "…" not in out  # no column cut short


@pytest.mark.parametrize("value", ["abc", "1,2,3", "1;2", "nan,1", ""])
def test_gains_command_refuses_a_bad_operating_point(saved, value, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["gains", str(saved), "--bandwidth", "1000", "--operating-point", value, "--out",
              str(tmp_path / "g.json")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--operating-point" in err and "Traceback" not in err, err
    assert "two currents ID,IQ in A" in err
    assert list(tmp_path.iterdir()) == []
