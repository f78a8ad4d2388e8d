"""The drivecal command: demo output, JSON, and one-line errors with exit status 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drivecal.cli import main
from helpers.cli import assert_page_embeds_files


def test_demo_json_parses_and_carries_the_numbers(demo_run):
    proc, _ = demo_run
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # stdout is JSON only
    assert doc["noise_sigma"] == 0.02 and doc["seed"] == 1
    good = doc["designs"]["default"]
    assert good["converged"] is True
    assert good["identifiability"]["rank"] == 4 and good["identifiability"]["dead_params"] == []
    for name, p in good["parameters"].items():
        true = doc["truth"][name]
        assert p["identifiable"] is True
        assert abs(p["estimate"] - true) < 3 * p["se"]
        assert abs(p["estimate"] - true) / true < 5e-4
        assert p["ci95"][0] < true < p["ci95"][1] or abs(p["estimate"] - true) > 1.9 * p["se"]
    poor = doc["designs"]["locked_q_step"]
    assert poor["identifiability"]["rank"] == 2
    assert sorted(poor["identifiability"]["dead_params"]) == ["Ld", "lambda_m"]
    assert poor["parameters"]["Ld"]["identifiable"] is False
    assert poor["parameters"]["lambda_m"]["identifiable"] is False
    assert poor["parameters"]["lambda_m"]["se"] is None


def test_demo_writes_report_and_figures(demo_run):
    proc, out = demo_run
    assert proc.returncode == 0
    names = sorted(p.name for p in out.iterdir())
    assert "report.json" in names
    for fig in ("excitation_default.png", "convergence_default.png", "estimates_default.png",
                "identifiability.png", "excitation_locked_q_step.png", "estimates_locked_q_step.png"):
        assert fig in names
        assert (out / fig).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not any(n.endswith(".part") for n in names)  # nothing half-written
    report = json.loads((out / "report.json").read_text())
    assert report == json.loads(proc.stdout)
    cov = np.asarray(report["designs"]["default"]["covariance"])
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_the_demo_page_embeds_the_drawings_of_its_files(demo_run):
    """Each design's estimates and convergence figures are both a PNG file and a figure of the page: drawn once
    (the renderer draws a job asked for twice once), the page embeds the file's very bytes."""
    proc, out = demo_run
    assert proc.returncode == 0
    assert_page_embeds_files(out, [f"{kind}_{design}.png" for kind in ("estimates", "convergence")
                                   for design in ("default", "locked_q_step")])


