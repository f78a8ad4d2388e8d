"""The inverter's voltage error: dead time (the only copy of it).

During the dead time of each PWM period neither switch of a leg conducts and
the phase voltage follows the current's freewheeling diode, so every phase
loses about ``v_dead = V_dc * t_dead * f_pwm`` volts in the direction of its
current: ``e_x = -v_dead * sign(i_x)`` for x = a, b, c. drivecal uses a smooth
sign, ``tanh(i_x / i_smooth)``, so the error is differentiable and the
Jacobian of a fit exists; the synthetic bench uses the same law on the engine.
Phase quantities come from dq by the amplitude-invariant inverse Park/Clarke
transforms at the electrical angle ``theta_e``, and the error goes back the
same way.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp

_SQRT3_2 = math.sqrt(3.0) / 2.0


def dead_time_error(i_d: Any, i_q: Any, theta_e: Any, v_dead: Any, i_smooth: Any) -> tuple[Any, Any]:
    """Dead-time voltage error in the rotor frame ``(e_d, e_q)`` (V).

    Args:
        i_d, i_q: dq currents (A).
        theta_e: electrical rotor angle (rad).
        v_dead: per-phase voltage lost to dead time (V), >= 0.
        i_smooth: current scale of the smooth sign (A).
    """
    c, s = jnp.cos(theta_e), jnp.sin(theta_e)
    i_alpha = i_d * c - i_q * s
    i_beta = i_d * s + i_q * c
    i_a = i_alpha
    i_b = -0.5 * i_alpha + _SQRT3_2 * i_beta
    i_c = -0.5 * i_alpha - _SQRT3_2 * i_beta
    e_a, e_b, e_c = (-v_dead * jnp.tanh(i / i_smooth) for i in (i_a, i_b, i_c))
    e_alpha = (2.0 * e_a - e_b - e_c) / 3.0
    e_beta = (e_b - e_c) / math.sqrt(3.0)
    return e_alpha * c + e_beta * s, -e_alpha * s + e_beta * c
