"""Issue 18: auto-plans that see the magnetic saturation and stay under the current limit.

With saturation coefficients to estimate, ``auto_plan`` lays out locked steps at three current levels per
axis (1/3, 2/3 and all of 0.8 of the limit) and combined d+q steps; the plan identifies the law (rank full)
and, run on the saturating engine bench, stays under the plan's current limit. Peaks are predicted with the
motor's law where it has one; a linear motor's free segments keep a margin for unknown saturation. Without
saturation names the plans are those of before.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.cli import main
from drivecal.design import (SATURATED_INDUCTANCE_FRACTION, SATURATION_LEVELS, SATURATION_TOP_FRACTION,
                             assess_design, auto_design, predict_segments, with_saturation_steps)
from drivecal.identify import magnetic_reasons
from drivecal.model import model_experiment
from drivecal.physics import MAGNETIC, from_hinkkanen
from helpers.blocks import lelli_bench, lelli_motor_file

#: Hinkkanen et al. 2017's 6.7-kW SyRM (doi 10.1109/TIA.2016.2644624), as in tests/selection.
HINKKANEN_SYRM = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1, V=0)
SYRM_NAMES = ("R", "Ld", "Lq") + MAGNETIC
SYRM_LIMIT = 40.0
SEED_LIMIT = 30.0
#: The seed motor with a saturating law (the secant inductances fall by a quarter to a half at the limit).
SEED_LAW = dict(sat_d=0.3, sat_q=0.8, sat_dq=0.3, i_ref=SEED_LIMIT)


def _peaks(currents: np.ndarray) -> tuple[float, float, float]:
    """Largest |i_d|, |i_q| and |i_dq| (A)."""
    c = np.asarray(currents)
    return float(np.abs(c[:, 0]).max()), float(np.abs(c[:, 1]).max()), float(np.hypot(c[:, 0], c[:, 1]).max())


def _segment_peaks(plan: dc.Plan, currents: np.ndarray) -> list[float]:
    """Largest |i_dq| (A) of each segment of ``plan`` in ``currents`` (the bench's, in plan order)."""
    out, k = [], 0
    for seg in plan.segments:
        n = seg.num_samples(plan.sample_rate)
        out.append(float(np.hypot(currents[k:k + n, 0], currents[k:k + n, 1]).max()))
        k += n
    return out


@pytest.fixture(scope="module")
def syrm() -> dc.MotorParams:
    return from_hinkkanen(dc.MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=20.0, **HINKKANEN_SYRM)


@pytest.fixture(scope="module")
def syrm_design(syrm) -> dc.DesignReport:
    return auto_design(syrm, v_dc=540.0, current_limit=SYRM_LIMIT, names=SYRM_NAMES)


@pytest.fixture(scope="module")
def syrm_bench(syrm, syrm_design):
    return engine_bench(syrm_design.plan, syrm)


def test_syrm_plan_has_levels_and_combined_steps_and_identifies_the_law(syrm, syrm_design):
    report, plan = syrm_design, syrm_design.plan
    ident = report.identifiability
    assert report.ok and ident.rank == len(SYRM_NAMES) and ident.fit_names == SYRM_NAMES
    assert ident.dead_params == ident.confounded_params == ident.weak_params == ()
    assert all(np.isfinite(ident.predicted_ci95))
    # No magnet: locked steps only (v_q alone turns no reluctance rotor), three levels per axis, two combined.
    assert all(s.locked for s in plan.segments) and len(plan.segments) == 8
    top = SATURATION_TOP_FRACTION * SYRM_LIMIT
    r = float(syrm.R)
    for axis in ("d", "q"):
        steps = [s for s in plan.segments if s.name.startswith(f"locked {axis}-step")]
        other = "v_q" if axis == "d" else "v_d"
        levels = [float(getattr(s, f"v_{axis}")) / r for s in steps]
        assert levels == pytest.approx([f * top for f in SATURATION_LEVELS])
        assert all(float(getattr(s, other)) == 0.0 for s in steps)
    combined = [s for s in plan.segments if s.name.startswith("locked dq-step")]
    assert sorted(np.sign([float(s.v_d) * float(s.v_q) for s in combined])) == [-1.0, 1.0]
    assert all(np.hypot(float(s.v_d), float(s.v_q)) / r == pytest.approx(top) for s in combined)
    # Predicted with the law; the per-unit coupling of Lq and sat_q is judged in the law's own coefficients.
    notes = " ".join(report.notes)
    assert "saturating magnetic law" in notes and "in the law's own coefficients" in notes
    assert report.to_dict()["notes"] == list(report.notes)


def test_syrm_plan_on_the_saturating_bench_stays_under_the_limit(syrm_design, syrm_bench):
    plan = syrm_design.plan
    i_d, i_q, i_dq = _peaks(syrm_bench.currents)
    assert max(i_d, i_q, i_dq) <= plan.current_limit
    # The steps settle at v/R whatever the iron: the top level is 0.8 of the limit, on d, on q and together.
    top = SATURATION_TOP_FRACTION * SYRM_LIMIT
    assert i_d == pytest.approx(top, rel=1e-6) and i_q == pytest.approx(top, rel=1e-6)
    assert i_dq == pytest.approx(top, rel=1e-6)
    # The design's predicted peaks are the saturating machine's (the bench's), segment by segment.
    predicted = [s.peak_current for s in syrm_design.segments]
    assert predicted == pytest.approx(_segment_peaks(plan, syrm_bench.currents), rel=1e-4)


@pytest.mark.slow  # a saturating engine bench run (~10 s) and a compile
def test_saturating_pm_motor_plan_is_predicted_with_its_law_and_stays_under_the_limit():
    law = dc.DEFAULT_MOTOR.replace(**SEED_LAW)
    report = auto_design(law, v_dc=48.0, current_limit=SEED_LIMIT, names=dc.ESTIMATED + MAGNETIC)
    plan = report.plan
    assert report.ok and report.identifiability.rank == len(dc.ESTIMATED + MAGNETIC)
    assert [s.locked for s in plan.segments] == [True] * 8 + [False]  # locked steps first, then the spin-up
    bench = engine_bench(plan, law)
    assert max(_peaks(bench.currents)) <= plan.current_limit
    measured = _segment_peaks(plan, bench.currents)
    assert [s.peak_current for s in report.segments] == pytest.approx(measured, rel=1e-3)
    # The spin-up's peak is the law's, not the small-signal motor's (a few per cent apart here).
    linear = predict_segments(plan, dc.DEFAULT_MOTOR)[-1].peak_current
    assert abs(linear - measured[-1]) > 10 * abs(report.segments[-1].peak_current - measured[-1])
    assert not any("saturation margin" in n for n in report.notes)  # a given law needs no margin


def test_plans_without_saturation_names_are_unchanged():
    """The seed motor's default auto-plan, exactly: the saturation steps leave it alone.

    (Since issue 22 it runs at a real inverter's 10 kHz, not 3.2 kHz, and spins up on a ramp to
    60 % of the no-load speed instead of a voltage step: the expectation was updated then.)
    """
    report = auto_design(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=SEED_LIMIT)
    plan = report.plan
    assert (plan.sample_rate, plan.v_dc, plan.current_limit, plan.max_speed) == (10_000.0, 48.0, 30.0, None)
    assert [(s.name, s.duration, s.locked, float(s.v_d), float(np.ravel(s.v_q)[-1]), s.continues)
            for s in plan.segments] == [
        ("locked d-step", 0.0625, True, 6.75, 0.0, False),
        ("locked q-step", 0.1134, True, 0.0, 6.75, False),
        ("free spin-up", 0.2337, False, 0.0, 16.62768775266122, False),
    ]
    assert report.waveforms == {("free spin-up", "v_q"): {"kind": "ramp", "level": 16.62768775266122,
                                                           "rise": 0.041583816825597704}}


@pytest.mark.slow  # a saturating engine bench run (~10 s) and a compile
def test_linear_motor_keeps_a_margin_for_unknown_saturation():
    """A motor whose spin-up current the inductance holds down: sized for Ld, Lq fallen to half.

    (Before issue 22 its spin-up was a voltage step that surged past the limit with the inductances fallen,
    and the note said by how much it was scaled down; the spin-up ramp keeps the acceleration current near a
    locked step's, so the note now states the margin it holds without scaling: the expectation was updated.)
    """
    motor = dc.DEFAULT_MOTOR.replace(Ld=3.2e-2, Lq=5.8e-2, J=2.4e-4)
    report = auto_design(motor, v_dc=48.0, current_limit=SEED_LIMIT)
    assert report.ok
    note = [n for n in report.notes if n.startswith("saturation margin")]
    assert len(note) == 1 and f"{100 * SATURATED_INDUCTANCE_FRACTION:.0f} %" in note[0]
    assert f"under the current limit {SEED_LIMIT:.3g} A" in note[0]
    for fraction in (SATURATED_INDUCTANCE_FRACTION, 0.5 * (1 + SATURATED_INDUCTANCE_FRACTION)):
        fallen = motor.replace(Ld=fraction * float(motor.Ld), Lq=fraction * float(motor.Lq))
        assert max(s.peak_current for s in predict_segments(report.plan, fallen)) <= SEED_LIMIT
    # Run on a bench motor whose secant inductances halve at the limit: still under it.
    saturating = motor.replace(sat_d=1.0, sat_q=1.0, i_ref=SEED_LIMIT)
    assert max(_peaks(engine_bench(report.plan, saturating).currents)) <= SEED_LIMIT


@pytest.mark.slow  # a saturating engine bench run (~10 s) and a compile
def test_plan_cli_with_saturation_names_runs_safely_on_a_saturating_bench(tmp_path, capsys):
    out = tmp_path / "sat.toml"
    estimate = ",".join(dc.ESTIMATED + MAGNETIC)
    assert main(["plan", "--vdc", "48", "--imax", "30", "--estimate", estimate, "--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["assessment"]["identifiable"] and doc["assessment"]["identifiability"]["rank"] == 7
    assert any(n.startswith("saturation margin") for n in doc["assessment"]["notes"])
    plan = dc.load_plan(out)
    assert len(plan.segments) == 9 and plan.segments[-1].name == "free spin-up"
    bench = engine_bench(plan, dc.DEFAULT_MOTOR.replace(**SEED_LAW))  # the motor's law was not known to the plan
    assert max(_peaks(bench.currents)) <= plan.current_limit


def test_with_saturation_steps_adds_what_the_law_needs_before_the_free_segments():
    law = dc.DEFAULT_MOTOR.replace(**SEED_LAW)
    names = dc.ESTIMATED + MAGNETIC
    # The auto-plan with a voltage-step spin-up (as auto-plan made it before issue 22): its ramp spin-up sweeps
    # the currents through many levels on both axes and hides nothing from identify.
    ramped = dc.auto_plan(dc.DEFAULT_MOTOR, v_dc=48.0, current_limit=SEED_LIMIT)
    assert with_saturation_steps(ramped, law, names)[1] == ()
    spin = ramped.segments[-1]
    base = dataclasses.replace(ramped, segments=ramped.segments[:-1] + (dataclasses.replace(spin, v_q=13.36),))
    plan, added = with_saturation_steps(base, law, names)
    # One level per axis before: three more on each; the spin-up already carries d and q current together.
    assert len(added) == 6 and not any("dq" in name for name in added)
    assert [s.locked for s in plan.segments] == [True] * 8 + [False] and plan.segments[-1].name == "free spin-up"
    assert plan.segments[:2] == base.segments[:2] and "locked d-step (saturation)" in added
    assert magnetic_reasons(model_experiment(dc.Experiment.from_plan(plan), law, names), law, names) == {}
    assert with_saturation_steps(plan, law, names) == (plan, ())
    assert with_saturation_steps(base, law, dc.ESTIMATED) == (base, ())


def test_a_motor_without_magnet_cannot_be_planned_for_lambda_m():
    motor = dc.DEFAULT_MOTOR.replace(lambda_m=0.0)
    with pytest.raises(dc.DrivecalError, match="no magnet"):
        dc.auto_plan(motor, v_dc=48.0, current_limit=SEED_LIMIT)


def test_design_reports_the_law_it_predicted_with(syrm, syrm_design):
    report = assess_design(syrm_design.plan, syrm, noise_sigma=0.08, names=SYRM_NAMES)
    assert any("saturating magnetic law" in n for n in report.notes)
    assert report.segments == syrm_design.segments


@pytest.mark.slow  # a plan through the CLI (~15 s)
def test_plan_cli_reads_the_syrm_law_from_its_motor_file(tmp_path, capsys, syrm_design, syrm_bench):
    """`drivecal plan --motor examples/syrm_motor.toml` (Hinkkanen's published law in the file) is the design above.

    So its run on the saturating engine bench is ``syrm_bench``: rank full and never over the current limit.
    """
    out = tmp_path / "syrm_plan.toml"
    motor = Path(__file__).resolve().parents[2] / "examples" / "syrm_motor.toml"
    args = ["plan", "--motor", str(motor), "--vdc", "540", "--imax", str(SYRM_LIMIT), "--estimate", ",".join(SYRM_NAMES)]
    assert main(args + ["--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["assessment"]["identifiable"] and doc["assessment"]["identifiability"]["rank"] == len(SYRM_NAMES)
    assert any("saturating magnetic law" in n for n in doc["assessment"]["notes"])  # the file's law, not a margin
    plan, designed = dc.load_plan(out), syrm_design.plan
    assert [(s.name, s.locked) for s in plan.segments] == [(s.name, s.locked) for s in designed.segments]
    for written, expected in zip(plan.segments, designed.segments):
        assert np.array_equal(written.voltages(plan.sample_rate), expected.voltages(designed.sample_rate))
    assert max(_peaks(syrm_bench.currents)) <= plan.current_limit


@pytest.mark.long
@pytest.mark.slow  # a plan through the CLI and nine segments on the engine (~40 s)
def test_plan_for_the_published_pm_syrm_stays_under_its_limit_on_its_own_law(tmp_path, capsys):
    """The 5.5-kW PM-SyRM of Lelli et al. (ICEM 2024, doi 10.1109/ICEM60801.2024.10700403; its published law in
    ``helpers.blocks``), planned as a user would from its small-signal values alone, on a bench of its real law.

    Its incremental Lq falls from 150 mH to 31 mH at 12 A and its Ld, with the bridge, from 30 mH to 17 mH at
    +/-12 A: the plan identifies drivecal's law (rank full) and never exceeds its current limit.
    """
    motor = lelli_motor_file(tmp_path / "pm_syrm.toml")
    out, names = tmp_path / "plan.toml", dc.ESTIMATED + MAGNETIC
    args = ["plan", "--motor", str(motor), "--vdc", "540", "--imax", "20", "--estimate", ",".join(names)]
    assert main(args + ["--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["assessment"]["identifiable"] and doc["assessment"]["identifiability"]["rank"] == len(names)
    plan = dc.load_plan(out)
    bench = lelli_bench(plan)
    assert max(_peaks(bench.currents)) <= plan.current_limit
    # The locked steps reach their levels (R*i = v at rest, whatever the iron): the law's range is seen.
    assert max(_peaks(bench.currents)[:2]) >= 0.75 * plan.current_limit


@pytest.mark.long
@pytest.mark.slow  # a plan through the CLI (the bridged law's identifiability compiles, ~60 s) and its bench run
def test_plan_for_the_pm_syrm_s_iron_bridge_identifies_it_and_stays_under_its_limit(tmp_path, capsys):
    """The same PM-SyRM planned for its whole law, the iron bridge's four coefficients included, from its motor
    file (``examples/pm_syrm_motor.toml``: Lelli et al.'s published law in a ``[lelli]`` table).

    The bridge saturates asymmetrically in i_d, so the d levels get a negative step: all eleven coefficients
    are identified (rank full), and the plan run on the independent plant never exceeds its current limit.
    """
    motor = Path(__file__).resolve().parents[2] / "examples" / "pm_syrm_motor.toml"
    names = dc.ESTIMATED + MAGNETIC + ("sat_b", "sat_bp", "k_q", "psi_n")
    out = tmp_path / "plan.toml"
    args = ["plan", "--motor", str(motor), "--vdc", "540", "--imax", "20", "--estimate", ",".join(names)]
    assert main(args + ["--json", "--out", str(out)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["assessment"]["identifiable"] and doc["assessment"]["identifiability"]["rank"] == len(names)
    plan = dc.load_plan(out)
    negative = [s for s in plan.segments if s.locked and np.any(np.asarray(s.v_d) < 0.0)]
    assert [s.name for s in negative] == ["locked d-step negative"] and np.all(np.asarray(negative[0].v_q) == 0.0)
    bench = lelli_bench(plan)
    assert max(_peaks(bench.currents)) <= plan.current_limit
    assert float(bench.currents[:, 0].min()) < -0.4 * plan.current_limit  # the bridge is driven both ways
