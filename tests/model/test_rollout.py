"""The segment-wise rollout equals the one-scan rollout: same RK4 recurrence, computed in another order.

``Experiment.segments`` lets the rollout integrate each segment on its own
(currents only where the speed is known) and, with ``linearised_tangents``,
build the Jacobian from the steps linearised all at once. Both must agree with the
sequential scan over all samples (``segments=None``) to rounding, value and
Jacobian, on every kind of segment and bench effect.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import drivecal as dc
from drivecal.plan import waveforms
from drivecal.model import model_experiment, predict_currents, simulate_states, stack_experiments

FS = 20_000.0
NAMES = dc.ESTIMATED


def _spin_speed(n: int, w_end: float) -> np.ndarray:
    """A smooth measured spin-up (rad/s), shape (n,)."""
    t = np.arange(n) / FS
    return w_end * (1.0 - np.exp(-t / 0.015)) + 3.0


def _chirp_prbs_plan() -> dc.Plan:
    n = 300
    return dc.Plan(
        segments=(
            dc.Segment("locked d-chirp", n / FS, True,
                       v_d=waveforms.chirp(n, FS, amplitude=6.0, f_start=20.0, f_stop=2000.0, offset=1.0)),
            dc.Segment("locked q-prbs", n / FS, True, v_q=waveforms.prbs(n, FS, amplitude=4.0, order=7)),
            dc.Segment("free chirp", 0.02, False, v_d=waveforms.chirp(400, FS, amplitude=2.0, f_start=50.0,
                                                                        f_stop=500.0),
                       v_q=12.0),
        ),
        sample_rate=FS,
    )


def _measured() -> dc.Experiment:
    """Locked steps, then a free segment driven by a measured speed, starting with current and speed."""
    n = 400
    volts = [np.tile([8.0, 0.0], (120, 1)), np.tile([0.0, 8.0], (130, 1)),
             np.stack([waveforms.chirp(n, FS, amplitude=3.0, f_start=30.0, f_stop=900.0), np.full(n, 12.0)], 1)]
    w = _spin_speed(n, 250.0)
    return dc.Experiment.from_segments(volts, [True, True, False], 1.0 / FS,
                                       initial_states=[np.zeros(4), np.zeros(4), [0.5, 2.0, w[0], 0.1]],
                                       speeds=[None, None, w])


def _cases() -> dict[str, tuple[dc.MotorParams, dc.Experiment, int]]:
    """``(motor, experiment, keep)`` per case; keep 4 writes out the rotor angle (phase offsets need it)."""
    motor = dc.DEFAULT_MOTOR
    chirp = _chirp_prbs_plan()
    thermal = dataclasses.replace(chirp, segments=(
        dataclasses.replace(chirp.segments[0], temperature=60.0), chirp.segments[1],
        dataclasses.replace(chirp.segments[2], temperature=85.0)))
    # A one-sample segment (no step inside it), then short ones.
    short = dc.Experiment.from_segments([np.array([[8.0, 0.0]]), np.tile([0.0, 8.0], (40, 1)),
                                         np.tile([2.0, 12.0], (60, 1))], [True, True, False], 1.0 / FS)
    return {
        "default plan": (motor, dc.Experiment.from_plan(dc.default_plan()), 3),
        "chirp and PRBS, thermal": (motor, dc.Experiment.from_plan(thermal), 2),
        "measured speed": (motor, _measured(), 4),
        "one-sample segment": (motor, short, 4),
    }


CASES = _cases()


@functools.partial(jax.jit, static_argnames=("keep",))
def _states_and_jacobian(theta, motor, experiment, keep):
    def states(th):
        return simulate_states(motor.with_vector(NAMES, th), experiment, keep)

    return states(theta), jax.jacfwd(states)(theta)


@pytest.mark.parametrize("case", list(CASES))
def test_segmentwise_rollout_equals_one_scan(case):
    motor, experiment, keep = CASES[case]
    assert experiment.segments is not None
    theta = motor.vector(NAMES)
    ref, ref_jac = _states_and_jacobian(theta, motor, dataclasses.replace(experiment, segments=None), keep)
    assert np.max(np.abs(np.asarray(ref[:, :2]))) > 1.0  # currents of amperes flow
    for linearised in (True, False):
        states, jac = _states_and_jacobian(theta, motor,
                                           dataclasses.replace(experiment, linearised_tangents=linearised), keep)
        np.testing.assert_allclose(states, ref, rtol=0, atol=1e-10)
        # d state / d ln(theta): every column in the state's own unit
        np.testing.assert_allclose(jac * theta, ref_jac * theta, rtol=0, atol=1e-10)


def test_dead_time_stays_on_the_one_scan():
    """The dead-time model couples the currents to the angle: the rollout is the sequential scan."""
    motor = dc.DEFAULT_MOTOR.replace(v_dead=0.3)
    experiment = model_experiment(CASES["one-sample segment"][1], motor, ())
    rollout = jax.jit(simulate_states, static_argnums=2)
    np.testing.assert_array_equal(rollout(motor, experiment, 2),
                                  rollout(motor, dataclasses.replace(experiment, segments=None), 2))


def test_layout_from_segments_and_stacking():
    experiment = CASES["measured speed"][1]
    assert experiment.segments == ((0, 120, "locked"), (120, 250, "locked"), (250, 650, "measured"))
    assert CASES["default plan"][1].segments == ((0, 200, "locked"), (200, 400, "locked"), (400, 1400, "free"))
    assert stack_experiments([experiment, experiment]).segments == experiment.segments
    other = dc.Experiment.from_segments([np.zeros((650, 2))], [True], 1.0 / FS)
    assert stack_experiments([experiment, other]).segments is None  # layouts differ: one scan


def test_batched_experiments_equal_one_scan():
    """A vmap over benches with their own measured speeds, both tangent modes, phase offsets on."""
    motor = dc.DEFAULT_MOTOR.replace(offset_a=0.05, offset_b=-0.03)
    first = model_experiment(_measured(), motor, ())
    second = dataclasses.replace(first, speed=first.speed * 0.8,
                                 initial_state=first.initial_state.at[250:, 2].multiply(0.8))
    stacked = stack_experiments([first, second])
    theta = motor.vector(NAMES)

    @jax.jit
    def sweep(experiment):
        def one(exp):
            return jax.jacfwd(lambda th: predict_currents(motor.with_vector(NAMES, th), exp))(theta)

        return jax.vmap(one)(experiment)

    ref = sweep(dataclasses.replace(stacked, segments=None))
    for linearised in (True, False):
        got = sweep(dataclasses.replace(stacked, linearised_tangents=linearised))
        np.testing.assert_allclose(got * theta, ref * theta, rtol=0, atol=1e-10)
    assert not np.allclose(ref[0], ref[1])


def test_linearised_tangents_differentiate_twice():
    """Forward over forward (the D-optimal design's derivative of the Jacobian by the voltages)."""
    motor, experiment, _ = CASES["one-sample segment"]
    theta = motor.vector(NAMES)

    def jacobian_norm(scale, exp):
        exp = dataclasses.replace(exp, voltages=exp.voltages * scale)
        jac = jax.jacfwd(lambda th: predict_currents(motor.with_vector(NAMES, th), exp))(theta)
        return jnp.sum((jac * theta) ** 2)

    @jax.jit
    def derivative(exp):
        return jax.jvp(lambda s: jacobian_norm(s, exp), (1.0,), (1.0,))

    ref = derivative(dataclasses.replace(experiment, segments=None))
    got = derivative(dataclasses.replace(experiment, linearised_tangents=True))
    np.testing.assert_allclose(got, ref, rtol=1e-10)


def test_locked_segments_from_constant_affine_step():
    """Locked segments in forward mode: ``x_(k+1) = A x_k + G v_k + g`` equals the RK4 scan.

    A locked rotor held at a speed (the dq coupling terms on), from a non-zero
    state, with a chirp voltage; values, the Jacobian and its derivative along
    the voltages (as the D-optimal design takes it).
    """
    n = 250
    volts = [np.stack([waveforms.chirp(n, FS, amplitude=5.0, f_start=20.0, f_stop=1500.0, offset=1.0),
                       np.full(n, -2.0)], 1), np.tile([0.0, 8.0], (90, 1))]
    experiment = dc.Experiment.from_segments(volts, [True, True], 1.0 / FS,
                                             initial_states=[[1.0, -0.5, 40.0, 0.2], np.zeros(4)])
    motor = dc.DEFAULT_MOTOR
    theta = motor.vector(NAMES)
    forward_mode = dataclasses.replace(experiment, linearised_tangents=False)
    ref, ref_jac = _states_and_jacobian(theta, motor, dataclasses.replace(experiment, segments=None), 4)
    states, jac = _states_and_jacobian(theta, motor, forward_mode, 4)
    np.testing.assert_allclose(states, ref, rtol=0, atol=1e-12 * np.max(np.abs(np.asarray(ref))))
    np.testing.assert_allclose(jac * theta, ref_jac * theta, rtol=0,
                               atol=1e-12 * np.max(np.abs(np.asarray(ref_jac * theta))))

    @jax.jit
    def derivative(exp):
        def norm(scale):
            scaled = dataclasses.replace(exp, voltages=exp.voltages * scale)
            j = jax.jacfwd(lambda th: predict_currents(motor.with_vector(NAMES, th), scaled))(theta)
            return jnp.sum((j * theta) ** 2)

        return jax.jvp(norm, (1.0,), (1.0,))

    np.testing.assert_allclose(derivative(forward_mode), derivative(dataclasses.replace(experiment, segments=None)),
                               rtol=1e-11)


def _rolled_cases() -> dict[str, tuple[dc.MotorParams, dc.Experiment, int]]:
    """Every path that takes RK4 steps: the segment-wise scans (locked, measured and simulated speed, thermal),
    the one scan with dead time, a fractional delay (two sub-intervals a period), the saturating flux model."""
    cases = {k: v for k, v in CASES.items() if k != "one-sample segment"}
    short = CASES["one-sample segment"][1]
    dead = dc.DEFAULT_MOTOR.replace(v_dead=0.3)
    # model_experiment rolls a dead-time or saturating model's steps (its kernels' size): unrolled, the reference
    cases["dead time"] = (dead, dataclasses.replace(model_experiment(short, dead, ()), rolled=False), 4)
    late = dc.DEFAULT_MOTOR.replace(delay=0.4)
    cases["fractional delay"] = (late, model_experiment(CASES["default plan"][1], late, ("delay",)), 2)
    iron = dc.DEFAULT_MOTOR.replace(sat_d=0.3, sat_q=1.5, sat_dq=0.5, i_ref=20.0, exp_d=2.0, exp_q=2.0)
    cases["saturating"] = (iron, dataclasses.replace(model_experiment(short, iron, ()), rolled=False), 2)
    return cases


def test_model_experiment_rolls_the_dead_time_and_saturating_models_only():
    """The dead time's and the saturating law's kernels are built with RK4's stages as loops
    (``Experiment.rolled``); a model without either keeps the unrolled steps (the demo's and the base fit's
    numbers)."""
    short = CASES["one-sample segment"][1]
    assert model_experiment(short, dc.DEFAULT_MOTOR.replace(v_dead=0.3), ()).rolled
    assert model_experiment(short, dc.DEFAULT_MOTOR, ("v_dead",)).rolled
    assert model_experiment(short, dc.DEFAULT_MOTOR, ("sat_d", "sat_q")).rolled
    assert not model_experiment(short, dc.DEFAULT_MOTOR, ("delay", "offset_d")).rolled


@pytest.mark.parametrize("case", list(_rolled_cases()))
def test_rolled_steps_give_the_same_states_and_tangents(case):
    """``Experiment.rolled`` (the score tests' kernels: RK4's stages and the start flux's Newton steps as loops)
    does the same arithmetic as the unrolled steps: only the compiled program differs, so the states and their
    forward-mode tangents agree to rounding."""
    motor, experiment, keep = _rolled_cases()[case]
    assert not experiment.rolled
    theta = motor.vector(NAMES)
    ref, ref_jac = _states_and_jacobian(theta, motor, experiment, keep)
    states, jac = _states_and_jacobian(theta, motor, dataclasses.replace(experiment, rolled=True), keep)
    assert np.max(np.abs(np.asarray(ref[:, :2]))) > 1.0
    np.testing.assert_allclose(states, ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jac * theta, ref_jac * theta, rtol=1e-12, atol=1e-12)



def test_the_sequential_step_is_traced_once_per_shape_and_reused_with_the_same_numbers(monkeypatch):
    """``rk4_step`` (the one-scan rollout's step: dead time, sub-steps) is a jitted function: a second program
    traced in the same process traces it no more, and the numbers are those of the step traced inline (XLA
    inlines the call before it optimises)."""
    from drivecal.model import _rollout

    traced = []
    rk4 = _rollout._rk4
    monkeypatch.setattr(_rollout, "_rk4", lambda *args, **kwargs: traced.append(1) or rk4(*args, **kwargs))
    _rollout.rk4_step.clear_cache()  # an earlier test's trace (any dead-time rollout: scalar steps) would serve
    # The dead time's model keeps the one sequential scan.
    plain = dc.Experiment.from_segments([np.tile([7.0, 0.0], (37, 1)), np.tile([1.0, 11.0], (53, 1))],
                                        [True, False], 1.0 / FS)
    experiment = model_experiment(plain, dc.DEFAULT_MOTOR.replace(v_dead=0.4), ("v_dead",))
    motor = dc.DEFAULT_MOTOR.replace(v_dead=0.4)
    jitted = jax.jit(predict_currents)(motor, experiment)
    first = len(traced)
    assert first >= 1
    jax.make_jaxpr(lambda m: predict_currents(m, experiment))(motor)
    assert len(traced) == first  # the next program reuses it
    monkeypatch.setattr(_rollout, "rk4_step", _rollout.rk4_step.__wrapped__)
    inline = jax.jit(lambda m, e: predict_currents(m, e))(motor, experiment)
    assert len(traced) > first
    np.testing.assert_array_equal(np.asarray(jitted), np.asarray(inline))
