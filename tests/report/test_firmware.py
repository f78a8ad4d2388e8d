"""Firmware hand-off of the gains: feed-forward, voltage limit, per-unit and Q-format constants, the C header."""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess

import numpy as np
import pytest

import drivecal as dc
from conftest import NOISE
from drivecal.cli import main
from drivecal.physics import dq_derivatives
from drivecal.report import build_result, design_current_loop, firmware_gains, to_fixed

BASE = {"current": 30.0, "voltage": 24.0, "frequency": 500.0}


@pytest.fixture(scope="module")
def exported(default_fit, default_bench, tmp_path_factory):
    """`drivecal gains ... --header --out` on a saved result: (header text, JSON doc, directory)."""
    out = tmp_path_factory.mktemp("firmware")
    path = out / "result.json"
    path.write_text(json.dumps(build_result(default_fit, default_bench, plan=dc.default_plan(), noise_sigma=NOISE)))
    assert main(["gains", str(path), "--bandwidth", "1000", "--sample-rate", "20000", "--samples", "500",
                 "--base-current", str(BASE["current"]), "--base-voltage", str(BASE["voltage"]),
                 "--base-frequency", str(BASE["frequency"]), "--q-format", "Q15", "--vdc", "60",
                 "--header", str(out / "gains.h"), "--out", str(out / "gains.json")]) == 0
    return (out / "gains.h").read_text(), json.loads((out / "gains.json").read_text()), out


def _defines(header: str) -> dict[str, float]:
    return {m.group(1): float(m.group(2)) for m in re.finditer(r"^#define DRIVECAL_(\w+) (\S+)", header, re.M)
            if re.fullmatch(r"[-+0-9.eE]+", m.group(2))}


@pytest.mark.parametrize("value", [0.0, 1.0, -1.0, 0.7, 14.0153, -25.365, 3.3e-4, 1234.5, 32767.0, 1e6])
@pytest.mark.parametrize("bits", [15, 31])
def test_fixed_point_is_within_half_an_lsb_and_uses_the_range(value, bits):
    q, shift = to_fixed(value, bits)
    assert isinstance(q, int) and abs(q) <= 2**bits - 1
    assert abs(q / 2.0**shift - value) <= 0.5 * 2.0**-shift
    if value != 0:
        assert abs(round(value * 2.0 ** (shift + 1))) > 2**bits - 1  # one more bit would not fit


