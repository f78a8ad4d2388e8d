"""The synthetic bench: a plan run on the Jaxonomy engine, the independent truth.

Each segment becomes its own small diagram (a rotor-locked and a free PMSM are
different blocks in Jaxonomy): a source that outputs the plan's sample k on
``[t_k, t_k+1)``, a zero-order hold at the sample period, and
``jaxonomy.library.drives.PMSM``. Jaxonomy's adaptive solver integrates it; the
currents are read at exactly ``t_k = k / sample_rate``. drivecal's own RK4
rollout (``drivecal.model``) is never used here, so comparing the two is a real test.
A run's bench is kept on disk beside the compiled kernels and read back by a later
run with the same inputs (below: :func:`_bench_key`).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from ..data import BenchData, SegmentData
from ..errors import PlanError
from ..physics import (MotorParams, bridge_error, coulomb_friction, delayed, encoder_frame, resistance_at,
                       rotor_frame, sensor_offsets)
from ..plan import Plan, Segment
from ._encoder import encoder_readings

#: Engine tolerances: tight enough that the bench is exact to ~1e-9 A.
ENGINE_RTOL = 1e-12
ENGINE_ATOL = 1e-12


def _quiet_jaxonomy() -> None:
    # jaxonomy logs INFO on every simulate(); a bench run is many of them.
    from jaxonomy import logging as jx_logging

    jx_logging.set_log_level(jx_logging.WARNING)
    logging.getLogger("jaxonomy").setLevel(logging.WARNING)


#: A fractional delay is run on a grid this many times finer at most (it must be a whole number of its steps).
MAX_DELAY_SUBDIVISION = 16


def _delay_grid(delay_samples: float) -> tuple[int, int]:
    """``(k, n)``: the engine runs ``k`` steps per sample and the delay is ``n`` of them (``n / k = delay``)."""
    d = float(delay_samples)
    for k in range(1, MAX_DELAY_SUBDIVISION + 1):
        if d >= 0 and abs(d * k - round(d * k)) < 1e-9:
            return k, int(round(d * k))
    raise PlanError(f"delay_samples = {delay_samples!r}: the engine bench applies delays of a whole number of "
                    f"1/k samples (k up to {MAX_DELAY_SUBDIVISION}), e.g. 0, 0.5, 1, 1.5, 2, >= 0")


def _run_segment(segment: Segment, motor: MotorParams, sample_rate: float,
                 delay_samples: float = 0, pwm_rate: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Run one segment on the engine; return sample times (s) and states (N, 4).

    The bench effects of ``motor`` act as on a real bench: R at the segment's
    winding temperature, the inverter's dead-time error fed back from the
    block's currents and angle, the commands applied ``delay_samples`` late,
    Coulomb friction fed back from the block's speed to its load port, the
    commands (in the drive's frame, at its encoder's angle) turned into the
    rotor frame by ``encoder_offset`` (``physics.rotor_frame``).
    A fractional delay (0.5, 1.5: the PWM loads its duty mid-period) runs the
    engine on a grid ``k`` times finer, each command held for ``k`` of its
    steps and applied ``delay * k`` of them late; the states are read back
    at the sample instants. ``pwm_rate`` (Hz; default ``sample_rate``) is the
    PWM carrier's, whose period sets the dead time's switching ripple.
    """
    pwm_rate = sample_rate if pwm_rate is None else pwm_rate
    k, late = _delay_grid(delay_samples)
    if k > 1:
        fine = Segment(segment.name, segment.duration, segment.locked,
                       np.repeat(segment.voltages(sample_rate)[:, 0], k),
                       np.repeat(segment.voltages(sample_rate)[:, 1], k), temperature=segment.temperature)
        t, states = _run_segment(fine, motor, sample_rate * k, late, pwm_rate=sample_rate)
        return t[::k], states[::k]
    warm = motor
    if segment.temperature is not None:
        warm = motor.replace(R=float(resistance_at(motor, float(segment.temperature))))
    dead = None
    if float(motor.v_dead) != 0.0:
        dead = (float(motor.pole_pairs), float(motor.v_dead), float(motor.i_dead), 1.0 / float(pwm_rate))
    commands = segment.voltages(sample_rate)
    if float(motor.encoder_offset) != 0.0:
        commands = np.stack(rotor_frame(commands[:, 0], commands[:, 1], float(motor.encoder_offset), xp=np), axis=1)
    volts = np.ascontiguousarray(delayed(commands, delay_samples), dtype=float)
    friction = None
    if float(motor.T_coulomb) != 0.0 and not segment.locked:
        friction = (float(motor.T_load), float(motor.T_coulomb), float(motor.w_coulomb))
    setup = _pmsm_setup(tuple((f.name, float(getattr(warm, f.name))) for f in dataclasses.fields(warm)),
                        bool(segment.locked), volts.shape[0], float(sample_rate), dead, friction)
    return _run_on_engine(setup, sample_rate, label=f"segment '{segment.name}'", voltages=volts)


