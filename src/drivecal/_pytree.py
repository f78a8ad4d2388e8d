"""Frozen dataclasses that are JAX pytrees: drivecal's motor, experiment and solve results.

What drivecal took from equinox's ``Module`` (a frozen dataclass whose fields are leaves, some marked
static), without importing equinox: ~0.25-0.3 s of every command that runs JAX on a 2-core machine, 15 %
of ``drivecal fit``'s imports (docs/performance.md). Equality is identity, as for any object: compare
fields (``dataclasses.astuple``) or leaves where values matter.
"""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from . import _setup  # noqa: F401  (JAX set up before its first use)

import jax  # noqa: E402

T = TypeVar("T", bound=type)


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is part of the tree's structure, not a leaf: a hashable setting (a bool, an int,
    a tuple) that a compiled program is specialised on. ``kwargs``: as :func:`dataclasses.field`."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: T) -> T:
    """``cls`` as a frozen dataclass and a JAX pytree: every field a leaf, in the order declared, except the
    :func:`static_field` ones."""
    return jax.tree_util.register_dataclass(dataclasses.dataclass(frozen=True, eq=False)(cls))
