"""Frozen dataclasses that are JAX pytrees: drivecal's motor, experiment and solve results.

What drivecal took from equinox's ``Module`` (a frozen dataclass whose fields are leaves, some marked
static), without importing equinox: ~0.25-0.3 s of every command that runs JAX on a 2-core machine, 15 %
of ``drivecal fit``'s imports (docs/performance.md). Two are equal, as two equinox Modules are, when their
trees are (the same class and static fields) and their leaves hold the same values.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from . import _setup  # noqa: F401  (JAX set up before its first use)

import jax  # noqa: E402
import numpy as np  # noqa: E402

T = TypeVar("T", bound=type)


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is part of the tree's structure, not a leaf: a hashable setting (a bool, an int,
    a tuple) that a compiled program is specialised on. ``kwargs``: as :func:`dataclasses.field`."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def _equal(self: Any, other: Any) -> bool:
    """The same tree (class and static fields) with equal leaves (arrays: equal shapes and values)."""
    if type(self) is not type(other):
        return NotImplemented
    leaves, tree = jax.tree_util.tree_flatten(self)
    other_leaves, other_tree = jax.tree_util.tree_flatten(other)
    return tree == other_tree and all(np.array_equal(a, b) for a, b in zip(leaves, other_leaves))


def _hash(self: Any) -> int:
    """The hash of the tree and its leaves (a TypeError where a leaf is an array, as for equinox's Modules)."""
    leaves, tree = jax.tree_util.tree_flatten(self)
    return hash((tree, *leaves))


def pytree_dataclass(cls: T) -> T:
    """``cls`` as a frozen dataclass and a JAX pytree: every field a leaf, in the order declared, except the
    :func:`static_field` ones; equal to another of its class with the same static fields and leaf values."""
    cls = dataclasses.dataclass(frozen=True, eq=False)(cls)
    cls.__eq__, cls.__hash__ = _equal, _hash
    return jax.tree_util.register_dataclass(cls)
