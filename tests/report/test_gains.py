"""Controller hand-off: PI gains, their uncertainty, the achieved loop; the `gains` command."""

from __future__ import annotations

import json
import math

import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.cli import main
from drivecal.errors import DrivecalError
from drivecal.report import design_current_loop, loop_metrics, pi_gains
from drivecal.report import build_result


BW = 1000.0  # Hz


@pytest.fixture(scope="module")
def design(default_fit):
    return design_current_loop(default_fit, BW)


@pytest.fixture(scope="module")
def saved(default_fit, default_bench, tmp_path_factory):
    path = tmp_path_factory.mktemp("gains") / "result.json"
    doc = build_result(default_fit, default_bench, plan=dc.default_plan(), noise_sigma=NOISE)
    path.write_text(json.dumps(doc, indent=2))
    return path


def test_gains_equal_the_formula(design, default_fit):
    est = dict(zip(default_fit.names, default_fit.estimate))
    w_c = 2 * math.pi * BW
    d, q = design.axes
    assert d.kp == pytest.approx(est["Ld"] * w_c, rel=1e-12) and q.kp == pytest.approx(est["Lq"] * w_c, rel=1e-12)
    assert d.ki == pytest.approx(est["R"] * w_c, rel=1e-12) and q.ki == pytest.approx(est["R"] * w_c, rel=1e-12)
    # on the calibrated motor the zero cancels the pole: closed loop w_c/(s + w_c), 90 deg margin
    assert d.bandwidth.nominal == pytest.approx(BW, rel=1e-6)
    assert d.phase_margin.nominal == pytest.approx(90.0, abs=1e-6)


def test_first_order_and_monte_carlo_agree(design):
    for ax in design.axes:
        assert abs(ax.kp_sd_mc / ax.kp_se - 1) < 0.10
        assert abs(ax.ki_sd_mc / ax.ki_se - 1) < 0.10


def test_true_motor_reaches_the_bandwidth_within_the_reported_spread(design, truth):
    for ax in design.axes:
        true_l = getattr(truth, ax.inductance_name)
        bw, pm = loop_metrics(ax.kp, ax.ki, truth.R, true_l, BW)
        assert ax.bandwidth.p025 <= bw[0] <= ax.bandwidth.p975
        assert ax.bandwidth.p025 <= BW <= ax.bandwidth.p975
        assert ax.phase_margin.p025 - 1e-9 <= pm[0] <= ax.phase_margin.p975 + 1e-9


def test_discrete_bandwidth_is_the_closed_loop_one(default_fit):
    """--bandwidth with a sample rate: the sampled loop with its one-sample delay has that -3 dB bandwidth."""
    disc = design_current_loop(default_fit, BW, sample_rate_hz=20e3, num_samples=500)
    assert disc.delay_samples == 1.0 and "no fitted delay" in disc.delay_source
    for ax in disc.axes:
        assert ax.ki_ts == pytest.approx(ax.ki / 20e3)
        assert ax.bandwidth.nominal == pytest.approx(BW, rel=1e-6)
        # the PI zero sits on the plant pole: Ki*Ts = Kp*(1 - exp(-R*Ts/L))
        assert ax.ki_ts == pytest.approx(ax.kp * -math.expm1(-ax.resistance / 20e3 / ax.inductance), rel=1e-12)
        # cancelled loop g/((z - 1) z): margin 90 deg - 1.5 samples of phase at the crossover
        assert ax.phase_margin.nominal == pytest.approx(90 - 1.5 * 360 * ax.crossover.nominal / 20e3, abs=1e-6)
        assert 0.5 * BW < ax.crossover.nominal < BW


def test_the_issue_case_a_1khz_crossover_is_a_2_2khz_bandwidth(default_fit):
    """The ambiguity reported: a 1 kHz crossover at 20 kHz gives 63 deg and a -3 dB bandwidth of ~2.2 kHz."""
    disc = design_current_loop(default_fit, crossover_hz=BW, sample_rate_hz=20e3, num_samples=500)
    for ax in disc.axes:
        assert ax.crossover.nominal == pytest.approx(BW, rel=1e-9)
        assert ax.phase_margin.nominal == pytest.approx(63.0, abs=1e-6)
        assert 2200 < ax.bandwidth.nominal < 2250


def test_phase_margin_spec_and_what_is_reachable(default_fit):
    disc = design_current_loop(default_fit, phase_margin_deg=45.0, sample_rate_hz=20e3, num_samples=500)
    lim = disc.limits
    # one sample of delay: margin = 90 - 1.5 * 360 * f/fs, so 30 deg at fs/9
    assert lim["max_crossover_hz"] == pytest.approx(20e3 / 9, rel=1e-9)
    assert lim["max_crossover_hz"] < lim["max_bandwidth_hz"] < 0.5 * 20e3
    for ax in disc.axes:
        assert ax.phase_margin.nominal == pytest.approx(45.0, abs=1e-6)
        assert ax.crossover.nominal == pytest.approx(20e3 * 45 / 540, rel=1e-9)
    at_limit = design_current_loop(default_fit, lim["max_bandwidth_hz"] * 0.999, sample_rate_hz=20e3, num_samples=200)
    assert at_limit.axes[0].phase_margin.nominal > 30.0
    with pytest.raises(DrivecalError, match="not reachable"):
        design_current_loop(default_fit, lim["max_bandwidth_hz"] * 1.01, sample_rate_hz=20e3, num_samples=200)


