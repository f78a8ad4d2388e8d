"""One sample period of the dq equations under the held input, and what a fractional delay applies in it.

Classical RK4 with one step per sample period (``_rk4``), the measured speed
at its stages interpolated (``_quadratic``); with a fractional inverter delay
the period is integrated in two sub-intervals, each under the command that
acts in it (``_held``, ``delay_inputs``): exact under the held input, as the
PWM applies it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp

from ._experiment import Experiment, chain_starts
from ._scans import seeded
from ..physics import MotorParams


def _quadratic(speed: Any, u: float) -> Any:
    """Speed at fraction ``u`` of the sample period from ``(w_k, w_k+1/2, w_k+1)`` (quadratic through the three)."""
    if isinstance(u, float) and u in (0.0, 0.5, 1.0):
        return speed[int(2 * u)]
    return (2 * (u - 0.5) * (u - 1) * speed[0] - 4 * u * (u - 1) * speed[1] + 2 * u * (u - 0.5) * speed[2])


def _rk4(f: Any, x: tuple, h: Any, stage_inputs: tuple, loop: bool = False) -> tuple:
    """One classical Runge-Kutta step of length ``h`` for ``dx/dt = f(x, s)`` (x a tuple).

    ``stage_inputs`` is ``(s(t), s(t + h/2), s(t + h))``: what ``f`` reads
    besides the state at the four stages (the middle one twice); None: nothing.
    ``loop`` (static): the four stages as a loop (:func:`_rk4_loop`), the same arithmetic.
    """
    if loop:
        return _rk4_loop(f, x, h, stage_inputs)

    def axpy(k, a):
        return tuple(xi + a * ki for xi, ki in zip(x, k))

    k1 = f(x, stage_inputs[0])
    k2 = f(axpy(k1, 0.5 * h), stage_inputs[1])
    k3 = f(axpy(k2, 0.5 * h), stage_inputs[1])
    k4 = f(axpy(k3, h), stage_inputs[2])
    return tuple(xi + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4))


def _rk4_loop(f: Any, x: tuple, h: Any, stage_inputs: tuple) -> tuple:
    """:func:`_rk4` with its four stages as a ``scan``: one copy of ``f`` in the program, not four.

    The same operations in the same order (stage ``j`` at ``x + a_j k_{j-1}``, ``a = (0, h/2, h/2, h)``;
    the weighted sum ``k1 + 2 k2 + 2 k3 + k4`` accumulated left to right from zero); compiled differently,
    so a result may differ in its last bit or two. XLA:CPU fuses an unrolled step's stages, and their
    forward-mode tangents, into kernels that each recompute the stages before them: the score test's
    Jacobian for dead time on examples/bench.csv compiled to 4.3 MB (3.5 s to compile, 0.73 s to load, 57 ms
    to run) against 0.86 MB (0.6 s, 0.10 s, 29 ms) with the loop.
    """
    xs = tuple(jnp.asarray(xi, dtype=float) for xi in x)
    h = jnp.asarray(h, dtype=float)
    steps = jnp.stack([jnp.zeros_like(h), 0.5 * h, 0.5 * h, h])
    weights = jnp.array([1.0, 2.0, 2.0, 1.0])
    given = stage_inputs[0] is not None
    inputs = (jnp.stack([jnp.asarray(stage_inputs[j], dtype=float) for j in (0, 1, 1, 2)]) if given
              else jnp.zeros(4))

    def stage(carry: tuple, item: tuple) -> tuple:
        k, total = carry
        a, weight, s = item
        k = tuple(jnp.asarray(ki, dtype=float) for ki in f(tuple(xi + a * ki for xi, ki in zip(xs, k)),
                                                          s if given else None))
        return (k, tuple(t + weight * ki for t, ki in zip(total, k))), None

    zeros = seeded(tuple(jnp.zeros_like(xi) for xi in xs), xs)  # differentiated and batched as the state
    (_, total), _ = jax.lax.scan(stage, (zeros, zeros), (steps, weights, inputs))
    return tuple(xi + (h / 6.0) * t for xi, t in zip(xs, total))


def _substeps(advance: Any, x: tuple, pieces: tuple, substeps: int) -> tuple:
    """Integrate a sample period piece by piece, ``substeps`` RK4 steps per piece.

    ``pieces`` is ``((v, a0, b0), ...)``: the input ``v`` acts over the fractions ``[a0, b0)`` of the period;
    ``advance(x, v, a, b)`` takes one RK4 step over ``[a, b)``. One step per piece: unrolled. More (the
    dead-time model's): a ``scan`` over the steps. XLA:CPU fuses an unrolled chain of RK4 stages and their forward-mode tangents
    into kernels it duplicates stage after stage (the dead-time model's Jacobian with 2 x 2 sub-steps: 80 s
    and 8 GB to compile, against 5 s and 1.1 GB as a loop).
    """
    items = [(v, a0 + (b0 - a0) * j / substeps, a0 + (b0 - a0) * (j + 1) / substeps)
             for v, a0, b0 in pieces for j in range(substeps)]
    if substeps == 1:
        for item in items:
            x = advance(tuple(x), *item)
        return tuple(x)
    stacked = jax.tree_util.tree_map(lambda *z: jnp.stack([jnp.asarray(zi, dtype=float) for zi in z]), *items)

    def body(x: tuple, item: tuple) -> tuple:
        return tuple(advance(x, *item)), None

    return jax.lax.scan(body, tuple(x), stacked)[0]


def delay_inputs(motor: MotorParams, experiment: Experiment) -> tuple[Any, Any, Any]:
    """What a fractional delay applies in each sample period: ``(v_after, v_before, fraction)``.

    With the total delay ``motor.delay = base_delay + n + fraction`` (samples;
    ``n`` whole, ``0 <= fraction < 1``), the period ``[t_k, t_k+1)`` applies
    the command of sample ``k - base_delay - n - 1`` (``v_before``, (M, 2) V)
    for its first ``fraction`` and that of ``k - base_delay - n``
    (``v_after``) for the rest. Before a segment's first command acts the
    inverter applies what ``physics.delayed`` applies (0 V from rest, else the
    first command). ``n`` may be negative (an estimate of a delay near zero):
    later commands, held at the segment's last. Traceable in ``motor.delay``;
    its derivative is that of ``fraction`` (the sub-interval lengths).
    """
    extra = motor.delay - experiment.base_delay
    whole = jnp.floor(extra)
    fraction = extra - whole
    v = experiment.voltages
    k = jnp.arange(v.shape[0])
    start = chain_starts(experiment)  # a continuing segment's delayed command comes from the previous one
    first = jax.lax.cummax(jnp.where(start, k, 0))
    last = jax.lax.cummin(jnp.where(jnp.concatenate([start[1:], jnp.ones(1, bool)]), k, v.shape[0] - 1),
                          reverse=True)
    at_rest = ~jnp.any(experiment.initial_state[:, :3] != 0.0, axis=-1)
    pad = jnp.where(at_rest[:, None], 0.0, v[first])

    def shifted(by):
        idx = k - by
        return jnp.where((idx < first)[:, None], pad, v[jnp.clip(idx, first, last)])

    n = whole.astype(int)
    return shifted(n), shifted(n + 1), fraction


def _with_delay(motor: MotorParams, experiment: Experiment) -> tuple[Experiment, Any]:
    """``experiment`` with ``v_after`` as its voltages, and ``(v_before, fraction)`` (:func:`delay_inputs`).

    Unchanged, and None, without a fractional delay (static).
    """
    if not experiment.fractional_delay:
        return experiment, None
    v_after, v_before, fraction = delay_inputs(motor, experiment)
    return dataclasses.replace(experiment, voltages=v_after), (v_before, fraction)


def _held(f_with: Any, x: tuple, dt: Any, v_after: tuple, before: Any, speed: tuple, loop: bool = False) -> tuple:
    """One sample period under the held input: RK4 of ``f_with(v)``, in two sub-intervals with a fractional delay.

    ``before`` is None (``v_after`` acts over the whole period) or
    ``(v_before, fraction)``: ``v_before`` acts for the first ``fraction`` of
    the period, then ``v_after``; each sub-interval is one RK4 step, with
    the speed at its stages interpolated from ``speed = (w(t), w(t + dt/2),
    w(t + dt))`` (or ``(None,) * 3`` where the speed is a state). ``loop``: as :func:`_rk4`.
    """
    if before is None:
        return _rk4(f_with(v_after), x, dt, speed, loop)
    v_before, fraction = before

    def stages(a, b):
        return tuple(None if speed[0] is None else _quadratic(speed, u) for u in (a, 0.5 * (a + b), b))

    x = _rk4(f_with(v_before), x, fraction * dt, stages(0.0, fraction), loop)
    return _rk4(f_with(v_after), x, (1.0 - fraction) * dt, stages(fraction, 1.0), loop)