@functools.lru_cache(maxsize=8)
def _pmsm_setup(motor_values: tuple, locked: bool, n: int, sample_rate: float, dead: tuple | None,
                friction: tuple | None = None):
    """The bench diagram of a segment of ``n`` samples on one motor, built once: its voltages are a parameter
    of the diagram's context (``_run_on_engine``), so segments of the same length and kind run on the same
    diagram and so on the engine's one compiled kernel (the default plan's locked d- and q-steps, and the
    demo's second design's q-step: one compilation of the engine for the three, ~0.5 s each; the nine locked
    steps of a PM-SyRM's multi-level plan: 23.5 -> 6.5 s); each run is its own, the same to the bit as on a
    diagram built for its voltages.

    ``motor_values``: ``(name, value)`` of every ``MotorParams`` field;
    ``n``: the number of samples;
    ``dead``: ``(pole_pairs, v_dead, i_dead, pwm_period)`` of the dead-time feedback, or None;
    ``friction``: ``(T_load, T_coulomb, w_coulomb)`` of the load-port feedback, or None.
    """

    from ._blocks import pmsm_block

    block_motor = MotorParams(**dict(motor_values))
    block = pmsm_block(block_motor, locked=locked, name="pmsm", load_port=friction is not None)
    load = None
    if friction is not None:
        t_load, t_coulomb, w_coulomb = friction

        def load(state):
            return t_load + coulomb_friction(state[2], t_coulomb, w_coulomb)

    error = None
    if dead is not None:
        pole_pairs, v_dead, i_dead, pwm_period = dead

        def error(state_and_volts):
            state, v = state_and_volts[:4], state_and_volts[4:]
            theta_e = pole_pairs * state[3]
            return jnp.stack(bridge_error(v[0], v[1], state[0], state[1], theta_e, block_motor.Ld, block_motor.Lq,
                                          pwm_period, v_dead, i_dead))

    return _held_voltage_diagram(block, np.zeros((n, 2)), sample_rate, error, load)


