"""What `drivecal fit FILE` loads: with the default motor and no format or plan file, no file schema (pydantic) and
no equinox (drivecal's pytrees are its own), ~0.5 s of imports on a 2-core machine that a fit does not need."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

_PROGRAM = """
import sys
import drivecal.cli._fit
from drivecal.data import load_bench, load_motor
from drivecal import diagnose, fitting, identify, report, results, selection

load_bench(sys.argv[1])
load_motor(None if sys.argv[2] == "-" else sys.argv[2])
print(sorted(m for m in ("pydantic", "equinox", "optimistix") if m in sys.modules))
"""


@pytest.mark.parametrize("motor, loaded", [("-", "[]"), ("motor.toml", "['pydantic']")])
def test_a_fit_with_the_default_motor_loads_no_file_schema_and_no_equinox(motor, loaded):
    """A motor file is read through its schema (pydantic); the default motor and a bench file need none."""
    argument = motor if motor == "-" else str(EXAMPLES / motor)
    proc = subprocess.run([sys.executable, "-c", _PROGRAM, str(EXAMPLES / "bench.csv"), argument],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == loaded