def test_discrete_first_order_and_monte_carlo_agree(default_fit):
    disc = design_current_loop(default_fit, BW, sample_rate_hz=1e3 * 20, num_samples=4000)
    for ax in disc.axes:
        assert abs(ax.kp_sd_mc / ax.kp_se - 1) < 0.10
        assert abs(ax.ki_sd_mc / ax.ki_se - 1) < 0.10
        # the true motors' spread of the achieved bandwidth holds the specification
        assert ax.bandwidth.p025 <= BW <= ax.bandwidth.p975


def test_continuous_bandwidth_matches_the_closed_form():
    # closed loop (Kp s + Ki)/(L s^2 + (R + Kp) s + Ki): |T|^2 = 1/2 solves a quadratic in w^2
    kp, ki = pi_gains(0.45, 3.2e-3, BW)
    r, ind = 0.5, 3.0e-3
    b = (r + kp) ** 2 - 2 * ki * ind - 2 * kp**2
    w2 = (-b + math.sqrt(b**2 + 4 * ind**2 * ki**2)) / (2 * ind**2)
    bw, _ = loop_metrics(kp, ki, r, ind, BW)
    assert bw[0] == pytest.approx(math.sqrt(w2) / (2 * math.pi), rel=1e-9)


def test_gains_command_json(saved, capsys):
    assert main(["gains", str(saved), "--bandwidth", "1000", "--sample-rate", "20000", "--samples", "500",
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["axes"]["d"]["kp"] > 0 and doc["sample_rate_hz"] == 20000
    assert set(doc["axes"]["q"]["bandwidth_hz"]) == {"nominal", "mean", "p025", "p975"}
    assert doc["specification"] == {"kind": "bandwidth", "value": 1000.0, "unit": "Hz"}
    assert doc["axes"]["q"]["bandwidth_hz"]["nominal"] == pytest.approx(1000.0, rel=1e-6)
    assert doc["reachable"]["max_crossover_hz"] == pytest.approx(20000 / 9)
    assert doc["firmware"]["voltage_limit"]["v_dc"] == 48.0  # the result's plan


@pytest.mark.parametrize("args, fragment", [
    (["--bandwidth", "0"], "--bandwidth"),
    (["--bandwidth", "5000", "--sample-rate", "20000"], "--bandwidth 5000 Hz is not reachable at --sample-rate 20000"),
    (["--crossover", "150", "--sample-rate", "1000"], "--crossover 150 Hz is not reachable"),
    (["--bandwidth", "1000", "--sample-rate", "-1"], "--sample-rate"),
    (["--bandwidth", "1000", "--crossover", "500"], "exactly one of --bandwidth, --crossover or --phase-margin"),
    (["--sample-rate", "20000"], "exactly one of"),
    (["--phase-margin", "20", "--sample-rate", "20000"], "--phase-margin 20 deg is not reachable"),
    (["--phase-margin", "60"], "--phase-margin needs --sample-rate"),
    (["--bandwidth", "1000", "--header", "HEADER"], "--header needs --sample-rate"),
    (["--bandwidth", "1000", "--sample-rate", "20000", "--base-current", "30"], "both --base-current and"),
    (["--bandwidth", "1000", "--sample-rate", "20000", "--q-format", "Q15"], "--q-format needs the per-unit base"),
    (["--bandwidth", "1000", "--sample-rate", "20000", "--base-current", "30", "--base-voltage", "28",
      "--q-format", "Q40"], "choose Q7 to Q31"),
    (["--bandwidth", "1000", "--sample-rate", "20000", "--q-format", "X"], "is not a Q format"),
])
def test_gains_refuses_bad_input_and_writes_nothing(saved, args, fragment, capsys, tmp_path):
    header, out = tmp_path / "gains.h", tmp_path / "gains.json"
    args = [str(header) if a == "HEADER" else a for a in args]
    extra = [] if "--header" in args else ["--out", str(out)]
    with pytest.raises(SystemExit) as exc:
        main(["gains", str(saved)] + args + extra)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []  # not even a temporary file


def test_gains_refuses_an_unwritable_output_before_any_work(saved, capsys, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main(["gains", str(saved), "--bandwidth", "1000", "--sample-rate", "20000", "--header",
              str(tmp_path / "missing" / "gains.h")])
    assert exc.value.code == 2
    assert "does not exist" in capsys.readouterr().err


def test_gains_refuses_a_file_that_is_not_a_result(tmp_path, capsys):
    for path, fragment in ((tmp_path / "missing.json", "no such file"), (tmp_path / "x.json", "not a drivecal")):
        if fragment != "no such file":
            path.write_text(json.dumps({"rows": [1, 2]}))
        with pytest.raises(SystemExit) as exc:
            main(["gains", str(path), "--bandwidth", "1000"])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and fragment in err
