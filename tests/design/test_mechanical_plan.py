"""Issue 20 item 3 (plan and design): `drivecal plan --estimate ...,J,B,T_coulomb` adds the mechanical test.

The motor file carries the issue's mechanics (J = 1.2e-3 kg m^2, B = 8e-5 N m s, T_coulomb = 2e-3 N m).
The auto-plan must identify all seven parameters (design's rank 7, finite predicted intervals), keep the
predicted speed under max_speed (and the back-EMF inside the voltage circle), and a run of it on the
Jaxonomy engine bench without a speed column, fitted with the speed simulated, must recover every
parameter within 3 standard errors (one seed). `drivecal design` of the written plan prints the
mechanical intervals.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import drivecal as dc
from drivecal import design as autoplan
from drivecal.cli import main
from drivecal.design import MAX_FRICTION_SAMPLES, friction_samples, mechanical_segments
from drivecal.fitting import fit_currents
from drivecal.identify import assess_identifiability
from drivecal.plan import plan_to_dict

NOISE = 0.02  # A
MAX_SPEED = 50.0  # rad/s
LOW_SPEED, REVERSED, BRAKING = "low-speed run", "reversed run", "short-circuit braking"
TRUE = dc.DEFAULT_MOTOR.replace(J=1.2e-3, B=8e-5, T_coulomb=2e-3)
NAMES = dc.ESTIMATED + ("J", "B", "T_coulomb")
MOTOR_TOML = """\
R = "0.45 ohm"
Ld = "3.2 mH"
Lq = "5.8 mH"
lambda_m = "0.0533 Wb"
pole_pairs = 4
J = 1.2e-3
B = 8e-5
T_coulomb = 2e-3
"""


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    """`drivecal plan --estimate R,Ld,Lq,lambda_m,J,B,T_coulomb --json`: the written plan and the JSON."""
    folder = tmp_path_factory.mktemp("mechanical_plan")
    motor = folder / "motor.toml"
    motor.write_text(MOTOR_TOML)
    out = folder / "plan.toml"
    code = main(["plan", "--motor", str(motor), "--vdc", "48", "--imax", "30", "--max-speed", str(MAX_SPEED),
                 "--noise", str(NOISE), "--estimate", ",".join(NAMES), "--json", "--out", str(out)])
    return code, out, motor


def test_plan_adds_the_mechanical_test_and_identifies_it(planned, capsys):
    code, out, _ = planned
    assert code == 0
    plan = dc.load_plan(out)
    names = [s.name for s in plan.segments]
    assert names == ["locked d-step", "locked q-step", "free spin-up", LOW_SPEED, BRAKING]
    spin, low, brake = plan.segments[2:]
    assert not spin.locked and not spin.continues
    assert low.continues and brake.continues and not low.locked and not brake.locked
    fs = plan.sample_rate
    assert not np.any(brake.voltages(fs))  # short-circuit braking: the inverter on, 0 V
    assert 0 < low.voltages(fs)[0, 1] < spin.voltages(fs)[0, 1]
    # design judges the written plan as the auto-plan did: all seven identified, finite intervals
    report = dc.assess_design(plan, TRUE, noise_sigma=NOISE, names=NAMES)
    ident = report.identifiability
    assert report.ok and ident.rank == len(NAMES) == 7
    ci = dict(zip(ident.names, ident.predicted_ci95))
    assert all(math.isfinite(ci[n]) and ci[n] > 0 for n in NAMES)
    # the friction is sized for an SE of FRICTION_SE of its value; the plan does at least that well
    se = dict(zip(ident.names, ident.predicted_se))
    for n in ("B", "T_coulomb"):
        assert se[n] <= autoplan.FRICTION_SE * float(getattr(TRUE, n)), (n, se[n])


def test_plan_keeps_the_speed_under_max_speed(planned):
    _, out, _ = planned
    plan = dc.load_plan(out)
    assert plan.max_speed == MAX_SPEED
    report = dc.assess_design(plan, TRUE, noise_sigma=NOISE, names=NAMES)
    peak = max(s.peak_speed for s in report.segments)
    assert 0 < peak <= autoplan.SPEED_FRACTION * MAX_SPEED * 1.05
    # the back-EMF at the peak speed stays inside the voltage circle (an inverter-off coast would carry no
    # current), the currents inside the limit, the voltages inside the circle (check_feasible)
    assert float(TRUE.pole_pairs) * peak * float(TRUE.lambda_m) < plan.voltage_limit
    assert all(s.peak_current <= autoplan.CURRENT_MARGIN * plan.current_limit for s in report.segments)
    plan.check_feasible()
    # the low-speed run settles well below the spin-up's speed: two speeds tell B from T_coulomb
    states = np.asarray(dc.simulate_states(TRUE, dc.Experiment.from_plan(plan)))
    n = [s.num_samples(plan.sample_rate) for s in plan.segments]
    ends = np.cumsum(n) - 1
    w_spin, w_low, w_end = (abs(states[ends[k], 2]) for k in (2, 3, 4))
    assert w_low < 0.5 * w_spin and w_end < 0.05 * w_spin  # the braking stops the rotor


def test_simulated_run_recovers_the_mechanics_within_3_se(planned):
    """The plan on the engine bench, no speed column, 20 mA noise; the fit from a prior 33 % / 50 % off."""
    _, out, _ = planned
    plan = dc.load_plan(out)
    bench = dc.engine_bench(plan, TRUE).add_noise(NOISE, 20)
    assert all(s.w_m is None for s in bench.segments)
    experiment = bench.experiment(measured_speed=True)  # no speed column: the speed is simulated
    prior = dc.datasheet_guess(TRUE).replace(J=1.6e-3, B=1.2e-4, T_coulomb=1e-3)
    ident = assess_identifiability(experiment, prior, names=NAMES)
    cal = fit_currents(experiment, bench.currents, prior, names=NAMES, identifiability=ident)
    assert bool(cal.converged)
    assert 0.8 * NOISE < float(cal.sigma_hat) < 1.2 * NOISE
    design = dc.assess_design(plan, TRUE, noise_sigma=NOISE, names=NAMES).identifiability
    predicted = dict(zip(design.names, design.predicted_se))
    for name in NAMES:
        i = cal.names.index(name)
        z = (float(cal.estimate[i]) - float(getattr(TRUE, name))) / float(cal.se[i])
        print(f"{name}: estimate {float(cal.estimate[i]):.6g}, SE {float(cal.se[i]):.3g} (design predicted "
              f"{predicted[name]:.3g}), z = {z:+.2f}")
        assert abs(z) < 3.0, (name, z)
        # design's prediction is the fit's interval (the motor is near nominal)
        assert 0.7 < float(cal.se[i]) / predicted[name] < 1.4, (name, float(cal.se[i]), predicted[name])


def test_design_prints_the_mechanical_intervals(planned, capsys):
    _, out, motor = planned
    estimate = "estimate = [" + ", ".join(f'"{n}"' for n in NAMES) + "]\n"
    motor.write_text(MOTOR_TOML + estimate)
    capsys.readouterr()
    assert main(["design", str(out), "--motor", str(motor), "--noise", str(NOISE)]) == 0
    text = capsys.readouterr().out
    assert "rank 7/7" in text
    rows = {cells[0]: cells for cells in ([c.strip() for c in line.split("\u2502")[1:-1]]
                                          for line in text.splitlines()) if cells}
    # engineering units: kg·m² as written, the friction in µN·m·s, the Coulomb torque in mN·m
    for name, unit, scale in (("J", "kg·m²", 1.0), ("B", "µN·m·s", 1e-6), ("T_coulomb", "mN·m", 1e-3)):
        _, shown_unit, nominal, half, relative, verdict = rows[name]
        assert shown_unit == unit and verdict == "yes", rows[name]
        assert float(nominal) * scale == pytest.approx(float(getattr(TRUE, name)), rel=1e-3), rows[name]
        assert 0 < float(half) and 0 < float(relative) < 50, rows[name]


def test_estimate_defaults_to_the_motor_file_and_plain_plans_stay_electrical(planned, tmp_path, capsys):
    _, first, _ = planned
    motor = tmp_path / "motor.toml"
    motor.write_text(MOTOR_TOML + "estimate = [" + ", ".join(f'"{n}"' for n in NAMES) + "]\n")
    out = tmp_path / "p.toml"
    # no --estimate: the motor file's 'estimate' asks for the mechanics, and the same plan comes out
    assert main(["plan", "--motor", str(motor), "--vdc", "48", "--imax", "30", "--max-speed", str(MAX_SPEED),
                 "--noise", str(NOISE), "--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert list(doc["assessment"]["predicted"]) == list(NAMES)
    assert [s["name"] for s in doc["segments"]][-1] == BRAKING and doc["segments"][-1]["continue"] is True
    assert plan_to_dict(dc.load_plan(out)) == plan_to_dict(dc.load_plan(first))
    # --estimate without mechanics: the three segments the plan always had
    assert main(["plan", "--motor", str(motor), "--vdc", "48", "--imax", "30", "--estimate", "R,Ld,Lq,lambda_m",
                 "--out", str(out)]) == 0
    assert [s.name for s in dc.load_plan(out).segments] == ["locked d-step", "locked q-step", "free spin-up"]
    assert "J" not in capsys.readouterr().out


def test_unknown_estimate_is_refused_in_one_sentence(tmp_path, capsys):
    from helpers.cli import assert_one_sentence, run_cli

    code, err = run_cli(["plan", "--vdc", "48", "--imax", "30", "--estimate", "R,J,friction",
                         "--out", tmp_path / "p.toml"], capsys)
    assert_one_sentence(code, err, "--estimate", "friction")


def test_friction_sizing_follows_noise_and_friction():
    """Samples of steady running grow with the noise squared and shrink with the friction squared."""
    base = friction_samples(TRUE, NAMES, 10.0, NOISE)
    assert base > 0
    assert friction_samples(TRUE, NAMES, 10.0, 2 * NOISE) == pytest.approx(4 * base, rel=1e-3)
    assert friction_samples(TRUE.replace(B=16e-5, T_coulomb=4e-3), NAMES, 10.0, NOISE) == pytest.approx(
        base / 4, rel=1e-2)
    assert friction_samples(TRUE, dc.ESTIMATED + ("J",), 10.0, NOISE) == 0  # J alone needs no steady running
    # a friction the motor file puts at 0 is sized against the friction torque at the low speed
    assert 0 < friction_samples(TRUE.replace(T_coulomb=0.0), NAMES, 10.0, NOISE) < MAX_FRICTION_SAMPLES
    # T_load: a reversed run joins (three speeds for B, T_coulomb and T_load)
    runs = mechanical_segments(10.0, NAMES + ("T_load",), [100, 100, 100], 1000.0)
    assert [s.name for s in runs] == [LOW_SPEED, REVERSED, BRAKING] and all(s.continues for s in runs)
    assert [float(s.v_q) for s in runs] == [2.5, -2.5, 0.0]


@pytest.mark.slow
def test_load_torque_plan_identifies_eight():
    names = NAMES + ("T_load",)
    report = dc.auto_design(TRUE.replace(T_load=5e-4), v_dc=48.0, current_limit=30.0, max_speed=MAX_SPEED,
                            noise_sigma=NOISE, names=names)
    assert report.ok and report.identifiability.rank == 8
    assert [s.name for s in report.plan.segments][3:] == [LOW_SPEED, REVERSED, BRAKING]
    assert max(s.peak_speed for s in report.segments) <= autoplan.SPEED_FRACTION * MAX_SPEED * 1.05


def test_design_refuses_an_inverter_off_coast_whose_back_emf_leaves_the_dc_link():
    """With the switches open the diodes conduct once the back-EMF exceeds v_dc/sqrt(3): design says so."""
    plan = dc.Plan((dc.Segment("spin-up", 0.12, False, v_q=12.0),
                    dc.Segment("coast-down", 0.4, False, continues=True, inverter="off")), sample_rate=5_000.0,
                   v_dc=21.0)
    # a load that drives the rotor (T_load < 0) speeds the coast past the DC link's reach
    report = dc.assess_design(plan, TRUE.replace(T_load=-0.02), names=("R",))
    coast = report.segments[1]
    assert float(TRUE.pole_pairs) * coast.peak_speed * float(TRUE.lambda_m) > plan.voltage_limit
    assert any("'coast-down': the inverter is off but the back-EMF" in p for p in report.problems)
    # without that load it coasts down inside the DC link: no problem
    assert not dc.assess_design(plan, TRUE, names=("R",)).problems
