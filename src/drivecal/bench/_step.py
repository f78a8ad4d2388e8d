"""The synthetic bench for step plans, fast for many motors: one compiled engine kernel.

:func:`drivecal.engine_bench` builds a fresh Jaxonomy diagram per segment, so
every motor pays the engine's compile (seconds) and its run (milliseconds).
For plans whose segments hold constant voltages or ramps (an auto-plan's steps and spin-up)
this module builds each diagram once — a held constant-or-ramp source, a
``ZeroOrderHold`` and ``jaxonomy.library.drives.PMSM``, as the bench does —
and passes the motor and the voltage as *context parameters*, which the
engine's kernel cache takes as traced arguments: the compile is reused across
motors.

To share one diagram between sample rates, time is counted in sample periods
(``s = t * fs``), an exact change of variables of the PMSM equations::

    L' = L * fs,  lambda_m' = lambda_m * fs,  J' = J * fs^3,  B' = B * fs^2,
    T_load' = T_load * fs,  w_m' = w_m / fs

with R and the pole pairs unchanged; currents and the rotor angle are the same
functions of the sample index. The engine's adaptive solver still integrates
the PMSM block; tests/design/test_autoplan.py checks it against
:func:`drivecal.engine_bench` to the engine's tolerance. Each segment is
simulated over a power-of-two number of samples (one compile per size) and
cut to its length.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from ._engine import ENGINE_ATOL, ENGINE_RTOL, _quiet_jaxonomy
from ..data import BenchData, SegmentData
from .._stats import next_power_of_two
from ..errors import PlanError
from ..physics import MotorParams
from ..plan import Plan, Segment


@functools.lru_cache(maxsize=4)
def _diagram(locked: bool):
    """(diagram, its default context, the PMSM, the source) in sample-period time; built once.

    The source holds ``start + (value - start) * clip(k / n_rise, 0, 1)`` at sample ``k``: a constant
    (``start = value``) or a ramp over ``n_rise`` samples (plan files' ``ramp``), its numbers context
    parameters.
    """
    import jax.numpy as jnp
    from jaxonomy import DiagramBuilder
    from jaxonomy.library import SourceBlock, ZeroOrderHold

    from ._blocks import pmsm_block

    def held(time, value, start, n_rise):
        k = jnp.floor(time + 1e-6)  # the sample whose value the hold takes at t = k
        return start + (value - start) * jnp.clip(k / n_rise, 0.0, 1.0)

    builder = DiagramBuilder()
    source = SourceBlock(held, name="v_dq")
    source.declare_dynamic_parameter("value", jnp.zeros(2))
    source.declare_dynamic_parameter("start", jnp.zeros(2))
    source.declare_dynamic_parameter("n_rise", jnp.asarray(1.0))
    source = builder.add(source)
    hold = builder.add(ZeroOrderHold(1.0, name="pwm_hold"))
    pmsm = builder.add(pmsm_block(MotorParams(), locked=locked, name="pmsm"))
    builder.connect(source.output_ports[0], hold.input_ports[0])
    builder.connect(hold.output_ports[0], pmsm.input_ports[0])
    diagram = builder.build()
    return diagram, diagram.create_context(), pmsm, source


def _source_values(segment: Segment, sample_rate: float) -> tuple[np.ndarray, np.ndarray, float]:
    """``(value, start, n_rise)`` of the held source: the segment's voltages as a constant or as a ramp
    from ``start`` at sample 0 to ``value`` at sample ``n_rise`` (V, V, samples; ``n_rise`` may be fractional)."""
    v = segment.voltages(sample_rate)
    if np.all(v == v[0]):
        return v[0], v[0], 1.0
    slope = v[1] - v[0]
    axis = int(np.argmax(np.abs(slope)))
    if slope[axis] != 0:
        n_rise = float((v[-1, axis] - v[0, axis]) / slope[axis])
        line = v[0] + (v[-1] - v[0]) * np.clip(np.arange(len(v))[:, None] / n_rise, 0.0, 1.0)
        if n_rise > 0 and np.max(np.abs(line - v)) <= 1e-9 * max(float(np.max(np.abs(v))), 1.0):
            return v[-1], v[0], n_rise
    raise PlanError(f"segment '{segment.name}': step_engine_bench needs constant voltages or a ramp; "
                    "use drivecal.engine_bench for other waveforms.")


def _run_segment(segment: Segment, motor: MotorParams, sample_rate: float) -> np.ndarray:
    """States (N, 4) at the segment's samples, in SI units."""
    import jax.numpy as jnp
    from jaxonomy import SimulatorOptions, simulate

    n = segment.num_samples(sample_rate)
    span = next_power_of_two(n, minimum=2)  # simulated samples: a power of two >= n
    diagram, context, pmsm, source = _diagram(bool(segment.locked))
    fs = float(sample_rate)
    scaled = {"R": float(motor.R), "Ld": float(motor.Ld) * fs, "Lq": float(motor.Lq) * fs,
              "lambda_m": float(motor.lambda_m) * fs, "pole_pairs": float(motor.pole_pairs),
              "J": float(motor.J) * fs**3, "B": float(motor.B) * fs**2, "T_load": float(motor.T_load) * fs}
    ctx = context.with_subcontext(pmsm.system_id, context[pmsm.system_id].with_parameters(
        {k: jnp.asarray(v) for k, v in scaled.items()}))
    value, start, n_rise = _source_values(segment, sample_rate)
    ctx = ctx.with_subcontext(source.system_id, ctx[source.system_id].with_parameters(
        {"value": jnp.asarray(value), "start": jnp.asarray(start), "n_rise": jnp.asarray(n_rise)}))
    t_samples = np.arange(n, dtype=float)
    buffer_length = 16 * span + 64
    for _ in range(3):
        options = SimulatorOptions(rtol=ENGINE_RTOL, atol=ENGINE_ATOL, buffer_length=buffer_length)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*recording buffer.*")
            result = simulate(diagram, ctx, (0.0, float(span - 1)), options=options,
                              recorded_signals={"x": pmsm.output_ports[0]})
        t_rec, x_rec = np.asarray(result.time), np.asarray(result.outputs["x"])
        # A sample instant may be recorded twice around the hold's update: take the last.
        idx = np.searchsorted(t_rec, t_samples + 1e-9, side="right") - 1
        found = (idx >= 0) & (np.abs(t_rec[np.clip(idx, 0, None)] - t_samples) <= 1e-9)
        if found.all():
            x = x_rec[idx].copy()
            x[:, 2] *= fs  # back to rad/s
            return x
        buffer_length *= 4
    raise PlanError(f"segment '{segment.name}': the engine did not record every sample instant.")


def step_engine_bench(plan: Plan, motor: MotorParams, *, record_speed: bool = False) -> BenchData:
    """Noise-free bench data of a step plan on the Jaxonomy engine, reusing compiled kernels.

    Same result as :func:`drivecal.engine_bench` (to the engine's tolerance,
    ~1e-9 A) for plans whose segments hold constant ``v_d``, ``v_q`` or ramp
    them (an auto-plan's spin-up); much faster when many motors run plans of
    similar length. It models the motor alone: for the dead time, sensor offsets
    and the other bench effects use :func:`drivecal.engine_bench`.

    Args:
        plan: the experiment; every segment's voltages constant or a ramp (V).
        motor: the true machine (SI units).
        record_speed: also record the mechanical speed ``w_m`` (rad/s).

    Raises:
        PlanError: a segment with another time-varying voltage, or a motor with a dead time.
    """
    plan.check_feasible()
    if float(motor.v_dead) != 0.0:
        raise PlanError(f"step_engine_bench models no dead time (the motor's v_dead is {float(motor.v_dead):g} V); "
                        "use drivecal.engine_bench.")
    _quiet_jaxonomy()
    segments = []
    for seg in plan.segments:
        states = _run_segment(seg, motor, plan.sample_rate)
        segments.append(SegmentData(
            name=seg.name, locked=seg.locked, t=np.arange(states.shape[0]) * (1.0 / plan.sample_rate),
            voltages=seg.voltages(plan.sample_rate), currents=states[:, :2].copy(),
            w_m=states[:, 2].copy() if record_speed else None))
    return BenchData(segments=tuple(segments), sample_rate=plan.sample_rate, source="synthetic bench")
