"""The physics equals jaxonomy's PMSM block: same trajectories from the same engine."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jaxonomy import DiagramBuilder, LeafSystem, SimulatorOptions, simulate
from jaxonomy.library import Constant
from jaxonomy.library.drives import PMSM

import drivecal as dc


class DrivecalPhysics(LeafSystem):
    """drivecal's dq_derivatives as a Jaxonomy block with PMSM's ports."""

    def __init__(self, motor: dc.MotorParams, locked: bool, x0):
        super().__init__(name="drivecal_pmsm")
        self._motor, self._locked = motor, locked
        self.declare_input_port(name="v_dq")
        self.declare_continuous_state(default_value=jnp.asarray(x0, dtype=float), ode=self._ode)
        self.declare_continuous_state_output(name="state")

    def _ode(self, _time, state, *inputs, **_params):
        return jnp.stack(dc.dq_derivatives(state.continuous_state, inputs[0], self._motor, self._locked))


def _final_state(block, v_dq, t_end):
    builder = DiagramBuilder()
    src = builder.add(Constant(jnp.asarray(v_dq, dtype=float), name="v"))
    builder.add(block)
    builder.connect(src.output_ports[0], block.input_ports[0])
    diagram = builder.build()
    res = simulate(
        diagram, diagram.create_context(), (0.0, t_end),
        options=SimulatorOptions(rtol=1e-11, atol=1e-11, buffer_length=20000),
        recorded_signals={"x": block.output_ports[0]},
    )
    return np.asarray(res.time), np.asarray(res.outputs["x"])


MOTORS = {
    "default": dc.DEFAULT_MOTOR,
    # a surface motor with load torque and very different scales
    "surface, loaded": dc.MotorParams(R=0.08, Ld=2.0e-4, Lq=2.0e-4, lambda_m=0.012, pole_pairs=7.0,
                                      J=3e-5, B=1e-5, T_load=0.02),
}
PARAMS = ("R", "Ld", "Lq", "lambda_m", "pole_pairs", "J", "B", "T_load")


@pytest.mark.parametrize("locked", [False, True], ids=["free", "locked"])
@pytest.mark.parametrize("name", list(MOTORS))
def test_engine_trajectories_match_jaxonomy_pmsm(name, locked):
    """Both blocks on the engine, same input and initial state: same trajectory."""
    motor = MOTORS[name]
    x0 = [1.5, -2.0, 0.0 if locked else 30.0, 0.3]
    v = [3.0, 9.0]
    params = {k: float(getattr(motor, k)) for k in PARAMS}
    t_ref, x_ref = _final_state(PMSM(**params, initial_state=np.asarray(x0), locked=locked, name="pmsm"), v, 0.02)
    t_dc, x_dc = _final_state(DrivecalPhysics(motor, locked, x0), v, 0.02)
    assert x_ref.shape[0] > 20 and t_ref[-1] == t_dc[-1] == 0.02
    # The adaptive steps may differ by rounding, so compare where both land
    # exactly: the end of the run, after hundreds of steps.
    scale = np.maximum(np.abs(x_ref).max(axis=0), 1e-12)
    assert np.max(np.abs(x_dc[-1] - x_ref[-1]) / scale) < 1e-10
    if locked:
        assert np.all(x_ref[:, 2] == 0.0) and np.all(x_dc[:, 2] == 0.0)
    else:
        assert np.ptp(x_ref[:, 2]) > 1.0  # the rotor really turned


_positive = st.floats(min_value=1e-5, max_value=10.0)


@settings(max_examples=60, deadline=None)
@given(
    state=st.lists(st.floats(-100, 100), min_size=4, max_size=4),
    v=st.lists(st.floats(-50, 50), min_size=2, max_size=2),
    values=st.tuples(_positive, _positive, _positive, _positive, st.integers(1, 12), _positive, _positive,
                     st.floats(-5, 5)),
    locked=st.booleans(),
)
def test_derivatives_equal_pmsm_block(state, v, values, locked):
    """dq_derivatives and the PMSM block's ODE agree at random states, inputs and motors."""
    motor = dc.MotorParams(*[float(x) for x in values])
    block = PMSM(locked=locked, name="pmsm")
    block.input_ports[0].fix_value(jnp.asarray(v, dtype=float))
    ctx = block.create_context().with_parameters({k: float(getattr(motor, k)) for k in PARAMS})
    ctx = ctx.with_continuous_state(jnp.asarray(state, dtype=float))
    expected = np.asarray(block.eval_time_derivatives(ctx))
    got = np.asarray(jnp.stack(dc.dq_derivatives(jnp.asarray(state), jnp.asarray(v), motor, locked)))
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9)


def test_stacked_and_tuple_states_agree():
    x = jnp.array([1.0, 2.0, 50.0, 0.1])
    v = jnp.array([5.0, -3.0])
    as_array = jnp.stack(dc.dq_derivatives(x, v, dc.DEFAULT_MOTOR, False))
    as_tuple = jnp.stack(dc.dq_derivatives(tuple(x), tuple(v), dc.DEFAULT_MOTOR, False))
    np.testing.assert_array_equal(as_array, as_tuple)
