"""Running the CLI in-process and checking its one-sentence refusals (shared by the tests of every input kind)."""

from __future__ import annotations

import base64
import re
from pathlib import Path

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


def assert_page_embeds_files(directory: Path, names) -> None:
    """``directory/report.html`` embeds each PNG file of ``names`` byte for byte (drawn once for both), shown at the
    size the page's own resolution would give it (``report.FIG_DPI``; the files are at ``report.FILE_DPI``)."""
    from drivecal.report import FIG_DPI, FILE_DPI

    page = (directory / "report.html").read_text()
    images = re.findall(r'<img alt="[^"]*"(?: width="(\d+)" height="(\d+)")? src="data:image/png;base64,([^"]+)"',
                        page)
    embedded = {base64.b64decode(data): (width, height) for width, height, data in images}
    for name in names:
        png = (directory / name).read_bytes()
        assert png in embedded, name
        width, height = (int.from_bytes(png[k:k + 4], "big") for k in (16, 20))
        assert embedded[png] == (str(round(width * FIG_DPI / FILE_DPI)), str(round(height * FIG_DPI / FILE_DPI)))
