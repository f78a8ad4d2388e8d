"""The one Clarke/Park pair of drivecal: phase (abc) <-> rotor frame (dq), amplitude-invariant.

Amplitude-invariant means a balanced set of phase currents of peak I gives
|i_dq| = I. Angles are electrical (rad), measured from phase a to the d axis.
Every function works on numpy and on JAX arrays alike (``xp`` picks the
module; JAX's ``jnp`` by default, so it traces and differentiates) and on any
shape, element-wise.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp

_SQRT3 = math.sqrt(3.0)


def clarke(a: Any, b: Any, c: Any | None = None) -> tuple[Any, Any]:
    """Phase quantities to ``(alpha, beta)``, amplitude-invariant.

    Without ``c`` there is no zero-sequence component: ``c = -a - b``.
    """
    if c is None:
        c = -a - b
    return (2.0 * a - b - c) / 3.0, (b - c) / _SQRT3


def inverse_clarke(alpha: Any, beta: Any) -> tuple[Any, Any, Any]:
    """``(alpha, beta)`` to the three phase quantities ``(a, b, c)`` (no zero sequence)."""
    return alpha, -0.5 * alpha + 0.5 * _SQRT3 * beta, -0.5 * alpha - 0.5 * _SQRT3 * beta


def park(alpha: Any, beta: Any, theta_e: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """``(alpha, beta)`` to the rotor frame ``(d, q)`` at electrical angle ``theta_e`` (rad)."""
    c, s = xp.cos(theta_e), xp.sin(theta_e)
    return alpha * c + beta * s, -alpha * s + beta * c


def inverse_park(d: Any, q: Any, theta_e: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """Rotor frame ``(d, q)`` to ``(alpha, beta)`` at electrical angle ``theta_e`` (rad)."""
    c, s = xp.cos(theta_e), xp.sin(theta_e)
    return d * c - q * s, d * s + q * c


def abc_to_dq(a: Any, b: Any, c: Any | None, theta_e: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """Phase quantities to ``(d, q)``: Clarke then Park (``c=None``: ``c = -a - b``)."""
    return park(*clarke(a, b, c), theta_e, xp)


def dq_to_abc(d: Any, q: Any, theta_e: Any, xp: Any = jnp) -> tuple[Any, Any, Any]:
    """``(d, q)`` to the three phase quantities: inverse Park then inverse Clarke."""
    return inverse_clarke(*inverse_park(d, q, theta_e, xp))