def _held_voltage_diagram(block, voltages: np.ndarray, sample_rate: float, voltage_error=None, load_torque=None):
    """The diagram of ``run_held_voltages``, its context, the block, the number of samples, the source and the hold.

    The source outputs row k of its parameter ``volts`` (shape (N, 2); ``voltages`` in the context made
    here, others set by ``_run_on_engine``) on ``[t_k, t_k+1)``; a zero-order hold at the sample period
    feeds the block. ``load_torque``: optional ``f(state) -> T`` (N*m) fed back to the block's load port
    (input 1).
    """
    from jaxonomy import DiagramBuilder
    from jaxonomy.library import Adder, FeedthroughBlock, Multiplexer, SourceBlock, ZeroOrderHold

    _quiet_jaxonomy()
    volts = jnp.asarray(voltages)
    n = volts.shape[0]
    dt = 1.0 / sample_rate

    def held_sample(time, volts):
        return _held_row(volts, time, sample_rate)

    builder = DiagramBuilder()
    source = builder.add(SourceBlock(held_sample, name="v_dq_samples"))
    source.declare_dynamic_parameter("volts", volts)
    hold = builder.add(ZeroOrderHold(dt, name="pwm_hold"))
    pmsm = builder.add(block)
    builder.connect(source.output_ports[0], hold.input_ports[0])
    if voltage_error is None:
        builder.connect(hold.output_ports[0], pmsm.input_ports[0])
    else:
        error = builder.add(FeedthroughBlock(voltage_error, name="inverter_error"))
        applied = builder.add(Adder(2, name="applied_voltage"))
        sensed = builder.add(Multiplexer(2, name="state_and_held_voltage"))
        builder.connect(pmsm.output_ports[0], sensed.input_ports[0])
        builder.connect(hold.output_ports[0], sensed.input_ports[1])
        builder.connect(sensed.output_ports[0], error.input_ports[0])
        builder.connect(hold.output_ports[0], applied.input_ports[0])
        builder.connect(error.output_ports[0], applied.input_ports[1])
        builder.connect(applied.output_ports[0], pmsm.input_ports[0])
    if load_torque is not None:
        load = builder.add(FeedthroughBlock(load_torque, name="load_torque"))
        builder.connect(pmsm.output_ports[0], load.input_ports[0])
        builder.connect(load.output_ports[0], pmsm.input_ports[1])
    diagram = builder.build()
    return diagram, diagram.create_context(), pmsm, n, source, hold


@functools.partial(jax.jit, static_argnums=(2,))
def _held_row(volts, time, sample_rate: float):
    """Row k of ``volts`` (N, 2) on ``[t_k, t_k+1)``. Jitted: the engine traces its source a dozen times a
    segment, and a jitted function is traced once per shape (0.3 s of a cold demo's engine bench)."""
    # The 1e-6 guards against t_k landing a rounding error below k/fs.
    k = jnp.clip(jnp.floor(time * sample_rate + 1e-6).astype(int), 0, volts.shape[0] - 1)
    return volts[k]


def run_held_voltages(block, voltages: np.ndarray, sample_rate: float, *, label: str = "segment",
                      voltage_error=None):
    """Drive a PMSM block on the engine with per-sample voltages held between samples.

    Args:
        block: a PMSM-like block (input port 0: ``[v_d, v_q]``, output port 0: state).
        voltages: ``[v_d, v_q]`` (V), shape (N, 2); row k acts on ``[t_k, t_k+1)``.
        sample_rate: samples per second (Hz).
        label: names the run in the error message.
        voltage_error: optional ``f(x) -> [e_d, e_q]`` (V) added to the held
            voltage, ``x`` the block's state followed by the held ``[v_d, v_q]``
            (shape (6,)): an inverter's dead time with its PWM ripple, for
            instance; the block's state output does not depend on its input,
            so the loop is not algebraic.

    Returns:
        Sample times ``t_k = k / sample_rate`` (s), shape (N,), and the state at
        each, shape (N, 4) (A, A, rad/s, rad).
    """
    setup = _held_voltage_diagram(block, voltages, sample_rate, voltage_error)
    return _run_on_engine(setup, sample_rate, label=label)


