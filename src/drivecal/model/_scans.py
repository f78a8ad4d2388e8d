"""The scans behind the segment-wise rollout: a plain scan, a scan of an affine step with a constant
linear part, and a scan whose tangents come from the linearised steps (see each docstring).

Each runs ``x_(k+1) = step(params, x_k, u_k)`` over a segment's samples and returns the states
``x_0 .. x_(N-1)``; ``model._rollout`` picks one per segment.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero


def seeded(x0: tuple, *sources: Any) -> tuple:
    """``x0`` with a zero added that depends on every float leaf of ``sources``: the same values (only a
    ``-0.0`` turns ``+0.0``), but a scan started from it has every carry differentiated and batched from the
    start.

    JAX's rules for a scan under ``jvp`` and under ``vmap`` find which carries have tangents, and which are
    batched, by a fixpoint: they go through the loop body again for each round in which a carry turns out to
    depend on the parameters. A state started from the bench's initial values has no tangent until the first
    step, so a forward-mode Jacobian (``jax.jacfwd``: ``vmap`` of ``jvp``) went through every loop body at
    least twice in each rule (the score test's dead-time Jacobian on examples/bench.csv: 1.7 -> 0.3 s to
    trace, the same numbers). A non-finite leaf adds nothing (``where``), so it cannot turn the state into NaN.
    """
    leaves = [jnp.ravel(leaf) for leaf in map(jnp.asarray, jax.tree_util.tree_leaves(sources))
              if jnp.issubdtype(leaf.dtype, jnp.floating)]
    if not leaves:
        return tuple(x0)
    flat = jnp.concatenate(leaves)  # one set of operations for all the leaves (tracing time)
    zero = jnp.sum(0.0 * jnp.where(jnp.isfinite(flat), flat, 0.0))
    return tuple(x + zero for x in x0)


def _scan_states(step: Any, params: Any, x0: tuple, inputs: tuple) -> tuple:
    """States ``x_0 .. x_(N-1)`` of ``x_(k+1) = step(params, x_k, u_k)``, a tuple of (N,) arrays.

    ``x0`` is a tuple of scalars and ``inputs`` a tuple of (N,) arrays (``u_k``
    their k-th entries). The parameter-only work is done by the caller, so
    the loop body is the step's sums of products on scalars.
    """
    def body(x, u):
        return step(params, x, u), x

    return jax.lax.scan(body, seeded(x0, params), inputs)[1]


def _scan_affine_constant(step: Any, params: Any, x0: tuple, inputs: tuple, varying: int = 2) -> tuple:
    """``_scan_states`` of a step affine in the state and the first ``varying`` inputs, the rest constant.

    On a locked rotor (``_constant_linear_part``) the RK4 step of the
    currents is ``x_(k+1) = A x_k + G v_k + g`` with ``v_k`` the applied
    voltages: the speed at the stages, the only other input, is the same at
    every sample. ``A``, ``G`` (the step's derivatives along the state and
    voltage directions: exact, the step being affine in both) and ``g`` (the
    step from zero state and voltage) come from the step at the first sample,
    once per call; the loop body is then a few products per step. The same
    RK4 recurrence, its terms summed in another order (equal to rounding).
    Forward mode through it (``vmap``-ped Jacobian sweeps) differentiates
    these products instead of the four RK4 stages at every step.
    """
    dims = len(x0)
    dtype = inputs[0].dtype
    constant = tuple(u[0] for u in inputs[varying:])

    def step_at(x, v):
        return step(params, x, tuple(v) + constant)

    x_zero = tuple(jnp.zeros((), dtype) for _ in range(dims))
    v_zero = tuple(jnp.zeros((), dtype) for _ in range(varying))

    def unit(j, n):
        return tuple(jnp.ones((), dtype) if i == j else jnp.zeros((), dtype) for i in range(n))

    g = step_at(x_zero, v_zero)
    # a[j][i] = A[i, j], b[j][i] = G[i, j]
    a = [jax.jvp(lambda x: step_at(x, v_zero), (x_zero,), (unit(j, dims),))[1] for j in range(dims)]
    b = [jax.jvp(lambda v: step_at(x_zero, v), (v_zero,), (unit(j, varying),))[1] for j in range(varying)]

    def body(x, v):
        x_next = tuple(g[i] + sum(a[j][i] * x[j] for j in range(dims)) + sum(b[j][i] * v[j] for j in range(varying))
                       for i in range(dims))
        return x_next, x

    return jax.lax.scan(body, seeded(tuple(x0), params), inputs[:varying])[1]


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def _scan_linearised_tangents(step: Any, params: Any, x0: tuple, inputs: tuple) -> tuple:
    """``_scan_states`` whose tangents come from the linearised steps, not through the loop.

    Forward mode through a scan evaluates the step's derivative inside the
    loop; with 4 tangents the loop body moves several kilobytes per step and
    XLA:CPU runs it op by op (~3 us a step). Here the value is the plain scan
    (a small loop XLA compiles whole), and the tangents solve the linearised
    recurrence ``dx_(k+1) = A_k dx_k + b_k``: ``A_k = d step / d x`` and
    ``b_k``, the step's derivative along the parameters' and inputs'
    tangents, are built for every sample at once (vectorised, no loop) at the
    states of the value, then a d x d recurrence runs as another small loop.
    The same derivative as forward mode through the loop (chain rule in
    another order: ~1e-15 relative), ~5x faster for one motor. In large
    ``vmap``-ped batches the arrays of every ``A_k`` and ``b_k`` cost more
    memory traffic than they save: ``Experiment.linearised_tangents`` picks.
    """
    return _scan_states(step, params, x0, inputs)


@functools.partial(_scan_linearised_tangents.defjvp, symbolic_zeros=True)
def _scan_linearised_tangents_jvp(step, primals, tangents):
    params, x0, inputs = primals
    d_params, d_x0, d_inputs = tangents
    xs = _scan_linearised_tangents(step, params, x0, inputs)
    dims = len(x0)
    dx0 = jnp.stack([jnp.zeros(()) if _is_zero(t) else t for t in d_x0])
    if xs[0].shape[0] == 1:
        return xs, tuple(dx0[i:i + 1] for i in range(dims))
    # The step from the last sample leads out of the segment: only x_0 .. x_(N-1) are wanted.
    x_k = tuple(x[:-1] for x in xs)
    u_k = tuple(u[:-1] for u in inputs)
    du_k = tuple(du if _is_zero(du) else du[:-1] for du in d_inputs)

    def step_k(x):
        return step(params, x, u_k)

    # A_k column by column, the unit directions as one vmapped axis: shape (d, d, N-1), A[i, j, k].
    basis = jnp.eye(dims)
    maps = jnp.stack(jax.vmap(lambda e: jax.jvp(step_k, (x_k,), (tuple(jnp.broadcast_to(e[i], x_k[0].shape)
                                                                       for i in range(dims)),))[1])(basis))
    forcing = jnp.stack(_jvp_nonzero(lambda p, u: step(p, x_k, u), (params, u_k), (d_params, du_k), x_k))
    # Fold dx_0 into the first step: the recurrence from zero then gives dx_1 .. dx_(N-1).
    forcing = forcing.at[:, 0].add(maps[:, :, 0] @ dx0)
    dxs = jnp.concatenate([dx0[:, None], _solve_linear_recurrence(maps, forcing)], axis=1)
    return xs, tuple(dxs[i] for i in range(dims))


def _is_zero(tangent: Any) -> bool:
    return isinstance(tangent, SymbolicZero)


def _jvp_nonzero(f: Any, primals: tuple, tangents: tuple, like: tuple) -> tuple:
    """``jax.jvp(f, primals, tangents)[1]`` over the leaves whose tangent is not a symbolic zero.

    Zeros where every tangent is zero (shaped as ``like``).
    """
    leaves, tree = jax.tree_util.tree_flatten(primals)
    d_leaves = jax.tree_util.tree_leaves(tangents, is_leaf=_is_zero)
    active = [i for i, t in enumerate(d_leaves) if not _is_zero(t)]
    if not active:
        return tuple(jnp.zeros_like(x) for x in like)

    def g(*values):
        full = list(leaves)
        for i, v in zip(active, values):
            full[i] = v
        return f(*jax.tree_util.tree_unflatten(tree, full))

    return jax.jvp(g, tuple(leaves[i] for i in active), tuple(d_leaves[i] for i in active))[1]


def _solve_linear_recurrence(maps: jnp.ndarray, offsets: jnp.ndarray) -> jnp.ndarray:
    """``x_1 .. x_K`` of ``x_(k+1) = maps[:, :, k] @ x_k + offsets[:, k]`` from ``x_0 = 0``, shape (d, K).

    ``maps`` (d, d, K), ``offsets`` (d, K). A sequential scan: its body (a
    d x d product) moves well under a kilobyte per step, which XLA:CPU runs as
    one compiled loop; measured faster here than a ``jax.lax.associative_scan``
    of the affine maps (log-depth, but many small operations per level).
    """
    def body(x, step):
        x_next = step[0] @ x + step[1]
        return x_next, x_next

    return jax.lax.scan(body, jnp.zeros(maps.shape[0]), (jnp.moveaxis(maps, 2, 0), offsets.T))[1].T
