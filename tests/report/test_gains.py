"""Controller hand-off: PI gains, their uncertainty, the achieved loop; the `gains` command."""

from __future__ import annotations

import json
import math

import pytest

from conftest import NOISE
from drivecal.cli import main
from drivecal.report import design_current_loop, loop_metrics, pi_gains
from drivecal.report import build_result


BW = 1000.0  # Hz


@pytest.fixture(scope="module")
def design(default_fit):
    return design_current_loop(default_fit, BW)


@pytest.fixture(scope="module")
def saved(default_fit, default_bench, tmp_path_factory):
    path = tmp_path_factory.mktemp("gains") / "result.json"
    path.write_text(json.dumps(build_result(default_fit, default_bench, noise_sigma=NOISE), indent=2))
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


def test_discrete_loop_with_delay_loses_margin(default_fit):
    disc = design_current_loop(default_fit, BW, sample_rate_hz=20e3, num_samples=500)
    for ax in disc.axes:
        assert ax.ki_ts == pytest.approx(ax.ki / 20e3)
        # 1.5 samples of delay (ZOH + computation) at the 1 kHz crossover cost ~27 deg
        assert 55.0 < ax.phase_margin.nominal < 70.0


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


@pytest.mark.parametrize("args, fragment", [
    (["--bandwidth", "0"], "--bandwidth"),
    (["--bandwidth", "5000", "--sample-rate", "20000"], "--bandwidth 5000 Hz is above"),
    (["--bandwidth", "1000", "--sample-rate", "-1"], "--sample-rate"),
])
def test_gains_refuses_bad_numbers(saved, args, fragment, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["gains", str(saved)] + args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and fragment in err and "Traceback" not in err


def test_gains_refuses_a_file_that_is_not_a_result(tmp_path, capsys):
    for path, fragment in ((tmp_path / "missing.json", "no such file"), (tmp_path / "x.json", "not a drivecal")):
        if fragment != "no such file":
            path.write_text(json.dumps({"rows": [1, 2]}))
        with pytest.raises(SystemExit) as exc:
            main(["gains", str(path), "--bandwidth", "1000"])
        assert exc.value.code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and fragment in err