def _run_on_engine(setup, sample_rate: float, *, label: str, voltages: np.ndarray | None = None):
    """``run_held_voltages`` on a built diagram (``_held_voltage_diagram``), with its source's ``voltages``
    (V, shape (N, 2)) where given."""
    from jaxonomy import SimulatorOptions, simulate

    _quiet_jaxonomy()
    diagram, context, pmsm, n, source, hold = setup
    if voltages is not None:
        # The context as a diagram built for these voltages makes it: made afresh from the parameter, and the
        # hold holding their first row from the start (the hold's first value is inferred once, when the diagram's
        # first context is made, and kept by the block: another segment's would act for the solver's first step,
        # ~1e-8 A on a saturating bench).
        source.dynamic_parameters["volts"].set(jnp.asarray(voltages))
        context = diagram.create_context()
        port = hold.output_ports[0]
        context = context.with_subcontext(hold.system_id, context[hold.system_id].with_cached_value(
            port.cache_index, jnp.asarray(voltages[0])))
    dt = 1.0 / sample_rate

    t_samples = np.arange(n) * dt
    # Time-varying inputs make the solver record several points per sample.
    buffer_length = 16 * n + 64
    for _ in range(4):
        options = SimulatorOptions(rtol=ENGINE_RTOL, atol=ENGINE_ATOL, buffer_length=buffer_length)
        with warnings.catch_warnings():
            # A full buffer is detected below (missing sample instants) and retried.
            warnings.filterwarnings("ignore", message=".*recording buffer.*")
            result = simulate(
                diagram, context, (0.0, t_samples[-1]), options=options, recorded_signals={"x": pmsm.output_ports[0]}
            )
        t_rec = np.asarray(result.time)
        x_rec = np.asarray(result.outputs["x"])
        # Some instants are recorded twice around the hold's update; the state is
        # continuous there, so take the last record at each sample time.
        idx = np.searchsorted(t_rec, t_samples + 1e-9 * dt, side="right") - 1
        found = (idx >= 0) & (np.abs(t_rec[np.clip(idx, 0, None)] - t_samples) <= 1e-9 * dt + 1e-15)
        if found.all():
            return t_samples, x_rec[idx]
        # A full buffer is thinned silently: record again with more room.
        buffer_length *= 4
    raise PlanError(f"{label}: the engine did not record every sample instant.")


def engine_bench(plan: Plan, motor: MotorParams, *, record_speed: bool = False,
                 delay_samples: float = 0, encoder_counts: int | None = None) -> BenchData:
    """Noise-free bench data: the plan run on the Jaxonomy engine.

    The bench effects set in ``motor`` are part of the truth: dead time
    (``v_dead``), sensor offsets (``offset_*``, added to the recorded
    currents), R at each segment's ``temperature`` (recorded too), and an
    encoder whose zero is ``encoder_offset`` (rad, electrical) off the d axis:
    the drive works in its encoder's frame, so the plan's voltages are its
    commands there (the motor receives them turned by ``+encoder_offset``),
    the recorded currents are the motor's turned by ``-encoder_offset``
    (``physics.encoder_frame``), and the recorded angle is the encoder's,
    ``theta_e + encoder_offset``. ``to_phase_frame`` of the result with that
    angle is then the phase file the drive would log.

    Args:
        plan: the experiment (checked for feasibility first).
        motor: the true machine, with its inverter and sensors.
        record_speed: also record the mechanical speed ``w_m`` (rad/s) and the
            electrical angle ``theta_e`` (rad), as an encoder would (its
            offset included).
        delay_samples: the inverter's PWM/computation delay (samples; 0.5,
            1.5 where the PWM loads its duty mid-period); the file records the
            commands, as a real inverter log does.
        encoder_counts: record ``w_m`` and ``theta_e`` as an incremental encoder of
            this many counts per revolution does: the angle in whole counts, the
            speed the difference of two counts over one sample
            (:func:`encoder_readings`; implies ``record_speed``). None: exact.
    """
    if encoder_counts is not None:
        exact = engine_bench(plan, motor, record_speed=True, delay_samples=delay_samples)
        return encoder_readings(exact, encoder_counts, float(motor.pole_pairs))
    plan.check_feasible()
    key = _bench_key(plan, motor, record_speed, delay_samples)
    kept = _kept_bench(key)
    if kept is not None:
        return kept
    _quiet_jaxonomy()
    segments = []
    for seg, t, states in _plan_states(plan, motor, delay_samples):
        # The encoder's angle: the phase sensors' offsets reach the drive's dq through it.
        theta_e = float(motor.pole_pairs) * states[:, 3] + float(motor.encoder_offset)
        if any(float(getattr(motor, o)) != 0.0 for o in ("offset_d", "offset_q", "offset_a", "offset_b")):
            d_offset, q_offset = (np.asarray(o) for o in sensor_offsets(theta_e, motor))
        else:  # ideal sensors: exactly the zeros sensor_offsets gives, without its dozen eager JAX ops
            d_offset = q_offset = np.zeros(theta_e.shape)
        i_d, i_q = states[:, 0], states[:, 1]
        if float(motor.encoder_offset) != 0.0:
            i_d, i_q = encoder_frame(i_d, i_q, float(motor.encoder_offset), xp=np)
        n = t.shape[0]
        segments.append(
            SegmentData(
                name=seg.name,
                locked=seg.locked,
                t=t,
                voltages=seg.voltages(plan.sample_rate),
                currents=np.stack([i_d + d_offset, i_q + q_offset], axis=1),
                w_m=states[:, 2].copy() if record_speed else None,
                temperature=None if seg.temperature is None else np.full(n, float(seg.temperature)),
                theta_e=theta_e.copy() if record_speed else None,
                continues=seg.continues,
                inverter_off=seg.inverter == "off",
            )
        )
    bench = BenchData(segments=tuple(segments), sample_rate=plan.sample_rate, source="synthetic bench")
    _keep_bench(key, bench)
    return bench


