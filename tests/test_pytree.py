"""drivecal's pytree dataclasses (in place of equinox's Module): leaves in the order declared, static fields in
the tree's structure, frozen, equal by value."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from drivecal._pytree import pytree_dataclass, static_field


@pytree_dataclass
class _Pair:
    a: object
    b: object = 2.0
    kind: str = static_field(default="plain")


def test_fields_are_leaves_in_order_and_static_fields_are_structure():
    leaves, tree = jax.tree_util.tree_flatten(_Pair(1.0, 3.0, kind="x"))
    assert leaves == [1.0, 3.0]
    assert jax.tree_util.tree_unflatten(tree, [5.0, 6.0]) == _Pair(5.0, 6.0, kind="x")
    assert jax.tree_util.tree_structure(_Pair(1.0)) != jax.tree_util.tree_structure(_Pair(1.0, kind="x"))


def test_traced_through_jit_and_vmap_with_the_static_field_as_python_value():
    @jax.jit
    def f(p):
        assert p.kind == "x"  # a Python string at trace time
        return p.a * p.b

    assert float(f(_Pair(jnp.float64(2.0), 4.0, kind="x"))) == 8.0
    out = jax.vmap(lambda p: dataclasses.replace(p, a=p.a + 1))(_Pair(jnp.arange(3.0), jnp.ones(3)))
    np.testing.assert_array_equal(out.a, [1.0, 2.0, 3.0])


def test_frozen_and_equal_by_value():
    p = _Pair(np.array([1.0, 2.0]))
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.a = 0.0
    assert p == _Pair(jnp.array([1.0, 2.0])) and p != _Pair(np.array([1.0, 2.5]))
    assert p != _Pair(np.array([1.0, 2.0]), kind="x") and p != _Pair(np.array([1.0]))
    assert hash(_Pair(1.0)) == hash(_Pair(1.0)) and {_Pair(1.0): "x"}[_Pair(1.0)] == "x"
