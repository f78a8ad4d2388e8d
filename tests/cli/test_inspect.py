"""Issue 19: `drivecal inspect LOG` lists a log's channels and proposes the format file that reads it."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

import drivecal as dc
from drivecal.cli import main
from drivecal.data import load_format

from helpers.bench_logs import (assert_same_bench, continuous_recording, format_toml, speed_bench, write_mdf4,
                                write_tdms)
from helpers.cli import assert_one_sentence, run_cli


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """The default plan recorded continuously with short rests (MDF4 and TDMS), its true windows, the CSV's bench."""
    bench = speed_bench()
    root = tmp_path_factory.mktemp("inspect")
    logged, windows = continuous_recording(bench, rest=60)
    return {"mf4": write_mdf4(root / "run.mf4", logged), "tdms": write_tdms(root / "run.tdms", logged)}, windows, \
        dc.load_bench(bench.save(root / "bench.csv"))


def _seconds(text: str) -> float:
    number, unit = text.split()
    return float(number) * {"ms": 1e-3, "s": 1.0}[unit]


@pytest.mark.parametrize("kind", ["mf4", "tdms"])
def test_inspect_proposes_the_windows_of_the_default_plan(kind, logs, tmp_path, capsys):
    paths, windows, csv_bench = logs
    out = tmp_path / "format.toml"
    assert main(["inspect", str(paths[kind]), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    for channel, unit in (("Id", "mA"), ("n_mech", "rpm"), ("Ud_ref", "V")):
        line = next(x for x in printed.splitlines() if f" {channel} " in x or f"/{channel} " in x)
        assert unit in line and "20000" in line and "1640" in line
    assert "proposed 3 segment windows" in printed and f"wrote {out}" in printed
    assert not list(tmp_path.glob(".*part"))  # written under a temporary name, then renamed
    proposal = tomllib.loads(out.read_text())
    assert proposal["units"] == {**({"t": "s"} if kind == "mf4" else {}), "v_d": "V", "v_q": "V", "i_d": "mA",
                                 "i_q": "mA", "w_m": "rpm", "theta_e": "deg"}
    assert proposal["columns"]["i_d"].endswith("Id") and proposal["columns"]["w_m"].endswith("n_mech")
    got = proposal["segment"]
    assert [w["locked"] for w in got] == [True, True, False]
    step = 1.0 / csv_bench.sample_rate
    for mine, truth in zip(got, windows):
        assert _seconds(mine["start"]) == pytest.approx(_seconds(truth["start"]), abs=1e-3 * step)
        assert _seconds(mine["stop"]) == pytest.approx(_seconds(truth["stop"]), abs=1e-3 * step)
    # The proposal reads the log as the drivecal CSV of the same run.
    assert_same_bench(dc.load_bench(paths[kind], format=out), csv_bench)


def test_inspect_prints_the_format_file_on_stdout_and_the_table_on_stderr(logs, capsys):
    paths, _, _ = logs
    assert main(["inspect", str(paths["mf4"])]) == 0
    captured = capsys.readouterr()
    fmt = tomllib.loads(captured.out)  # stdout is the format file alone: `drivecal inspect LOG > FORMAT.toml`
    assert len(fmt["segment"]) == 3 and "n_mech" in captured.err


def test_inspect_with_a_format_file_uses_its_mapping(logs, tmp_path, capsys):
    paths, windows, _ = logs
    fmt = tmp_path / "given.toml"
    fmt.write_text(format_toml(windows, names={"t": "time", "v_d": "Ud_ref", "v_q": "Uq_ref", "i_d": "Iq",
                                               "i_q": "Id", "w_m": "n_mech", "theta_e": "phi_el"}))
    assert main(["inspect", str(paths["mf4"]), "--format", str(fmt)]) == 0
    proposal = tomllib.loads(capsys.readouterr().out)
    assert proposal["columns"]["i_d"] == "Iq"  # as the format file says, not as guessed
    assert [w["name"] for w in proposal["segment"]] == [w["name"] for w in windows]
    assert load_format(fmt).columns["i_q"] == "Id"


def test_inspect_refuses_a_missing_file_and_a_bad_format_in_one_sentence(logs, tmp_path, capsys):
    paths, windows, _ = logs
    out = tmp_path / "format.toml"
    code, err = run_cli(["inspect", tmp_path / "nope.mf4", "--out", out], capsys)
    assert_one_sentence(code, err, "nope.mf4", "no such file")
    fmt = tmp_path / "bad.toml"
    fmt.write_text(format_toml(windows).replace('i_d = "Id"', 'i_d = "Idd"'))
    code, err = run_cli(["inspect", paths["mf4"], "--format", fmt, "--out", out], capsys)
    assert_one_sentence(code, err, "channel 'Idd'", "close matches: 'Id'")
    assert not out.exists() and not list(tmp_path.glob(".*part"))


def test_a_zero_crossing_inside_a_segment_is_no_rest():
    from drivecal.data import propose_windows

    fs = 20_000.0  # a rest is 0.5 ms: 10 samples
    t = np.arange(400) / fs
    v = np.zeros(400)
    v[50:150] = np.sign(np.sin(np.arange(100) / 3.0 + 0.5))  # a square wave...
    v[[80, 81, 120]] = 0.0  # ...passing through zero for a sample or two (shorter than a rest)
    v[250:350] = 5.0
    proposals = propose_windows(t, v, None, None)
    assert [(p.first, p.last) for p in proposals] == [(50, 149), (250, 349)]
    assert all(p.window.locked is None for p in proposals)  # no speed channel to tell


# `drivecal inspect` as a fresh process runs it, then what the process had loaded.
_INSPECT_PROGRAM = """
import sys
from drivecal.cli import main

assert main(["inspect", sys.argv[1], "--out", sys.argv[2]]) == 0
print(sorted(m for m in ("jax", "jaxlib", "equinox", "drivecal.physics", "drivecal.model") if m in sys.modules))
"""


@pytest.mark.parametrize("kind", ["mf4", "tdms"])
def test_inspect_loads_nothing_of_jax(kind, logs, tmp_path):
    """Listing a log's channels and proposing its format file needs no motor model: JAX (~0.6 s of imports) and
    drivecal's model are not loaded for it."""
    import subprocess
    import sys

    paths, _, _ = logs
    out = tmp_path / "format.toml"
    proc = subprocess.run([sys.executable, "-c", _INSPECT_PROGRAM, str(paths[kind]), str(out)], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "[]"
    assert load_format(out).columns  # the proposal was written, and reads