# --------------------------------------------------------------------------- engine runs kept on disk
# A run of the engine is a pure function of its inputs: the same plan and motor give the same bench to the
# last bit. It is kept beside the compiled kernels (``model.keep_result``), keyed by the inputs, drivecal's
# source and the versions of JAX and Jaxonomy, so a later process with the same inputs (a second `drivecal
# demo`, `simulate` of the same plan) reads it rather than importing Jaxonomy and running the engine
# (~2.5 s of a warm demo). Off with the compilation cache (DRIVECAL_JAX_CACHE=0, as the test suite runs).

#: The kind of kept result, and its format's version (bump when a kept bench changes meaning).
_KEPT_KIND = "engine-benches-v1"


def kept_engine_bench(plan: Plan, motor: MotorParams, *, record_speed: bool = False,
                      delay_samples: float = 0) -> BenchData | None:
    """The bench :func:`engine_bench` kept for these arguments in an earlier run, or None: it would run the engine."""
    return _kept_bench(_bench_key(plan, motor, record_speed, delay_samples))


def _bench_key(plan: Plan, motor: MotorParams, record_speed: bool, delay_samples: float) -> str | None:
    """The key of this engine run's bench; None where nothing is kept (caching off, inputs that do not pickle)."""
    from ..model import lowered_cache_directory

    return None if lowered_cache_directory() is None else _key_of(plan, motor, record_speed, delay_samples)


def _key_of(plan: Plan, motor: MotorParams, record_speed: bool, delay_samples: float) -> str | None:
    """The inputs, pickled (equal inputs pickle alike), with what the engine's run depends on besides, hashed."""
    import pickle

    from ..model import result_key

    try:
        material = pickle.dumps((plan, motor, bool(record_speed), float(delay_samples)), protocol=5)
    except Exception:  # noqa: BLE001  (a plan with a callable in it, say: run the engine)
        return None
    return result_key(_KEPT_KIND, material, libraries=("jaxonomy",))


def _kept_bench(key: str | None) -> BenchData | None:
    """The bench kept under ``key`` by an earlier run; None where there is none or it does not load."""
    import pickle
    import zlib

    from ..model import kept_result

    data = None if key is None else kept_result(_KEPT_KIND, key)
    if data is None:
        return None
    try:
        bench = pickle.loads(zlib.decompress(data))
    except Exception:  # noqa: BLE001  (damaged: run the engine and keep it again)
        return None
    return bench if isinstance(bench, BenchData) else None


