"""The inverter's voltage error: dead time (the only copy of it).

During the dead time of each PWM period neither switch of a leg conducts and
the phase voltage follows the current's freewheeling diode, so every phase
loses about ``v_dead = V_dc * t_dead * f_pwm`` volts in the direction of its
current: ``e_x = -v_dead * sign(i_x)`` for x = a, b, c. drivecal uses a smooth
sign, ``tanh(i_x / i_smooth)``, so the error is differentiable and the
Jacobian of a fit exists; the synthetic bench uses the same law on the engine.
Phase quantities come from dq by the amplitude-invariant inverse Park/Clarke
transforms at the electrical angle ``theta_e`` (``_transforms``), and the
error goes back the same way.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from ._transforms import abc_to_dq, dq_to_abc


def dead_time_error(i_d: Any, i_q: Any, theta_e: Any, v_dead: Any, i_smooth: Any) -> tuple[Any, Any]:
    """Dead-time voltage error in the rotor frame ``(e_d, e_q)`` (V).

    Args:
        i_d, i_q: dq currents (A).
        theta_e: electrical rotor angle (rad).
        v_dead: per-phase voltage lost to dead time (V), >= 0.
        i_smooth: current scale of the smooth sign (A).
    """
    e_a, e_b, e_c = (-v_dead * jnp.tanh(i / i_smooth) for i in dq_to_abc(i_d, i_q, theta_e))
    return abc_to_dq(e_a, e_b, e_c, theta_e)
