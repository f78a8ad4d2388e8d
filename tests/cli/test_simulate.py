"""`drivecal simulate --inverter switching`: the switching-level plant from the CLI, its settings from the
options or the plan's [inverter] table, and each refusal one sentence with exit status 2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivecal.cli import main
from drivecal.data import load_bench
from drivecal.physics import DEFAULT_MOTOR
from drivecal.plan import load_plan
from helpers.cli import assert_one_sentence, run_cli

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DEFAULT_PLAN = EXAMPLES / "default_plan.toml"
SHORT_PLAN = """sample_rate = "10 kHz"
{table}
[[segment]]
name = "locked d-step"
duration = "4 ms"
locked = true
v_d = "8 V"

[[segment]]
name = "free spin-up"
duration = "6 ms"
locked = false
v_q = "12 V"
"""


def _plan(tmp_path, table: str = "") -> Path:
    path = tmp_path / "plan.toml"
    path.write_text(SHORT_PLAN.format(table=table))
    return path


def _motor(tmp_path, text: str) -> Path:
    path = tmp_path / "motor.toml"
    path.write_text('R = 0.45\nLd = 3.2e-3\nLq = 5.8e-3\nlambda_m = 0.0533\npole_pairs = 4\nJ = 1.2e-3\nB = 8e-5\n'
                    + text)
    return path


def test_switching_round_trip_writes_a_bench_file_drivecal_reads(tmp_path, capsys):
    out = tmp_path / "x.csv"
    assert main(["simulate", str(DEFAULT_PLAN), "--inverter", "switching", "--dead-time", "1e-6",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "wrote" in printed and "1400 samples in 3 segment(s)" in printed
    assert "switching SVPWM inverter, 1 µs dead time, no device drop, delay 0 samples" in printed
    bench = load_bench(out)
    plan = load_plan(DEFAULT_PLAN)
    assert bench.num_samples == 1400 and bench.sample_rate == pytest.approx(20_000.0)
    assert [s.name for s in bench.segments] == [s.name for s in plan.segments]
    header = out.read_text().splitlines()[0].split(",")
    assert header[:8] == ["segment", "locked", "t", "v_d", "v_q", "i_d", "i_q", "w_m"]
    for recorded, seg in zip(bench.segments, plan.segments):
        np.testing.assert_array_equal(recorded.voltages, seg.voltages(plan.sample_rate))  # the commands
    # The dead time shows: the locked d-step loses 4/3 * V_dc * t_dead * f_pwm = 1.28 V of its 8 V (a first-order
    # response to 6.72 V instead of 8 V; the ideal inverter would reach 13.4 A), to the noise and the ripple.
    motor = DEFAULT_MOTOR
    t_end = bench.segments[0].t[-1]
    rise = 1.0 - np.exp(-t_end * float(motor.R) / float(motor.Ld))
    expected = (8.0 - 4.0 / 3.0 * 48.0 * 1e-6 * 20_000.0) / float(motor.R) * rise
    assert abs(bench.segments[0].currents[-1, 0] - expected) < 0.1, (bench.segments[0].currents[-1, 0], expected)


def test_the_plans_table_is_the_default_and_the_options_override_it(tmp_path, capsys):
    table = '[inverter]\nmodel = "switching"\nmodulation = "sine"\ndead_time = "2 us"\ndevice_drop = "0.5 V"\n'
    plan = _plan(tmp_path, table)
    assert main(["simulate", str(plan), "--noise", "1e-9", "--out", str(tmp_path / "a.csv")]) == 0
    assert "switching sine inverter, 2 µs dead time, 0.5 V device drop" in capsys.readouterr().out
    assert main(["simulate", str(plan), "--noise", "1e-9", "--modulation", "svpwm", "--dead-time", "1 us",
                 "--device-drop", "0", "--out", str(tmp_path / "b.csv")]) == 0
    assert "switching SVPWM inverter, 1 µs dead time, no device drop" in capsys.readouterr().out
    a, b = load_bench(tmp_path / "a.csv"), load_bench(tmp_path / "b.csv")
    # More dead time and a drop: a smaller locked d current.
    assert a.segments[0].currents[-1, 0] < b.segments[0].currents[-1, 0] - 0.3
    # --inverter averaged with the table's dead time is refused (the next test); with a clean table it runs.
    clean = _plan(tmp_path, '[inverter]\nmodel = "switching"\n')
    assert main(["simulate", str(clean), "--inverter", "averaged", "--out", str(tmp_path / "c.csv")]) == 0
    assert "switching" not in capsys.readouterr().out


@pytest.mark.parametrize("args, motor, needles", [
    (["--dead-time", "1e-6"], None, ["--dead-time: the averaged inverter has no", "--inverter switching",
                                     "v_dead"]),
    (["--modulation", "sine"], None, ["--modulation: the averaged inverter"]),
    (["--inverter", "switching", "--dead-time", "60 us"], None,
     ["--inverter switching: dead_time = 6e-05 s", "half the carrier period (5e-05 s at 10000 Hz)"]),
    (["--inverter", "switching", "--dead-time", "1 V"], None, ["--dead-time", "has unit 'V' but a time in s"]),
    (["--inverter", "switching", "--device-drop", "-1"], None, ["--device-drop", "must be >= 0 V"]),
    (["--inverter", "switching"], "v_dead = 0.48\n", ["motor.toml: v_dead = 0.48", "set it to 0 in the motor file",
                                                      "--dead-time"]),
    (["--inverter", "switching"], "offset_d = 0.05\n", ["motor.toml: offset_d = 0.05", "sensors ideal"]),
    (["--inverter", "switching"], "delay_samples = 0.3\n",
     ["delay_samples = 0.3", "multiple of 0.5", "set delay_samples in the motor file"]),
])
def test_refusals_are_one_sentence_exit_2(tmp_path, capsys, args, motor, needles):
    argv = ["simulate", str(_plan(tmp_path)), *args, "--out", str(tmp_path / "x.csv")]
    if motor is not None:
        argv += ["--motor", str(_motor(tmp_path, motor))]
    code, err = run_cli(argv, capsys)
    assert_one_sentence(code, err, *needles)
    assert not (tmp_path / "x.csv").exists()


def test_a_bad_inverter_table_names_the_plan_file(tmp_path, capsys):
    plan = _plan(tmp_path, '[inverter]\nmodel = "switching"\ndead_time = -1e-6\n')
    code, err = run_cli(["simulate", str(plan), "--out", str(tmp_path / "x.csv")], capsys)
    assert_one_sentence(code, err, f"{plan}: 'inverter.dead_time' must be >= 0")
    plan = _plan(tmp_path, '[inverter]\nmodel = "switching"\ndeadtime = "1 us"\n')
    code, err = run_cli(["simulate", str(plan), "--out", str(tmp_path / "x.csv")], capsys)
    assert_one_sentence(code, err, f"{plan}: unknown key 'inverter.deadtime'")
    # The table's dead time with --inverter averaged: refused, naming the table.
    plan = _plan(tmp_path, '[inverter]\nmodel = "switching"\ndead_time = "1 us"\n')
    code, err = run_cli(["simulate", str(plan), "--inverter", "averaged", "--out", str(tmp_path / "x.csv")], capsys)
    assert_one_sentence(code, err, "[inverter] table: the averaged inverter has no")
