"""A motor file's nominal values and limits read as plain numbers (drivecal/data/_nominal.py): what
``drivecal fleet-report --motor`` reads without JAX is what the motor loaded whole gives."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from drivecal.data import load_motor, motor_nominal
from drivecal.errors import DrivecalError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
MOTOR_FILES = ("motor.toml", "motor_alpha.toml", "motor_spec.toml", "servo_400v.toml", "inverter_bench_truth.toml",
               "syrm_motor.toml", "pm_syrm_motor.toml")


@pytest.mark.parametrize("name", MOTOR_FILES)
def test_the_nominal_values_and_limits_are_those_of_the_loaded_motor(name):
    """Every example motor file (plain, with a [tolerance] table, with Hinkkanen's and Lelli's published laws)."""
    loaded, nominal = load_motor(EXAMPLES / name), motor_nominal(EXAMPLES / name)
    assert nominal.values == loaded.motor.all_values()
    assert nominal.tolerance == loaded.tolerance
    assert nominal.defaulted == loaded.defaulted


def test_a_bad_value_is_refused_alike(tmp_path):
    """The checks are the same code: one sentence naming the file and the key, from either reader."""
    path = tmp_path / "bad.toml"
    path.write_text('R = "0.45 ohm"\nLd = "3.2 mH"\nLq = "5.8 mH"\nlambda_m = "0.05 Wb"\npole_pairs = 4\n'
                    'v_dead = -1.0\nestimate = ["R"]\n')
    messages = []
    for read in (load_motor, motor_nominal):
        with pytest.raises(DrivecalError) as info:
            read(path)
        messages.append(str(info.value))
    assert messages[0] == messages[1] and "'v_dead'" in messages[0] and str(path) in messages[0]


_PROGRAM = """
import sys
from drivecal.data import motor_nominal

motor_nominal(sys.argv[1])
print(sorted(m for m in ("jax", "jaxlib", "equinox", "drivecal.physics", "drivecal.model") if m in sys.modules))
"""


@pytest.mark.parametrize("name, loads_jax", [("motor_spec.toml", False), ("syrm_motor.toml", True)])
def test_a_plain_motor_file_is_read_without_jax(name, loads_jax):
    """A plain file's values need no motor model; a published law (Hinkkanen's, Lelli's) gives Ld and Lq, so
    such a file is loaded whole."""
    proc = subprocess.run([sys.executable, "-c", _PROGRAM, str(EXAMPLES / name)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert (proc.stdout.splitlines()[-1] != "[]") is loads_jax
