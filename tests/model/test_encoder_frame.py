"""The encoder offset's rotation (issue 20, item 4): its sign convention, and a zero offset that changes nothing.

Convention: the encoder reads ``theta_enc = theta_e + encoder_offset``; a Park transform at ``theta_enc``
turns rotor-frame quantities by ``-encoder_offset`` (``physics.encoder_frame``), and the model turns a
phase file's voltages back by ``+encoder_offset`` (``physics.rotor_frame``) before its rollout.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

import drivecal as dc
from drivecal.identify import assess_identifiability
from drivecal.model import Experiment, in_rotor_frame, model_experiment, predicted_currents
from drivecal.physics import abc_to_dq, dq_to_abc, encoder_frame, rotor_frame


def test_a_park_transform_at_the_encoders_angle_turns_dq_by_minus_the_offset():
    rng = np.random.default_rng(0)
    d, q, theta, offset = rng.normal(size=(4, 50))
    a, b, c = dq_to_abc(d, q, theta, xp=np)  # the phase quantities of rotor-frame (d, q) at the true angle
    d_enc, q_enc = abc_to_dq(a, b, c, theta + offset, xp=np)  # as a file's Park transform at the encoder's angle
    np.testing.assert_allclose(np.stack(encoder_frame(d, q, offset, xp=np)), np.stack([d_enc, q_enc]), atol=1e-12)
    # Turned back, and the sign: +90 degrees on the encoder puts the d axis where q was, seen from the file.
    np.testing.assert_allclose(np.stack(rotor_frame(d_enc, q_enc, offset, xp=np)), np.stack([d, q]), atol=1e-12)
    np.testing.assert_allclose(encoder_frame(1.0, 0.0, np.pi / 2, xp=np), (0.0, -1.0), atol=1e-15)


def _phase_experiment(plan: dc.Plan) -> Experiment:
    """The plan's experiment as from a phase file: a measured angle (0 rad at every sample)."""
    experiment = Experiment.from_plan(plan)
    return dataclasses.replace(experiment, theta_e=jnp.zeros(experiment.num_samples))


def test_a_zero_offset_gives_back_the_unrotated_model_exactly():
    experiment = _phase_experiment(dc.default_plan())
    names = dc.ESTIMATED + ("encoder_offset",)
    flagged = model_experiment(experiment, dc.DEFAULT_MOTOR, names)
    assert flagged.encoder_offset and not model_experiment(experiment, dc.DEFAULT_MOTOR, dc.ESTIMATED).encoder_offset
    turned = in_rotor_frame(dc.DEFAULT_MOTOR, flagged)
    assert np.array_equal(np.asarray(turned.voltages), np.asarray(experiment.voltages))
    assert np.array_equal(np.asarray(turned.initial_state), np.asarray(experiment.initial_state))
    plain = predicted_currents(dc.DEFAULT_MOTOR, experiment)
    assert np.array_equal(predicted_currents(dc.DEFAULT_MOTOR, flagged), plain)
    # ... and an offset does turn it: 20 degrees move the currents by amperes.
    moved = predicted_currents(dc.DEFAULT_MOTOR.replace(encoder_offset=np.radians(20.0)), flagged)
    assert np.max(np.abs(moved - plain)) > 1.0


def test_a_dq_experiment_never_turns():
    """Without a measured angle (a dq file) the offset is not modelled, whatever the motor says."""
    experiment = Experiment.from_plan(dc.default_plan())
    motor = dc.DEFAULT_MOTOR.replace(encoder_offset=0.3)
    assert not model_experiment(experiment, motor, dc.ESTIMATED + ("encoder_offset",)).encoder_offset


def test_identifiability_says_what_shows_the_offset():
    guess = dc.datasheet_guess(dc.DEFAULT_MOTOR)
    names = dc.ESTIMATED + ("encoder_offset",)
    assert "encoder_offset" in assess_identifiability(_phase_experiment(dc.default_plan()), guess,
                                                      names=names).fit_names
    # Locked steps on a motor without saliency: the offset does not move the currents.
    locked = _phase_experiment(dc.Plan(dc.default_plan().segments[:2]))
    ident = assess_identifiability(locked, guess.replace(Lq=guess.Ld), names=("R", "Ld", "Lq", "encoder_offset"))
    assert ident.dead_params == ("encoder_offset",)
    assert "free segment" in ident.reasons["encoder_offset"] and "saliency" in ident.reasons["encoder_offset"]