@pytest.mark.parametrize(
    "args, fragment",
    [
        (["demo", "--noise", "-1"], "--noise"),
        (["demo", "--noise", "abc"], "--noise"),
        (["demo", "--noise", "nan"], "--noise"),
        (["demo", "--seed", "-3"], "--seed"),
        (["demo", "--bogus"], "--bogus"),
        (["nonsense"], "nonsense"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(args, fragment, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("drivecal: error:") and fragment in err
    assert "Traceback" not in err


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    target = tmp_path / "report.txt"
    target.write_text("keep me")
    with pytest.raises(SystemExit) as exc:
        main(["demo", "--out", str(target)])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(target) in err
    assert target.read_text() == "keep me"


def test_help_is_there_for_every_command(capsys):
    for args in (["--help"], ["demo", "--help"]):
        assert main(args) == 0
    out = capsys.readouterr().out
    assert "--noise" in out and "[A]" in out


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_design_of_the_seed_poor_plan_names_the_dead_parameters(capsys):
    with pytest.raises(SystemExit) as info:
        main(["design", str(EXAMPLES / "seed_poor_plan.toml")])
    captured = capsys.readouterr()
    assert info.value.code == 2
    assert "rank 2/4" in captured.out
    assert "Ld: no d-axis excitation (i_d never changes)" in captured.out
    assert "lambda_m: no free-rotor segment (back-EMF needs the rotor to turn)" in captured.out
    assert captured.err.strip().endswith("cannot identify Ld, lambda_m; see the assessment above.")


def test_design_json_of_the_default_plan(capsys):
    assert main(["design", str(EXAMPLES / "default_plan.toml"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["feasible"] and doc["identifiable"] and doc["identifiability"]["rank"] == 4
    assert [s["name"] for s in doc["segments"]] == ["locked d-step", "locked q-step", "free spin-up"]
    assert all(0 < s["peak_current"] < doc["current_limit"] for s in doc["segments"])
    # Predicted half-widths at 20 mA: relative CIs of a few hundredths of a percent.
    assert all(0 < p["relative_ci95"] < 1e-3 for p in doc["predicted"].values())


def test_design_flags_current_limit_and_runaway(tmp_path, capsys):
    plan = tmp_path / "hot.toml"
    plan.write_text('current_limit = "10 A"\nmax_speed = "20 rad/s"\n[[segment]]\nname = "spin"\n'
                    'duration = "50 ms"\nlocked = false\nv_q = "12 V"\n')
    with pytest.raises(SystemExit) as info:
        main(["design", str(plan)])
    captured = capsys.readouterr()
    assert info.value.code == 2
    assert "exceeds the current limit 10 A" in captured.out
    assert "runs away" in captured.out and "above max_speed 20 rad/s" in captured.out
    assert "feasibility problem(s)" in captured.err


@pytest.mark.parametrize("command", ["simulate", "fit", "design"])
def test_every_command_has_help(command, capsys):
    assert main([command, "--help"]) == 0
    assert "Usage: drivecal " + command in capsys.readouterr().out


# The group loads each command's module on first use (drivecal.cli._common.COMMANDS): the help lists
# the commands from registered summaries, so the listing must read exactly as click's own would.
_LAZY_HELP = """
import sys
import click
from click.testing import CliRunner
from drivecal.cli import cli

def loaded():
    return sorted(m for m in sys.modules if m.startswith("drivecal.cli._") and m != "drivecal.cli._common")

widths = (40, 60, 80, 200)
def help_text(group, width):
    return CliRunner().invoke(group, ["--help"], terminal_width=width, prog_name="drivecal")

before = {w: help_text(cli, w) for w in widths}
assert all(r.exit_code == 0 for r in before.values())
assert CliRunner().invoke(cli, ["--version"]).exit_code == 0
print("after --help and --version:", loaded())
r = CliRunner().invoke(cli, ["fit", "--help"], prog_name="drivecal")
assert r.exit_code == 0 and "Usage: drivecal fit" in r.output, r.output
print("after fit --help:", loaded())
# Plain click with the loaded commands: the listing it prints is the reference.
plain = click.Group("drivecal", help=cli.help, params=cli.params, context_settings=cli.context_settings,
                    commands={n: cli.get_command(None, n) for n in cli.list_commands(None)})
for w in widths:
    assert before[w].output == help_text(plain, w).output == help_text(cli, w).output, w
print("same listing")
"""


def test_help_and_version_load_no_command_module_and_list_each_commands_own_summary():
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _LAZY_HELP], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines == ["after --help and --version: []", "after fit --help: ['drivecal.cli._fit']", "same listing"]


@pytest.mark.parametrize("command", ["batch", "demo", "design", "fit", "fleet-report", "gains", "plan", "report",
                                     "simulate"])
def test_every_command_is_listed_and_answers_its_help(command, capsys):
    assert main(["--help"]) == 0
    listing = capsys.readouterr().out.split("Commands:")[1]
    assert f"\n  {command} " in listing
    assert main([command, "-h"]) == 0
    assert "Usage: drivecal " + command in capsys.readouterr().out


def test_version(capsys):
    from drivecal import __version__

    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"drivecal, version {__version__}\n"


# The drivecal program as its script runs it (main() on sys.argv), with an object the interpreter's teardown
# would free (and so print) and an atexit callback registered while the command runs, as a command's own are.
_PROGRAM = """
import atexit, sys
from drivecal.cli import _common

class Freed:
    def __del__(self):
        print("torn down", flush=True)

FREED = Freed()
run = _common._run

def command(argv):
    atexit.register(print, "cleaned up", flush=True)
    return run(argv)

_common._run = command
sys.argv = ["drivecal"] + sys.argv[1:]
sys.exit(_common.main())
"""


@pytest.mark.parametrize("args, status, out", [(["--version"], 0, "drivecal, version"),
                                               (["report", "no-such-result.json"], 2, "")])
def test_the_program_ends_with_its_status_after_cleaning_up_without_teardown(args, status, out):
    """The program's exit: its status, its output whole, the atexit callbacks run, the teardown skipped."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _PROGRAM, *args], capture_output=True, text=True, timeout=120)
    assert proc.returncode == status, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines[-1] == "cleaned up" and "torn down" not in lines
    assert lines[0].startswith(out) and len(lines) == (2 if out else 1)
    assert (status == 2) == proc.stderr.startswith("drivecal: error: no-such-result.json")





# The program's garbage collector, seen from inside its command: its youngest generation's threshold.
_GC_PROGRAM = """
import gc, sys
from drivecal.cli import _common
run = _common._run
_common._run = lambda argv: print(gc.get_threshold()[0], _common.YOUNG_GENERATION, flush=True) or run(argv)
sys.argv = ["drivecal", "--version"]
sys.exit(_common.main())
"""


def test_the_program_collects_garbage_less_often_a_caller_in_python_keeps_its_settings():
    """The drivecal program's youngest generation holds ``YOUNG_GENERATION`` objects (tracing JAX programs pushed
    Python's default into full collections); ``main(argv)`` called from Python leaves the caller's settings."""
    import gc
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _GC_PROGRAM], capture_output=True, text=True, timeout=120)
    threshold, wanted = proc.stdout.splitlines()[0].split()
    assert proc.returncode == 0 and threshold == wanted and int(wanted) > 700
    before = gc.get_threshold()
    assert main(["--version"]) == 0 and gc.get_threshold() == before


# The program's linear algebra, seen from inside its command: the variable it set and, where NumPy's OpenBLAS is
# a bundled library that says (a NumPy wheel's), how many threads OpenBLAS runs.
_BLAS_PROGRAM = """
import ctypes, glob, os, sys
from drivecal.cli import _common
run = _common._run

def openblas_threads():
    import numpy
    for path in glob.glob(os.path.join(os.path.dirname(numpy.__file__) + ".libs", "libscipy_openblas*")):
        library = ctypes.CDLL(path)
        for name in ("scipy_openblas_get_num_threads64_", "openblas_get_num_threads64_", "openblas_get_num_threads"):
            if hasattr(library, name):
                return getattr(library, name)()
    return "unknown"

_common._run = lambda argv: print(os.environ.get("OPENBLAS_NUM_THREADS"), openblas_threads(), flush=True) or run(argv)
sys.argv = ["drivecal", "--version"]
sys.exit(_common.main())
"""


@pytest.mark.parametrize("given, variable, threads", [({}, "1", "1"), ({"OMP_NUM_THREADS": "2"}, "None", "2"),
                                                      ({"OPENBLAS_NUM_THREADS": "2"}, "2", "2")])
def test_the_program_runs_its_linear_algebra_in_one_thread_unless_told(given, variable, threads):
    """The drivecal program sets OpenBLAS to one thread before NumPy loads (its second thread only spun), unless
    a variable that sets it is given; ``main(argv)`` called from Python leaves the environment alone."""
    import os
    import subprocess
    import sys

    blas = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")  # OpenBLAS reads the first one set
    env = {k: v for k, v in os.environ.items() if k not in blas} | given
    proc = subprocess.run([sys.executable, "-c", _BLAS_PROGRAM], capture_output=True, text=True, timeout=120, env=env)
    assert proc.returncode == 0, proc.stderr
    seen_variable, seen_threads = proc.stdout.splitlines()[0].split()
    assert seen_variable == variable
    if seen_threads != "unknown" and (threads == "1" or (os.cpu_count() or 1) >= 2):
        assert seen_threads == threads
    before = dict(os.environ)
    assert main(["--version"]) == 0 and dict(os.environ) == before


def test_fit_exit_status_is_the_verdicts(tmp_path, poor_bench, capsys):
    """0 only for 'calibrated'; partial, mismatch and not converged each their own status, none of them 2."""
    from drivecal.results import Status

    codes = {s: s.exit_code for s in Status}
    assert codes[Status.CALIBRATED] == 0 and codes[Status.INVALID] == 2
    assert len(set(codes.values())) == len(codes)  # one status, one code
    assert main(["fit", str(EXAMPLES / "bench.csv"), "--json"]) == 0  # calibrated
    assert json.loads(capsys.readouterr().out)["verdict"]["status"] == "calibrated"
    poor = poor_bench.save(tmp_path / "poor.csv")  # a locked q-step alone: Ld and lambda_m not identifiable
    assert main(["fit", str(poor), "--json"]) == Status.PARTIAL.exit_code == 3
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"]["status"] == "partial"
    # A realistic inverter (a one-sample delay, dead time, offsets) with its effects left out: model mismatch,
    # the delay named first. The default (--effects auto) finds them: docs/fitting.md's
    # `drivecal fit examples/inverter_bench.csv` (no flags, exit 0), run by tests/test_docs.py.
    assert main(["fit", str(EXAMPLES / "inverter_bench.csv"), "--effects", "none", "--json"]) == 4
    doc = json.loads(capsys.readouterr().out)
    assert Status.MISMATCH.exit_code == 4 and doc["verdict"]["status"] == "mismatch"
    assert doc["verdict"]["headline"].startswith("model mismatch suspected: most likely")
    # The Python API judges the same fit of the same data as the command: the same verdict, word for word.
    import drivecal as dc

    cal = dc.fit(dc.load_bench(EXAMPLES / "inverter_bench.csv", pole_pairs=4.0, nominal_R=0.45), dc.DEFAULT_MOTOR)
    assert cal.to_dict()["verdict"] == doc["verdict"] and cal.verdict.exit_code == 4


def test_a_fit_that_did_not_converge_exits_5():
    from drivecal.diagnose import verdict
    from drivecal.results import Status

    judged = verdict({"parameters": {}, "converged": False, "message": "max steps"})
    assert Status(judged["status"]) is Status.NOT_CONVERGED and Status.NOT_CONVERGED.exit_code == 5
