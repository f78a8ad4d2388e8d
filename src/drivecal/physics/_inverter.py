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

The PWM ripple. A leg loses its volts at its switching edges, not over the
whole period, and it is the current *at the edge* whose sign decides: the
rising edge of phase x sits at ``(1 - d_x) T/2`` after the carrier peak and the
falling edge symmetrically before the next one, where the phase current is
the sampled (period-mean) current plus and minus the ripple ``r_x``. So
``e_x = -(v_dead/2) (s(i_x + r_x) + s(i_x - r_x))``: a phase whose current sits
within its ripple of zero loses nothing at one edge and gains at the other,
and its error vanishes (a dead zone of half-width ``|r_x|``), as on a real
bridge with a phase near zero current (a locked q step, the start of a
spin-up). ``switching_ripple`` computes ``r_x`` from the period's applied
phase voltages, a center-aligned carrier and the inductances; with ``r = 0`` the law is
``-v_dead * s(i_x)``. ``s`` is the smooth sign above.

With the ripple computed, the smooth sign's width ``i_smooth`` (the motor's
``i_dead``, 10 mA by default) is only what is left: the switches'
capacitance and the sampled current's chatter about an edge. It matters most
where a phase current is held near zero for many periods (the start of a
spin-up from a rotor angle where one phase carries no current: the current is
clamped at the edge of its dead zone). Measured on the switching plant (default
plan at 10 kHz, 48 V, 1 us dead time, one sample of delay; the bias of a
noise-free fit over the standard error at 20 mA noise): the ripple with a 10 mA
width gives R, Ld, Lq, lambda_m, delay within 0.2 SE; the same with 50 mA,
Ld -0.73 and lambda_m +0.35 SE; the plain sign of the mean current with 50 mA,
lambda_m -0.90 and delay -0.99 SE, and with 4 mA lambda_m -4.5 SE.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp

from ._transforms import abc_to_dq, clarke, dq_to_abc, inverse_clarke, inverse_park


def switching_ripple(v_d: Any, v_q: Any, i_d: Any, i_q: Any, theta_e: Any, L_d: Any, L_q: Any, period: Any,
                     v_dead: Any = 0.0, i_smooth: Any = 0.01) -> tuple[Any, Any, Any]:
    """PWM current ripple of each phase at its own rising edge ``(r_a, r_b, r_c)`` (A).

    A center-aligned carrier of period ``T = period`` (s) peaks at the sample
    instant with every leg low; leg y's gate rises at ``(1 - d_y) T/2``, and its
    pole follows ``t_dead`` later when its current is positive (the lower
    diode holds it low until the upper switch closes). Between the peak and
    phase x's rising edge the phase-to-neutral voltages differ from their
    period means ``v_y``; their volt-seconds there are
    ``S_y = T/2 (u_y - 1/3 sum_z u_z) - v_y T/4`` with
    ``u_y = max(0, v_y - v_x - 2 v_dead s_y)`` (``V_dc t_dead = v_dead T``; ``s_y``
    the smooth step ``(1 + tanh(i_y / i_smooth)) / 2``; the ``T/4`` takes phase
    x's duty as 1/2). Through the inductances in the rotor frame they give the
    phase current's deviation from its mean at the edge; the falling edge
    sees the opposite one. A common DC link and the modulation's zero
    sequence (SVPWM or sine) drop out: only voltage differences count.

    Args:
        v_d, v_q: applied voltage over the period (V).
        i_d, i_q: dq currents (A).
        theta_e: electrical rotor angle (rad).
        L_d, L_q: inductances the ripple sees (H).
        period: carrier (= sample) period (s).
        v_dead: per-phase voltage lost to dead time (V).
        i_smooth: current scale of the smooth sign (A).
    """
    # Linear in the volt-seconds: phase x's deviation is row x of inverse_clarke . G . clarke applied to S,
    # with G the rotor frame's inverse inductance turned into the stator (alpha, beta) frame. A common
    # part of S (the neutral) drops out in clarke, so only the u_y above phase x and the means v_y count.
    c, s = jnp.cos(theta_e), jnp.sin(theta_e)
    g_d, g_q = 1.0 / L_d, 1.0 / L_q
    g_aa, g_bb, g_ab = c * c * g_d + s * s * g_q, s * s * g_d + c * c * g_q, c * s * (g_d - g_q)

    def deviation(a: Any, b: Any, cc: Any) -> tuple[Any, Any, Any]:
        alpha, beta = clarke(a, b, cc)
        return inverse_clarke(g_aa * alpha + g_ab * beta, g_ab * alpha + g_bb * beta)

    v = inverse_clarke(*inverse_park(v_d, v_q, theta_e))
    late = [0.5 * (1.0 + jnp.tanh(i / i_smooth)) for i in inverse_clarke(*inverse_park(i_d, i_q, theta_e))]
    mean = deviation(*v)
    out = []
    for x in range(3):
        above = [jnp.maximum(v[y] - v[x] - 2.0 * v_dead * late[y], 0.0) if y != x else jnp.zeros_like(v[x])
                 for y in range(3)]
        out.append(0.5 * period * deviation(*above)[x] - 0.25 * period * mean[x])
    return out[0], out[1], out[2]