def _keep_bench(key: str | None, bench: BenchData) -> None:
    import pickle
    import zlib

    from ..model import keep_result

    if key is not None:
        keep_result(_KEPT_KIND, key, zlib.compress(pickle.dumps(bench, protocol=5), 1))


def _plan_states(plan: Plan, motor: MotorParams, delay_samples: float):
    """``(segment, t, states)`` per segment of ``plan``: the engine's states at the sample instants.

    Segments that continue one another with the inverter on run as one engine run (the state and the
    delayed command carry over), then are split again, each with its own clock from 0. An inverter-off
    segment (a coast-down) starts where the previous run arrived one sample later, its currents zero,
    and its speed comes from ``J dw_m/dt = -B w_m - T_coulomb tanh(w_m / w_coulomb) - T_load`` solved by
    scipy's adaptive Runge-Kutta (not drivecal's model): the block cannot hold its currents at zero.
    """
    fs = plan.sample_rate
    chains: list[list[Segment]] = []
    for seg in plan.segments:
        if seg.continues and seg.inverter == "on" and chains[-1][-1].inverter == "off":
            raise PlanError(f"segment '{seg.name}': the engine bench cannot start the inverter again after an "
                            "inverter-off segment; begin a new segment from rest (continue = false).")
        if seg.continues and seg.inverter == chains[-1][-1].inverter == "on":
            chains[-1].append(seg)
        else:
            chains.append([seg])
    arrived = None  # the state one sample after the previous chain's last
    for k, chain in enumerate(chains):
        counts = [seg.num_samples(fs) for seg in chain]
        follows = k + 1 < len(chains) and chains[k + 1][0].continues
        if chain[0].inverter == "off":
            states = _coast(motor, arrived, sum(counts) + follows, fs)
        else:
            volts = np.concatenate([seg.voltages(fs) for seg in chain] + ([chain[-1].voltages(fs)[-1:]] if follows
                                                                          else []))
            run = Segment(chain[0].name, volts.shape[0] / fs, chain[0].locked, volts[:, 0], volts[:, 1],
                          temperature=chain[0].temperature)
            states = _run_segment(run, motor, fs, delay_samples)[1]
        arrived = states[-1] if follows else None
        at = 0
        for seg, n in zip(chain, counts):
            yield seg, np.arange(n) * (1.0 / fs), states[at:at + n]
            at += n


def _coast(motor: MotorParams, start: np.ndarray, n: int, sample_rate: float) -> np.ndarray:
    """States (n, 4) at the sample instants of a rotor coasting from ``start`` with no current (scipy, rtol 1e-12)."""
    from scipy.integrate import solve_ivp

    def mechanics(_, x):
        torque = float(motor.T_load) + float(coulomb_friction(x[0], float(motor.T_coulomb), float(motor.w_coulomb)))
        return [(-float(motor.B) * x[0] - torque) / float(motor.J), x[0]]

    t = np.arange(n) / sample_rate
    solved = solve_ivp(mechanics, (0.0, t[-1]), [start[2], start[3]], t_eval=t, rtol=1e-12, atol=1e-12,
                       method="DOP853")
    return np.stack([np.zeros(n), np.zeros(n), solved.y[0], solved.y[1]], axis=1)


def synthetic_bench(plan: Plan, motor: MotorParams, *, noise: float = 0.02, seed: int = 1) -> BenchData:
    """Bench data from the engine with seeded Gaussian current-sensor noise.

    Args:
        plan: the experiment.
        motor: the true machine.
        noise: sensor noise standard deviation on i_d and i_q (A).
        seed: seed of the noise generator (numpy ``default_rng``).
    """
    return engine_bench(plan, motor).add_noise(noise, seed)
