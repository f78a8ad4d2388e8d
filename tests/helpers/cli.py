"""Running the CLI in-process and checking its one-sentence refusals (shared by the tests of every input kind)."""

from __future__ import annotations

import pytest

from drivecal.cli import main


def run_cli_output(args, capsys) -> tuple[int, str, str]:
    """Run ``drivecal ARGS`` that must exit through SystemExit: ``(exit status, stderr, stdout)``."""
    with pytest.raises(SystemExit) as info:
        main([str(a) for a in args])
    captured = capsys.readouterr()
    return info.value.code, captured.err, captured.out


def run_cli(args, capsys) -> tuple[int, str]:
    """As :func:`run_cli_output`, without stdout: ``(exit status, stderr)``."""
    code, err, _ = run_cli_output(args, capsys)
    return code, err


def assert_one_sentence(code, err, *needles):
    """Bad input: exit status 2, one line ``drivecal: error: ...`` on stderr holding every needle, no traceback."""
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("drivecal: error: ")
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def assert_plan_refused(document: dict, *needles: str, source: str = "p.toml") -> None:
    """``plan_from_dict(document)`` refuses in one sentence that starts with ``source`` and holds every needle."""
    from drivecal.errors import DrivecalError
    from drivecal.plan import plan_from_dict

    with pytest.raises(DrivecalError) as info:
        plan_from_dict(document, source=source)
    message = str(info.value)
    assert message.startswith(f"{source}: ") and "\n" not in message
    for needle in needles:
        assert needle in message, (needle, message)