def stable_dead_width(i_smooth: Any, v_dead: Any, L_d: Any, L_q: Any, step: Any) -> Any:
    """The smooth sign's width (A) an RK4 step of ``step`` (s) can integrate: ``i_smooth``, at least
    ``v_dead * step / (2 * min(L_d, L_q))``.

    The error's slope ``v_dead / i_smooth`` (V/A) over an inductance is a rate; RK4 is stable while that
    rate times the step stays under about 2.8, and this floor keeps it under 2 with the neutral's 2/3
    (a motor with a small inductance and a large dead-time voltage would otherwise blow up, not fit).
    The default motor at 10 kHz with four sub-steps needs 1.9 mA: the floor does not act there.
    """
    return jnp.maximum(i_smooth, v_dead * step / (2.0 * jnp.minimum(L_d, L_q)))


def dead_time_error(i_d: Any, i_q: Any, theta_e: Any, v_dead: Any, i_smooth: Any,
                    ripple: tuple[Any, Any, Any] | None = None) -> tuple[Any, Any]:
    """Dead-time voltage error in the rotor frame ``(e_d, e_q)`` (V).

    Args:
        i_d, i_q: dq currents (A).
        theta_e: electrical rotor angle (rad).
        v_dead: per-phase voltage lost to dead time (V), >= 0.
        i_smooth: current scale of the smooth sign (A).
        ripple: each phase's PWM ripple at its switching edges (A), from
            :func:`switching_ripple`; None: none (the error follows the
            sign of the mean current).
    """
    i_abc = dq_to_abc(i_d, i_q, theta_e)
    if ripple is None:
        e_abc = [-v_dead * jnp.tanh(i / i_smooth) for i in i_abc]
    else:
        e_abc = [-0.5 * v_dead * (jnp.tanh((i + r) / i_smooth) + jnp.tanh((i - r) / i_smooth))
                 for i, r in zip(i_abc, ripple)]
    return abc_to_dq(e_abc[0], e_abc[1], e_abc[2], theta_e)


def bridge_error(v_d: Any, v_q: Any, i_d: Any, i_q: Any, theta_e: Any, L_d: Any, L_q: Any, period: Any,
                 v_dead: Any, i_smooth: Any, width: Any = None) -> tuple[Any, Any]:
    """The bridge's voltage error ``(e_d, e_q)`` (V): :func:`dead_time_error` with the PWM ripple of
    :func:`switching_ripple` at these currents and this angle, under the commanded ``(v_d, v_q)`` (V)
    over a carrier period ``period`` (s).

    ``width`` (A): the smooth sign's width in the error (``stable_dead_width`` for a fixed-step
    integrator); None: ``i_smooth``. The engine bench and the model both take their error from here.
    """
    ripple = switching_ripple(v_d, v_q, i_d, i_q, theta_e, L_d, L_q, period, v_dead, i_smooth)
    return dead_time_error(i_d, i_q, theta_e, v_dead, i_smooth if width is None else width, ripple)