def test_the_header_compiles(exported, tmp_path):
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH: the header's syntax is not checked")
    header, _, out = exported
    source = tmp_path / "use.c"
    source.write_text(f'#include "{out / "gains.h"}"\n#include "{out / "gains.h"}" /* the guard */\n'
                      "int main(void) { drivecal_pi_state s = {0.0f, 0.0f}; float v_d, v_q;\n"
                      "  drivecal_current_step(&s, 1.0f, 2.0f, 0.5f, 0.5f, 300.0f, &v_d, &v_q);\n"
                      "  return (int)(v_d + v_q + DRIVECAL_KP_D_Q + DRIVECAL_KP_D_SHIFT + DRIVECAL_KI_TS_Q_PU); }\n")
    proc = subprocess.run([cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-fsyntax-only", str(source)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr


def test_fixed_point_values_match_the_floating_ones_within_one_lsb(exported):
    header, doc, _ = exported
    defines = _defines(header)
    constants = doc["firmware"]["constants"]
    checked = 0
    for name, c in constants.items():
        if "fixed" not in c:
            continue
        q, shift, pu = defines[f"{name}_Q"], defines[f"{name}_SHIFT"], defines[f"{name}_PU"]
        assert abs(q) <= 32767 and q == c["fixed"]["q"] and shift == c["fixed"]["shift"]
        assert abs(q / 2.0**shift - pu) <= 2.0**-shift  # within one LSB of the per-unit float
        assert pu == c["pu"] and defines[name] == c["value"]  # the header's floats are the JSON's
        checked += 1
    assert checked == 8  # Kp and Ki*Ts of each axis, Ld, Lq, lambda_m, V_max
    # per unit is the SI value on the stated base
    ib, vb, wb = BASE["current"], BASE["voltage"], 2 * math.pi * BASE["frequency"]
    assert defines["KP_D_PU"] == pytest.approx(defines["KP_D"] * ib / vb, rel=1e-15)
    assert defines["KI_TS_Q_PU"] == pytest.approx(defines["KI_Q"] * defines["TS"] * ib / vb, rel=1e-12)
    assert defines["LQ_PU"] == pytest.approx(defines["LQ"] * wb * ib / vb, rel=1e-15)
    assert defines["LAMBDA_M_PU"] == pytest.approx(defines["LAMBDA_M"] * wb / vb, rel=1e-15)
    assert defines["V_MAX"] == pytest.approx(60 / math.sqrt(3), rel=1e-15)  # --vdc beats the plan's 48 V


def test_the_exported_gains_carry_their_uncertainty(exported):
    header, doc, _ = exported
    d = doc["axes"]["d"]
    kp = doc["firmware"]["constants"]["KP_D"]
    assert kp["value"] == d["kp"] and kp["se"] == d["kp_se_first_order"] > 0
    assert kp["pu_se"] == pytest.approx(kp["se"] * BASE["current"] / BASE["voltage"], rel=1e-15)
    assert re.search(r"#define DRIVECAL_KP_D \S+ /\* V/A, SE \d", header)


def test_feed_forward_cancels_the_speed_voltages(default_fit):
    """With v_ff added, the dq equations at speed are the standstill ones: each axis is 1/(L s + R)."""
    motor = default_fit.motor
    w_m, i_d, i_q, v_pi = 150.0, -3.0, 7.0, (2.0, -1.5)
    w_e = float(motor.pole_pairs) * w_m
    v_ff = (-w_e * float(motor.Lq) * i_q, w_e * (float(motor.Ld) * i_d + float(motor.lambda_m)))
    moving = dq_derivatives(np.array([i_d, i_q, w_m, 0.0]), np.add(v_pi, v_ff), motor, False)
    still = dq_derivatives(np.array([i_d, i_q, 0.0, 0.0]), np.array(v_pi), motor, True)
    assert float(moving[0]) == pytest.approx(float(still[0]), rel=1e-12)
    assert float(moving[1]) == pytest.approx(float(still[1]), rel=1e-12)


def test_the_header_reference_step_limits_to_the_voltage_circle(exported, tmp_path):
    """Compiled and run: a small error gives the PI plus feed-forward; a huge one is held on the circle and
    its integrator does not wind up."""
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc, gcc or clang) on PATH")
    header, _, out = exported
    d = _defines(header)
    source = tmp_path / "run.c"
    source.write_text(
        f'#include <stdio.h>\n#include "{out / "gains.h"}"\n'
        "int main(void) { drivecal_pi_state s = {0.0f, 0.0f}; float v_d, v_q; int k;\n"
        "  drivecal_current_step(&s, 0.1f, 0.2f, 0.0f, 0.0f, 100.0f, &v_d, &v_q);\n"
        "  printf(\"%.9g %.9g %.9g %.9g\\n\", v_d, v_q, s.x_d, s.x_q);\n"
        "  s.x_d = 0.0f; s.x_q = 0.0f;\n"
        "  for (k = 0; k < 1000; ++k) drivecal_current_step(&s, 0.0f, 100.0f, 0.0f, 0.0f, 0.0f, &v_d, &v_q);\n"
        "  printf(\"%.9g %.9g %.9g %.9g\\n\", v_d, v_q, s.x_d, s.x_q);\n  return 0; }\n")
    exe = tmp_path / "run"
    proc = subprocess.run([cc, "-std=c99", "-O1", str(source), "-o", str(exe), "-lm"], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    small, big = (np.array(line.split(), float) for line in subprocess.run(
        [str(exe)], capture_output=True, text=True, timeout=10, check=True).stdout.splitlines())
    assert small[0] == pytest.approx(d["KP_D"] * 0.1, rel=1e-6)
    assert small[1] == pytest.approx(d["KP_Q"] * 0.2 + 100.0 * d["LAMBDA_M"], rel=1e-6)
    assert small[2:] == pytest.approx([d["KI_TS_D"] * 0.1, d["KI_TS_Q"] * 0.2], rel=1e-6)
    v_max = d["V_MAX"]
    assert big[0] == 0.0 and big[1] == pytest.approx(v_max, rel=1e-6)
    assert abs(big[3]) <= v_max * (1 + 1e-6)  # the integrator held at the limit, not 1000 steps of Ki*Ts*e


def test_firmware_options_need_a_base_and_a_sample_rate(default_fit):
    cont = design_current_loop(default_fit, 1000.0, num_samples=200)
    with pytest.raises(dc.DrivecalError, match="need --sample-rate"):
        firmware_gains(cont, default_fit)
    disc = design_current_loop(default_fit, 1000.0, sample_rate_hz=20e3, num_samples=200)
    fw = firmware_gains(disc, default_fit)  # SI only: no voltage limit, no per-unit, no fixed point
    assert fw.q_bits is None and all(c.pu is None and c.fixed is None for c in fw.constants)
    assert "V_MAX" not in {c.name for c in fw.constants}
    with pytest.raises(dc.DrivecalError, match="--base-frequency needs the per-unit base"):
        firmware_gains(disc, default_fit, base_frequency_hz=500.0)
