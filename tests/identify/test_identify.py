"""Identifiability before fitting."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import drivecal as dc
from drivecal.plan import load_plan


def test_default_plan_identifies_all_four(truth):
    ident = dc.assess_identifiability(dc.Experiment.from_plan(dc.default_plan()), truth)
    assert ident.rank == 4 and ident.identifiable
    assert ident.dead_params == () and ident.confounded_params == () and ident.weak_params == ()
    assert ident.fit_names == dc.ESTIMATED
    assert 1.0 < ident.condition_number < 100.0
    assert all(np.isfinite(ident.predicted_ci95))


def test_locked_q_step_leaves_ld_and_lambda_dead_with_reasons(truth):
    ident = dc.assess_identifiability(dc.Experiment.from_plan(dc.locked_q_step_plan()), truth)
    assert ident.rank == 2 and not ident.identifiable
    assert set(ident.dead_params) == {"Ld", "lambda_m"}
    assert ident.fit_names == ("R", "Lq")
    assert "no free-rotor segment" in ident.reasons["lambda_m"]
    assert "no d-axis excitation" in ident.reasons["Ld"]
    sens = dict(zip(ident.names, ident.sensitivity))
    assert sens["Ld"] == 0.0 and sens["lambda_m"] == 0.0 and sens["R"] > 0 and sens["Lq"] > 0
    assert np.isnan(ident.predicted_ci95[1]) and np.isnan(ident.predicted_ci95[3])


def test_locked_steps_without_spin_up_lose_lambda_m_only(truth):
    plan = dc.Plan(segments=dc.default_plan().segments[:2])
    ident = dc.assess_identifiability(dc.Experiment.from_plan(plan), truth)
    assert ident.dead_params == ("lambda_m",)
    assert ident.fit_names == ("R", "Ld", "Lq")


def test_predicted_intervals_match_the_realised_ones(truth, default_fit):
    """Predicted at the true motor before any data, the SEs match those of the fit (same sigma)."""
    ident = dc.assess_identifiability(dc.Experiment.from_plan(dc.default_plan()), truth, noise_sigma=0.02)
    ratio = np.asarray(ident.predicted_se) / default_fit.se
    # the fit's SEs use sigma_hat (within ~2 % of sigma for 2800 samples) and the Jacobian at the estimate
    np.testing.assert_allclose(ratio, 1.0, rtol=0.05)


def test_sensitivity_jacobian_shape_and_zero_columns(truth):
    jac = np.asarray(dc.sensitivity_jacobian(truth, dc.Experiment.from_plan(dc.locked_q_step_plan())))
    assert jac.shape == (400, 4)
    assert np.all(jac[:, 1] == 0.0) and np.all(jac[:, 3] == 0.0)


def test_the_score_tests_kernel_has_the_plain_jacobian_s_numbers(truth):
    """``probing=True`` compiles the same Jacobian with other XLA options (PROBE_COMPILER_OPTIONS): the same
    columns up to float64 rounding (a few ulps of the column's scale, accumulated over the rollout's steps)."""
    from drivecal.model import model_experiment

    names = ("R", "Ld", "Lq", "lambda_m", "delay", "offset_d")
    experiment = model_experiment(dc.Experiment.from_plan(dc.locked_q_step_plan()), truth, names)
    plain = np.asarray(dc.sensitivity_jacobian(truth, experiment, names))
    probed = np.asarray(dc.sensitivity_jacobian(truth, experiment, names, probing=True))
    scale = np.abs(plain).max(axis=0)
    assert np.all(scale[[0, 2, 4, 5]] > 0.0)
    assert np.all(np.abs(probed - plain) <= 1e3 * np.finfo(float).eps * scale)


def test_the_offsets_columns_written_down_are_forward_mode_s(truth):
    """The sensors' dq offsets only add to the currents: their columns (``identify.ADDITIVE``) are written down
    beside the other parameters' program, and are exactly forward mode's over the whole model (1 on their
    axis's rows, 0 on the others), with the dead time's rollout too; the other columns are the program's."""
    import jax

    from drivecal.identify import ADDITIVE, jacobian_and_outputs
    from drivecal.model import model_experiment

    names = ("R", "offset_q", "Ld", "Lq", "lambda_m", "v_dead", "offset_d")
    motor = truth.replace(v_dead=0.3, offset_d=0.05, offset_q=-0.02)
    experiment = model_experiment(dc.Experiment.from_plan(dc.default_plan()), motor, names)
    assert experiment.dead_time and set(ADDITIVE) == {"offset_d", "offset_q"}
    jac, outputs = (np.asarray(a) for a in jacobian_and_outputs(motor, experiment, names))
    forward = np.asarray(jax.jit(jax.jacfwd(
        lambda th: dc.predict_currents(motor.with_vector(names, th), experiment).reshape(-1)))(motor.vector(names)))
    assert jac.shape == forward.shape == (2 * experiment.num_samples, len(names))
    for n in ADDITIVE:
        np.testing.assert_array_equal(jac[:, names.index(n)], forward[:, names.index(n)])
    scale = np.abs(forward).max(axis=0)
    assert np.all(np.abs(jac - forward) <= 1e3 * np.finfo(float).eps * scale)
    predicted = np.asarray(jax.jit(dc.predict_currents)(motor, experiment)).reshape(-1)
    np.testing.assert_allclose(outputs, predicted, rtol=0, atol=1e3 * np.finfo(float).eps * np.abs(predicted).max())
    alone = np.asarray(dc.sensitivity_jacobian(motor, experiment, ("offset_d", "offset_q"), probing=True))
    np.testing.assert_array_equal(alone, forward[:, [names.index("offset_d"), names.index("offset_q")]])


def test_identifiability_report_is_jaxterity_s(truth):
    """identify.py repeats jaxterity's identifiability_from_jacobian (importing it loads MuJoCo): same report."""
    import contextlib
    import io

    from drivecal.identify import COND_MAX, identifiability_report

    with contextlib.redirect_stdout(io.StringIO()):
        from jaxterity.sysid.recipes import identifiability_from_jacobian

    rng = np.random.default_rng(0)
    jacs = [np.asarray(dc.sensitivity_jacobian(truth, dc.Experiment.from_plan(p)))
            for p in (dc.default_plan(), dc.locked_q_step_plan())]
    base = rng.normal(size=(300, 3))
    jacs += [rng.normal(size=(200, 4)) * [1e-3, 1.0, 1e2, 1e-6],  # full rank, badly scaled
             np.column_stack([base, base[:, 0] + 1e-5 * rng.normal(size=300)]),  # nearly confounded: weak
             np.column_stack([base, np.zeros(300)])]  # a dead column
    for jac in jacs:
        names = ("R", "Ld", "Lq", "lambda_m")[: jac.shape[1]]
        ours = identifiability_report(jac, names)
        theirs = identifiability_from_jacobian(jac, names=names, cond_max=COND_MAX)
        assert ours.singular_values == theirs.singular_values and ours.rank == theirs.rank
        assert ours.condition_number == theirs.condition_number and ours.identifiable == theirs.identifiable
        assert ours.weak_params == theirs.weak_params


def test_dead_time_that_looks_like_r_is_named_with_the_segment_that_would_separate_it(truth):
    """Issue 17: identifiability says when the plan cannot tell dead time from R, and what segment would."""
    from drivecal.identify import assess_identifiability
    from drivecal.model import Experiment

    motor = truth.replace(v_dead=0.48, i_dead=0.05)
    names = dc.ESTIMATED + ("v_dead",)
    steps = dc.default_plan().segments[:2]  # locked d- and q-steps: every phase current keeps its sign
    idf = assess_identifiability(Experiment.from_plan(dc.Plan(steps)), motor, names=names)
    assert {"R", "v_dead"} <= set(idf.weak_params)
    for name in ("R", "v_dead"):
        assert "no phase current reverses within a segment" in idf.reasons[name], idf.reasons[name]
        assert "free spin-up" in idf.reasons[name] and "changes sign" in idf.reasons[name]
    # The segment it names separates them: a locked d-axis square wave (8 V, reversing every 2.5 ms).
    square = np.where((np.arange(200) // 50) % 2 == 0, 8.0, -8.0)
    reversing = dc.Plan((dc.Segment("locked d square wave", 0.010, locked=True, v_d=square, v_q=0.0), steps[1]))
    idf = assess_identifiability(Experiment.from_plan(reversing), motor, names=names)
    assert not {"R", "v_dead"} & set(idf.weak_params), idf.reasons
    assert idf.predicted_ci95[names.index("v_dead")] < 0.05 * 0.48
    # The default plan (its spin-up reverses every phase current) needs no advice.
    idf = assess_identifiability(Experiment.from_plan(dc.default_plan()), motor, names=names)
    assert idf.identifiable and not any("dead time" in r for r in idf.reasons.values())


def test_the_one_line_verdict_names_what_is_at_fault(truth):
    """One line for every command: identifiable; NOT identifiable naming the dead; weakly naming the weak."""
    good = dc.assess_identifiability(dc.Experiment.from_plan(dc.default_plan()), truth)
    assert good.verdict() == ("identifiable", "green")
    assert good.summary() == f"rank 4/4, condition number {good.condition_number:.3g} -> identifiable"
    poor = dc.assess_identifiability(dc.Experiment.from_plan(dc.locked_q_step_plan()), truth)
    assert poor.verdict() == ("NOT identifiable: Ld, lambda_m", "red")
    assert poor.summary(markup=True).endswith("-> [red]NOT identifiable: Ld, lambda_m[/red]")
    close = load_plan(Path(__file__).resolve().parents[2] / "examples" / "close_plan.toml")  # hot steps 1 K warmer
    weak = dc.assess_design(close, truth, names=dc.ESTIMATED + ("alpha_R",)).identifiability
    assert weak.rank == 5 and not weak.identifiable
    assert weak.verdict() == ("weakly identifiable: R, alpha_R", "yellow")
