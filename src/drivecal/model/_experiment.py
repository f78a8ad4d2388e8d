"""The experiment on the sample grid: what was applied on the bench, as the forward model reads it.

All segments of an experiment are laid end to end in one sample axis of length
M, with a flag marking where each segment starts (the state is reset there to
the segment's initial state), and the segment layout (static,
``Experiment.segments``) the rollout (``_rollout``) follows. A batch of
datasets of one plan shape is one experiment with a leading axis on every
field (:func:`stack_experiments`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._pytree import pytree_dataclass, static_field
from ..physics import MAGNETIC, MotorParams, delayed, rotor_frame
from ..plan import Plan


#: Kinds of segment in ``Experiment.segments``: the rotor is locked; the speed
#: is measured and drives the electrical equations; the speed is simulated; the
#: inverter is off (no current flows, a free rotor coasts on its friction).
SEGMENT_KINDS: tuple[str, ...] = ("locked", "measured", "free", "coast")


@pytree_dataclass
class Experiment:
    """What was applied on the bench, on the sample grid (a pytree of arrays).

    Attributes:
        voltages: applied ``[v_d, v_q]`` (V), shape (M, 2); row k acts on ``[t_k, t_k+1)``.
        locked: 1.0 where the rotor is locked, 0.0 where free, shape (M,).
        segment_start: True on the first sample of each segment, shape (M,).
        initial_state: ``[i_d, i_q, w_m, theta_m]`` (A, A, rad/s, rad) a segment
            starts from, read on its first sample, shape (M, 4).
        sample_period: seconds between samples, scalar.
        speed: measured mechanical speed at the start, middle and end of each
            sample period, ``[w_m(t_k), w_m(t_k + dt/2), w_m(t_k+1)]`` (rad/s),
            shape (M, 3); zero where unused.
        speed_input: 1.0 where the measured speed drives the electrical
            equations (J and B unused), 0.0 where speed is simulated, shape (M,).
        temperature: winding temperature (degC) per sample, NaN where not
            recorded (R is then the stated R), shape (M,).
        theta_e: measured electrical rotor angle (rad) per sample, NaN where
            not measured (dq bench files), shape (M,).
        theta_e_start: electrical angle (rad) at the segment's start: the
            measured one, else 0 (a locked rotor's d axis on phase a), shape (M,).
        dead_time: the applied voltage includes the inverter's dead-time error
            ``inverter.dead_time_error`` of magnitude ``motor.v_dead`` (static:
            a model with it compiles separately).
        phase_offsets: the measured currents include the phase sensors'
            offsets ``offset_a``, ``offset_b``, rotated by the rotor angle (static).
        encoder_offset: the file's dq quantities came from a Park transform at
            a measured angle that reads ``theta_e + motor.encoder_offset``
            (static; a bench file's angle column): the model turns the
            voltages and starting currents into the rotor frame before the
            rollout and the currents back after it (:func:`in_rotor_frame`,
            ``physics.encoder_frame``).
        thermal: some segment recorded a temperature, so R follows it (static;
            without it the rollout skips the per-sample resistance).
        dead_time_substeps: RK4 sub-steps per sample with the dead-time model
            (static): 4 resolve its smooth sign to 3e-7 A of the engine.
        segments: the segment layout (static): ``(start, stop, kind)`` per
            segment, samples ``start:stop``, ``kind`` one of :data:`SEGMENT_KINDS`;
            None when unknown (the rollout is then one scan over all samples).
        carried: the indices (into ``segments``) of the segments that continue the
            previous one (static): their state at the first sample is where the
            previous segment's rollout arrived, not ``initial_state``, and the
            delayed command carries over (:func:`chain_starts`).
        speed_outputs: the indices of the free segments whose measured speed is
            a second measured output (static; its samples in ``speed[:, 0]``):
            the speed is simulated from J, B and the friction, and the fit
            weighs its residuals with ``speed_weight``.
        speed_weight: current noise over speed noise (A per rad/s; one per
            dataset of a stack): the speed residuals times it share the
            currents' scale, so one sigma_hat and one covariance serve both.
        base_delay: the whole samples of inverter delay already applied in
            ``voltages`` (static): row k is the command of sample k - base_delay.
        fractional_delay: the model applies the rest of the motor's ``delay``
            (samples), ``delay - base_delay``, in the rollout (static): within
            each sample period the applied voltage switches from one command
            to the next at that fraction of the period, and both
            sub-intervals are integrated (exact under the held input).
            Switched on by :func:`model_experiment` when the delay is
            estimated or not a whole number.
        linearised_tangents: derivatives of the segment-wise rollout from
            the steps linearised all at once (static; fastest for one motor),
            else by forward mode through the scans (fastest in ``vmap``-ped
            batches of more than a few motors); same values either way.
        saturating: the motor's iron saturates (static): the rollout integrates
            the flux linkages and takes the currents from the law
            (``physics.currents_of_flux``, ``_flux``). Switched on by
            :func:`model_experiment` when a saturation coefficient is estimated or non-zero.
        bridge: the saturating law has a PM-assisted motor's iron bridge or its terms about zero flux
            (static; ``physics.has_bridge``): the rollout evaluates the whole law, else the law about the
            magnet without the bridge (the same currents, with less work). Switched on by
            :func:`model_experiment` when ``sat_b`` is estimated or either is non-zero.
        rolled: the model's repeated steps kept as loops in the program (static): each RK4 step's four
            stages (``_steps._rk4``) and the start flux's Newton steps (``physics.flux_of_currents``). The
            same arithmetic (the results agree to rounding) in a program a fraction of the size, which
            compiles and loads several times faster. The score tests' kernels use it
            (``identify.sensitivity_jacobian(probing=True)``, ``start_saturation_columns``), and
            :func:`model_experiment` switches it on with the dead time and the saturating law.
    """

    voltages: jnp.ndarray
    locked: jnp.ndarray
    segment_start: jnp.ndarray
    initial_state: jnp.ndarray
    sample_period: jnp.ndarray
    speed: jnp.ndarray
    speed_input: jnp.ndarray
    temperature: jnp.ndarray
    theta_e: jnp.ndarray
    theta_e_start: jnp.ndarray
    dead_time: bool = static_field(default=False)
    phase_offsets: bool = static_field(default=False)
    encoder_offset: bool = static_field(default=False)
    thermal: bool = static_field(default=False)
    dead_time_substeps: int = static_field(default=4)
    segments: tuple[tuple[int, int, str], ...] | None = static_field(default=None)
    carried: tuple[int, ...] = static_field(default=())
    speed_outputs: tuple[int, ...] = static_field(default=())
    speed_weight: jnp.ndarray = 1.0
    base_delay: int = static_field(default=0)
    fractional_delay: bool = static_field(default=False)
    linearised_tangents: bool = static_field(default=True)
    saturating: bool = static_field(default=False)
    bridge: bool = static_field(default=False)
    rolled: bool = static_field(default=False)

    @property
    def num_samples(self) -> int:
        """M, the number of sample instants."""
        return int(self.voltages.shape[-2])

    @classmethod
    def from_segments(
        cls,
        voltages: list[np.ndarray],
        locked: list[bool],
        sample_period: float,
        initial_states: list[np.ndarray] | None = None,
        speeds: list[np.ndarray | None] | None = None,
        temperatures: list[np.ndarray | float | None] | None = None,
        angles: list[np.ndarray | None] | None = None,
        delay_samples: float = 0.0,
        host: bool = False,
        continues: list[bool] | None = None,
        inverter_off: list[bool] | None = None,
        speed_output: bool = False,
        speed_weight: float | np.ndarray = 1.0,
    ) -> Experiment:
        """Lay segments end to end.

        Every per-segment array may carry the same leading axes (a stack of
        datasets of one plan shape, e.g. a fleet's benches); the experiment
        then has them on every field, as :func:`stack_experiments` gives.

        Args:
            voltages: per segment, commanded ``[v_d, v_q]`` (V), shape (N_s, 2).
            locked: per segment, whether the rotor is locked.
            sample_period: seconds between samples (one per dataset of a stack).
            initial_states: per segment, the starting state (default: rest).
            speeds: per segment, a measured speed (rad/s, shape (N_s,)) to use
                as an input, or None to simulate the speed from J and B.
            temperatures: per segment, winding temperature (degC): a constant,
                one value per sample, or None (not recorded).
            angles: per segment, the measured electrical angle (rad, shape
                (N_s,)) of a phase bench file, or None.
            delay_samples: PWM/computation delay: the inverter applies command
                k at sample k + delay_samples. The first samples of a segment
                then apply 0 V (from rest) or the first command (a segment
                that starts moving). Its whole samples are applied here
                (``base_delay``); a fraction is the model's (``MotorParams.delay``
                and ``fractional_delay``).
            host: keep the arrays in numpy (a fleet stacks thousands of
                experiments: one transfer for the stack, not one per field and motor).
            continues: per segment, whether it continues the previous one (its state
                and the delayed command carry over; ``Experiment.carried``).
            inverter_off: per segment, whether the inverter's switches are open (kind
                "coast": no current flows; the voltages are not applied).
            speed_output: the measured ``speeds`` of free segments are a second measured
                output, not an input (``speed_outputs``), weighted by ``speed_weight``
                (A per rad/s).
        """
        base = _whole_samples(delay_samples)
        batch = np.shape(voltages[0])[:-2]  # leading axes: one experiment per dataset (see stack_experiments)
        applied, starts, lock, x0, speed, use, temp, theta, theta0 = [], [], [], [], [], [], [], [], []
        layout, at = [], 0
        carried = tuple(s for s in range(1, len(voltages)) if continues is not None and continues[s])
        outputs = tuple(s for s in range(len(voltages))
                        if speed_output and speeds is not None and speeds[s] is not None and not locked[s])
        for s, v in enumerate(voltages):
            n = v.shape[-2]
            measured = speeds is not None and speeds[s] is not None and s not in outputs
            off = inverter_off is not None and inverter_off[s]
            layout.append((at, at + n, "coast" if off else "measured" if measured else "locked" if locked[s] else "free"))
            at += n
            init = np.zeros(4) if initial_states is None else np.asarray(initial_states[s], dtype=float)
            init = np.broadcast_to(init, batch + (4,))
            if off:
                v = np.zeros_like(v)  # switches open: nothing applied
            if s in carried:  # the previous segment's last commands act first
                previous = voltages[s - 1] if inverter_off is None or not inverter_off[s - 1] else 0.0 * voltages[s - 1]
                v_chain = np.concatenate([previous, v], axis=-2)
                applied.append(delayed(v_chain, base)[..., -n:, :])
            else:
                applied.append(delayed(v, base, at_rest=~np.any(init[..., :3] != 0.0, axis=-1)))
            t_s = None if temperatures is None else temperatures[s]
            temp.append(np.full(batch + (n,), np.nan) if t_s is None
                        else np.broadcast_to(np.asarray(t_s, dtype=float), batch + (n,)))
            a_s = None if angles is None else angles[s]
            theta.append(np.full(batch + (n,), np.nan) if a_s is None else np.asarray(a_s, dtype=float))
            # The measured angle at the start, else 0 (also for a dataset of a stack that has none: NaN).
            a0 = 0.0 if a_s is None else np.asarray(a_s, dtype=float)[..., :1]
            if s in carried:  # the angle runs on from the start of the chain of segments
                a0 = theta0[-1][..., :1]
            theta0.append(np.broadcast_to(np.where(np.isfinite(a0), a0, 0.0), batch + (n,)))
            start = np.zeros(n, dtype=bool)
            start[0] = True
            starts.append(np.broadcast_to(start, batch + (n,)))
            lock.append(np.full(batch + (n,), float(locked[s])))
            w = None if speeds is None else speeds[s]
            if w is None:
                speed.append(np.zeros(batch + (n, 3)))
                use.append(np.zeros(batch + (n,)))
            elif s in outputs:  # measured, not used: the model simulates the speed and is compared with it
                speed.append(np.broadcast_to(np.asarray(w, dtype=float)[..., None], batch + (n, 3)))
                use.append(np.zeros(batch + (n,)))
            else:
                w = np.asarray(w, dtype=float)
                speed.append(_speed_at_stages(w))
                use.append(np.ones(batch + (n,)))
                init = np.concatenate([init[..., :2], w[..., :1], init[..., 3:]], axis=-1)
            x0.append(np.broadcast_to(init[..., None, :], batch + (n, 4)))
        xp = np if host else jnp
        return cls(
            voltages=xp.asarray(np.concatenate(applied, axis=-2), dtype=float),
            locked=xp.asarray(np.concatenate(lock, axis=-1)),
            segment_start=xp.asarray(np.concatenate(starts, axis=-1)),
            initial_state=xp.asarray(np.concatenate(x0, axis=-2)),
            sample_period=xp.asarray(np.broadcast_to(np.asarray(sample_period, dtype=float), batch)),
            speed=xp.asarray(np.concatenate(speed, axis=-2)),
            speed_input=xp.asarray(np.concatenate(use, axis=-1)),
            temperature=xp.asarray(np.concatenate(temp, axis=-1)),
            theta_e=xp.asarray(np.concatenate(theta, axis=-1)),
            theta_e_start=xp.asarray(np.concatenate(theta0, axis=-1)),
            thermal=temperatures is not None and any(t is not None for t in temperatures),
            segments=tuple(layout),
            carried=carried,
            speed_outputs=outputs,
            speed_weight=xp.asarray(np.broadcast_to(np.asarray(speed_weight, dtype=float), batch)),
            base_delay=base,
        )

    @classmethod
    def from_plan(cls, plan: Plan, *, delay_samples: float = 0.0) -> Experiment:
        """The experiment a plan commands, every segment starting from rest or continuing the previous one.

        Args:
            plan: the plan (checked for feasibility first).
            delay_samples: PWM/computation delay of the inverter (samples).
        """
        plan.check_feasible()
        return cls.from_segments(
            [seg.voltages(plan.sample_rate) for seg in plan.segments],
            [seg.locked for seg in plan.segments],
            plan.sample_period,
            temperatures=[seg.temperature for seg in plan.segments],
            delay_samples=delay_samples,
            continues=[seg.continues for seg in plan.segments],
            inverter_off=[seg.inverter == "off" for seg in plan.segments],
        )

    @property
    def has_angle(self) -> bool:
        """Some sample carries a measured rotor angle (a phase bench file)."""
        return bool(np.any(np.isfinite(np.asarray(self.theta_e))))



def chain_starts(experiment: Experiment) -> jnp.ndarray:
    """``segment_start`` without the starts of segments that continue the previous one (``carried``), (M,):
    where the model's state is reset, and where a delayed command starts from rest (or the first command)."""
    if not experiment.carried:
        return experiment.segment_start
    mask = np.zeros(experiment.num_samples, dtype=bool)
    for s in experiment.carried:
        mask[experiment.segments[s][0]] = True
    return experiment.segment_start & ~jnp.asarray(mask)


def _whole_samples(delay_samples: float) -> int:
    """The whole samples of a delay (samples) >= 0: ``floor(delay_samples)``."""
    d = float(delay_samples)
    if not np.isfinite(d) or d < 0:
        raise ValueError(f"delay_samples must be a number of samples >= 0, got {delay_samples!r}")
    return int(np.floor(d + 1e-9))


def _speed_at_stages(w: np.ndarray) -> np.ndarray:
    """``[w_k, w_(k+1/2), w_(k+1)]`` (rad/s) from samples ``w`` (..., N): cubic midpoints, shape (..., N, 3).

    Linear interpolation of the speed at the RK4 midpoint costs ~1e-5 A; the
    four-point cubic midpoint brings the forward model back to ~1e-8 A.
    """
    # Linear extrapolation by one sample at the start and two at the end;
    # the values past the last sample are never read back.
    first, last, before = w[..., :1], w[..., -1:], w[..., -2:-1]
    ext = np.concatenate([2 * first - w[..., 1:2], w, 2 * last - before, 3 * last - 2 * before], axis=-1)
    w_mid = (-ext[..., :-3] + 9.0 * ext[..., 1:-2] + 9.0 * ext[..., 2:-1] - ext[..., 3:]) / 16.0
    return np.stack([w, w_mid, ext[..., 2:-1]], axis=-1)



def model_experiment(experiment: Experiment, motor: MotorParams, names: tuple[str, ...]) -> Experiment:
    """``experiment`` with the bench effects the model needs switched on.

    The dead-time term costs in every RK4 stage, phase offsets need the
    rotor angle written out, and a fractional delay two integrations per
    sample, so each is compiled in only when its parameters are estimated or
    set non-zero (the delay: estimated, or not a whole number of samples; a
    whole-sample delay is the experiment's ``base_delay``, see
    :func:`with_experiment_delay`). The encoder offset turns the frame only
    of an experiment with a measured angle (every phase bench file; a dq
    file's ``theta_e`` column is taken, as for the phase offsets, as the angle
    its Park transform used): a dq file without one was turned into dq by the
    drive with an angle the file does not hold. A saturation coefficient estimated
    or non-zero makes the rollout a flux-state one (``saturating``).
    """
    def used(name):
        return name in names or bool(np.any(np.asarray(getattr(motor, name)) != 0.0))

    dead_time = experiment.dead_time or used("v_dead")
    phase_offsets = experiment.phase_offsets or used("offset_a") or used("offset_b")
    encoder = experiment.encoder_offset or (used("encoder_offset") and experiment.has_angle)
    delay = np.asarray(motor.delay)
    fractional = experiment.fractional_delay or "delay" in names or bool(np.any(delay != np.floor(delay)))
    bridge = experiment.bridge or used("sat_b") or used("sat_at_zero")
    saturating = experiment.saturating or bridge or any(used(n) for n in MAGNETIC)
    # The dead time's and the saturating law's RK4 steps as loops (``rolled``): XLA:CPU fuses an unrolled step,
    # and its tangents, into kernels that recompute the stages. examples/inverter_bench.csv (dead time): a cold fit
    # 95 -> 43-45 s, warm 12.7 -> 5.4 s; Hinkkanen's SyRM (saturating), a first fit 20 -> 6.3 s, warm the same
    # (0.56 s). Their numbers within 1e-10 relative; a batch of saturating fits unrolls them again (fitting).
    rolled = experiment.rolled or dead_time or saturating
    if (dead_time, phase_offsets, encoder, fractional, saturating, bridge, rolled) == (
            experiment.dead_time, experiment.phase_offsets, experiment.encoder_offset, experiment.fractional_delay,
            experiment.saturating, experiment.bridge, experiment.rolled):
        return experiment
    return dataclasses.replace(experiment, dead_time=dead_time, phase_offsets=phase_offsets,
                               encoder_offset=encoder, fractional_delay=fractional, saturating=saturating,
                               bridge=bridge, rolled=rolled)


def in_rotor_frame(motor: MotorParams, experiment: Experiment) -> Experiment:
    """``experiment`` as the motor sees it: a phase file's dq inputs turned into the rotor frame (traceable).

    Where ``experiment.encoder_offset`` (static) is set, the applied voltages and the currents a
    segment starts from are turned by ``+motor.encoder_offset`` (``physics.rotor_frame``), and the
    angle at each segment's start becomes the rotor's, ``theta_e_start - encoder_offset`` (the dead
    time acts at it); else ``experiment`` itself. The angle column (``theta_e``) stays the
    encoder's: the phase sensors' offsets reach the file's dq through it.
    """
    if not experiment.encoder_offset:
        return experiment
    offset = jnp.asarray(motor.encoder_offset, dtype=float)
    v_d, v_q = rotor_frame(experiment.voltages[..., 0], experiment.voltages[..., 1], offset)
    i_d, i_q = rotor_frame(experiment.initial_state[..., 0], experiment.initial_state[..., 1], offset)
    return dataclasses.replace(
        experiment,
        voltages=jnp.stack([v_d, v_q], axis=-1),
        initial_state=jnp.concatenate([jnp.stack([i_d, i_q], axis=-1), experiment.initial_state[..., 2:]], axis=-1),
        theta_e_start=experiment.theta_e_start - offset,
    )


def stack_experiments(experiments: list[Experiment]) -> Experiment:
    """One experiment per dataset along a new leading axis (all of the same plan shape).

    The result feeds ``fit_currents`` with a batch of currents, fitting benches
    that each applied their own voltages (or measured their own speed) in one call.
    """
    # Static model switches must agree across the batch: switch on what any one needs.
    flags = {f: any(getattr(e, f) for e in experiments)
             for f in ("dead_time", "phase_offsets", "encoder_offset", "thermal", "fractional_delay", "saturating",
                       "bridge")}
    # The segment layout is shared by the batch; where the datasets' layouts differ, none is used.
    layouts = {e.segments for e in experiments}
    flags["segments"] = layouts.pop() if len(layouts) == 1 else None
    if (len({(e.carried, e.speed_outputs) for e in experiments}) > 1
            or ((experiments[0].carried or experiments[0].speed_outputs) and flags["segments"] is None)):
        raise ValueError("the experiments differ in their segment layout or in which segments continue the previous "
                         "one; stack experiments of one plan shape only.")
    fields = dataclasses.fields(Experiment)
    statics = {f.name: getattr(experiments[0], f.name) for f in fields if f.metadata.get("static", False)}
    # Field by field, stacked on the host, then one transfer per field (the experiments may hold numpy
    # arrays); one Module built for the batch, not one per experiment (~0.1 ms each in a fleet).
    arrays = {f.name: jnp.asarray(np.stack([np.asarray(getattr(e, f.name)) for e in experiments]))
              for f in fields if not f.metadata.get("static", False)}
    return Experiment(**arrays, **{**statics, **flags})


def with_experiment_delay(motor: MotorParams, experiment: Experiment) -> MotorParams:
    """``motor`` whose ``delay`` (samples) agrees with the whole samples ``experiment`` applies.

    A whole-sample delay lives in the experiment (``base_delay``); a motor
    made without one (``delay = 0``) for an experiment that applies one
    would, once its delay is estimated, start from the wrong delay. A whole
    ``motor.delay`` other than ``base_delay`` is therefore replaced by it; a
    fractional one (a total delay the model applies) is kept.
    """
    delay = float(np.asarray(motor.delay).reshape(-1)[0]) if np.size(motor.delay) else 0.0
    if delay == np.floor(delay) and delay != experiment.base_delay:
        return motor.replace(delay=float(experiment.base_delay))
    return motor
