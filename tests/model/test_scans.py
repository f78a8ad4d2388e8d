"""``model._scans.seeded``: a scan's start that JAX's scan rules differentiate and batch from the first step."""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
import numpy as np
from jax._src.interpreters import ad, batching  # the scan rules' fixpoint steps (jax is pinned: 0.9.2)

from drivecal.model._scans import seeded


def _rollout(params, x0):
    """A two-state affine recurrence over 50 steps, the states (50,)."""
    def body(x, u):
        return (params[0] * x[0] + u, params[1] * x[1] + x[0]), x[0] + x[1]

    return jax.lax.scan(body, x0, jnp.linspace(0.0, 1.0, 50))[1]


def test_seeded_start_has_the_same_values():
    params = jnp.array([0.9, np.inf, np.nan])  # a non-finite parameter does not reach the state
    start = (jnp.asarray(1.5), jnp.asarray(-2.0), jnp.asarray(0.0))
    out = seeded(start, params, {"gain": jnp.asarray(3.0), "rows": jnp.ones(4)})
    assert all(float(a) == float(b) for a, b in zip(out, start))
    assert all(np.isfinite(float(a)) for a in out)


def test_forward_mode_jacobian_goes_through_the_loop_body_fewer_times_with_the_same_numbers(monkeypatch):
    """``jax.jacfwd`` (``vmap`` of ``jvp``) of a scan from a constant start differentiates and batches the
    loop body again in each rule's fixpoint; from a seeded start the rules find every carry differentiated
    and batched at once."""
    passes = []

    def counted(rule):
        def call(*args, **kwargs):
            if sys._getframe(1).f_code.co_name in ("_scan_jvp", "_scan_batching_rule"):  # the scan's rules
                passes.append(rule.__name__)
            return rule(*args, **kwargs)
        return call

    for module, name in ((ad, "jvp_jaxpr"), (batching, "batch_jaxpr")):
        monkeypatch.setattr(module, name, counted(getattr(module, name)))
    params = jnp.array([0.95, 0.8])
    x0 = (jnp.asarray(0.2), jnp.asarray(-0.1))
    ref = jax.make_jaxpr(jax.jacfwd(lambda p: _rollout(p, x0)))(params)
    plain, passes[:] = len(passes), []
    got = jax.make_jaxpr(jax.jacfwd(lambda p: _rollout(p, seeded(x0, p))))(params)
    assert plain == 4 and len(passes) == 2, (plain, passes)  # each rule's fixpoint: two rounds, then one
    np.testing.assert_array_equal(jax.core.eval_jaxpr(got.jaxpr, got.consts, params)[0],
                                  jax.core.eval_jaxpr(ref.jaxpr, ref.consts, params)[0])
