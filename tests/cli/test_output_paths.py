"""Every command's output paths, checked before any work by one rule; refused input writes nothing.

The rule (drivecal._io.check_output_path): an output file's directory must exist and be writable, and the file
must not be a directory; an output directory (demo/fit --out) is created if missing, but its parent must exist.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from drivecal.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

#: command -> (argv with {out} for the output path, the option, whether the output is a directory, a file name)
COMMANDS = {
    "demo": (["demo", "--out", "{out}"], "--out", True, "out"),
    "fit": (["fit", str(EXAMPLES / "bench.csv"), "--out", "{out}"], "--out", True, "out"),
    "simulate": (["simulate", str(EXAMPLES / "default_plan.toml"), "--out", "{out}"], "--out", False, "sim.csv"),
    "design": (["design", str(EXAMPLES / "default_plan.toml"), "--optimize", "--out", "{out}"], "--out", False,
               "opt.toml"),
    "plan": (["plan", "--vdc", "48", "--imax", "30", "--out", "{out}"], "--out", False, "plan.toml"),
    "batch": (["batch", str(EXAMPLES / "bench.csv"), "--out", "{out}", "--workers", "1"], "--out", False,
              "results.parquet"),
    "report": (["report", "{tmp}/result.json", "--html", "{out}"], "--html", False, "report.html"),
    "fleet-report": (["fleet-report", "{tmp}/results.parquet", "--html", "{out}"], "--html", False, "fleet.html"),
}


def listing(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def refused(argv: list[str], capsys) -> str:
    with pytest.raises(SystemExit) as info:
        main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("drivecal: error: "), err
    assert "Traceback" not in err
    return lines[0]


def argv_for(command: str, out: Path, tmp: Path) -> list[str]:
    return [a.format(out=out, tmp=tmp) for a in COMMANDS[command][0]]


def _missing_directory(tmp: Path, name: str, directory: bool) -> tuple[Path, str]:
    return tmp / "nowhere" / name, "does not exist"


def _parent_is_a_file(tmp: Path, name: str, directory: bool) -> tuple[Path, str]:
    (tmp / "afile").write_text("keep me")
    return tmp / "afile" / name, "is a file, not a directory"


def _wrong_kind(tmp: Path, name: str, directory: bool) -> tuple[Path, str]:
    if directory:  # a file where the output directory should be
        (tmp / name).write_text("keep me")
        return tmp / name, "is an existing file, not a directory"
    (tmp / name).mkdir()  # a directory where the output file should be
    return tmp / name, "is a directory, not a file"


@pytest.mark.parametrize("case", [_missing_directory, _parent_is_a_file, _wrong_kind],
                         ids=["missing-directory", "parent-is-a-file", "wrong-kind"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_an_output_path_that_cannot_be_written_is_refused_before_any_work(command, case, tmp_path, capsys):
    _, option, directory, name = COMMANDS[command]
    out, why = case(tmp_path, name, directory)
    before = listing(tmp_path)
    line = refused(argv_for(command, out, tmp_path), capsys)
    assert f"{option} {out}" in line and why in line, line
    assert listing(tmp_path) == before  # nothing written, nothing created
    if (tmp_path / "afile").exists():
        assert (tmp_path / "afile").read_text() == "keep me"


@pytest.mark.parametrize("command", list(COMMANDS))
def test_an_output_in_a_directory_without_write_permission_is_refused(command, tmp_path, capsys, monkeypatch):
    _, option, directory, name = COMMANDS[command]
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    # Tests may run as root, who may write anywhere: the directory answers "no" as a read-only one would.
    monkeypatch.setattr(os, "access", lambda p, mode, **kw: Path(p) != locked and real_access(p, mode, **kw))
    before = listing(tmp_path)
    line = refused(argv_for(command, locked / name, tmp_path), capsys)
    assert f"{option} {locked / name}" in line and "no permission to write" in line, line
    assert listing(tmp_path) == before


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root may write in a read-only directory")
def test_a_read_only_directory_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        line = refused(["plan", "--vdc", "48", "--imax", "30", "--out", str(locked / "p.toml")], capsys)
    finally:
        locked.chmod(0o755)
    assert "no permission to write" in line and not list(locked.iterdir())


def test_an_empty_output_path_is_refused(tmp_path, capsys):
    line = refused(["plan", "--vdc", "48", "--imax", "30", "--out", ""], capsys)
    assert "--out: the path is empty" in line


def test_an_output_directory_is_created_when_its_parent_exists_and_only_then(tmp_path):
    from drivecal.errors import DrivecalError
    from drivecal.report import prepare_output_dir

    assert prepare_output_dir(tmp_path / "new").is_dir()
    assert prepare_output_dir(tmp_path / "new").is_dir()  # an existing directory is fine
    with pytest.raises(DrivecalError, match="does not exist"):
        prepare_output_dir(tmp_path / "a" / "b")
    assert not (tmp_path / "a").exists()


def _bad_plan(tmp: Path) -> str:
    (tmp / "bad_plan.toml").write_text('sample_rate = 0\n[[segment]]\nname = "a"\nduration = "5 ms"\nlocked = true\n')
    return str(tmp / "bad_plan.toml")


def _empty_motor(tmp: Path) -> str:
    (tmp / "motor.toml").write_text("# nothing here\n")
    return str(tmp / "motor.toml")


#: command -> argv whose input is refused (after the output path passed), with the fragment of the refusal.
BAD_INPUT = {
    "demo": (lambda t: ["demo", "--out", str(t / "out"), "--noise", "-1"], "--noise"),
    "fit": (lambda t: ["fit", str(t / "missing.csv"), "--out", str(t / "out")], "missing.csv"),
    "simulate": (lambda t: ["simulate", _bad_plan(t), "--out", str(t / "sim.csv")], "'sample_rate' must be positive"),
    "design": (lambda t: ["design", _bad_plan(t), "--optimize", "--out", str(t / "opt.toml")], "sample_rate"),
    "plan": (lambda t: ["plan", "--vdc", "48", "--imax", "30", "--motor", _empty_motor(t), "--out",
                        str(t / "p.toml")], "the motor file is empty"),
    "batch": (lambda t: ["batch", str(t / "nothing-here"), "--out", str(t / "r.parquet")], "no bench files"),
    "report": (lambda t: ["report", str(t / "missing.json"), "--html", str(t / "r.html")], "missing.json"),
    "fleet-report": (lambda t: ["fleet-report", str(t / "missing.parquet"), "--html", str(t / "f.html")],
                     "missing.parquet"),
}


@pytest.mark.parametrize("command", list(BAD_INPUT))
def test_no_command_writes_anything_when_it_refuses_its_input(command, tmp_path, capsys):
    make, fragment = BAD_INPUT[command]
    argv = make(tmp_path)
    before = listing(tmp_path)
    line = refused(argv, capsys)
    assert fragment in line, line
    assert listing(tmp_path) == before


def test_an_empty_motor_file_is_refused_and_a_partial_one_warns(tmp_path, capsys):
    line = refused(["design", str(EXAMPLES / "default_plan.toml"), "--motor", _empty_motor(tmp_path)], capsys)
    assert "the motor file is empty" in line and "leave out --motor" in line
    partial = tmp_path / "partial.toml"
    partial.write_text('R = "0.45 ohm"\nLd = "3.2 mH"\n')
    assert main(["design", str(EXAMPLES / "default_plan.toml"), "--motor", str(partial), "--json"]) == 0
    captured = capsys.readouterr()
    warning = captured.err.strip().splitlines()
    assert len(warning) == 1 and warning[0].startswith("drivecal: warning: --motor ")
    assert "Lq, lambda_m, pole_pairs not in the file" in warning[0] and "demo motor" in warning[0]
    assert captured.out.lstrip().startswith("{")  # stdout stays JSON
    # a complete file, and no --motor at all: no warning
    assert main(["design", str(EXAMPLES / "default_plan.toml"), "--motor", str(EXAMPLES / "motor.toml"),
                 "--json"]) == 0
    assert capsys.readouterr().err == ""
