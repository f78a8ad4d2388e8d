"""Magnetic saturation: the flux linkages as states and the currents as an algebraic function of them.

A saturating machine is written with the stator flux linkages as its state (rotor dq frame,
amplitude-invariant, SI units)::

    dpsi_d/dt = v_d - R*i_d + w_e*psi_q
    dpsi_q/dt = v_q - R*i_q - w_e*psi_d
    Te = 1.5*pole_pairs*(psi_d*i_q - psi_q*i_d)

and the currents ``(i_d, i_q) = i(psi_d, psi_q)`` from a current-of-flux law. drivecal's law is the
self- and cross-saturation model of Hinkkanen et al. (IEEE Trans. Ind. Appl. 2017, doi
10.1109/TIA.2016.2644624) written about the magnet's operating point: with ``delta = psi_d - lambda_m``
(the flux the stator's own current makes on d), ``x = delta / (Ld * i_ref)`` and
``y = psi_q / (Lq * i_ref)`` (dimensionless),::

    i_d = i_ref * x * (1 + sat_d*|x|**S + sat_dq*sqrt(Lq/Ld)/(V + 2) * |x|**U * |y|**(V + 2))
    i_q = i_ref * y * (1 + sat_q*|y|**T + sat_dq*sqrt(Ld/Lq)/(U + 2) * |x|**(U + 2) * |y|**V)

(``S, T, U, V`` are the motor's ``exp_d, exp_q, exp_dq_d, exp_dq_q``). The currents are the gradient
of one magnetic energy, so the incremental inductance matrix is symmetric (reciprocal), and:

- with ``sat_d = sat_q = sat_dq = 0`` it is the linear motor ``psi_d = Ld*i_d + lambda_m``,
  ``psi_q = Lq*i_q`` exactly (and these equations are then those of ``_motor``);
- at zero current the flux is ``(lambda_m, 0)`` and the incremental inductances are ``Ld`` and ``Lq``
  whatever the saturation: ``Ld``, ``Lq``, ``lambda_m`` keep their small-signal meaning;
- with ``lambda_m = 0`` it is Hinkkanen's synchronous reluctance model with ``a_d0 = 1/Ld``,
  ``a_q0 = 1/Lq`` and the coefficients of :func:`hinkkanen_coefficients`;
- ``sat_d = 1`` means that at ``i_ref`` (as the linear machine would carry it) the d-axis secant
  inductance has halved: the coefficients are per unit of the machine's own linear law.

A PM-assisted motor's iron bridges saturate asymmetrically in ``i_d`` (Lelli, Hinkkanen, Giulii Capponi,
ICEM 2024, doi 10.1109/ICEM60801.2024.10700403): a saturable reluctance in parallel with the magnet's Norton
equivalent, which carries the flux ``psi_n``. With ``u = (psi_d - psi_n) / (Ld * i_ref)``,
``v = psi_q / (Ld * i_ref)`` and ``s**W = (u**2 + k_q*v**2)**(W/2)`` (``W`` is ``exp_b``) it adds::

    b_d = G_b * (psi_d - psi_n),  b_q = k_q * G_b * psi_q,  G_b = (sat_b / Ld) * s**W / (1 + sat_bp * s**W)

and, with ``sat_at_zero = 1``, the self- and cross-saturation terms are written about zero flux as
Hinkkanen's and Lelli's are (``x = psi_d / (Ld * i_ref)``). Either shifts the current at the magnet's flux
and its slope there, so the law takes them back out: with ``f`` the terms above and ``psi0 = (lambda_m, 0)``,::

    i(psi) = f(psi) - f(psi0) - (J_f(psi0) - diag(1/Ld, 1/Lq)) (psi - psi0)

(``J_f(psi0)`` is diagonal: every term is even in ``psi_q``). Zero current is still the flux
``(lambda_m, 0)`` and ``Ld``, ``Lq`` are still the small-signal inductances there; the published PM-SyRM
law is this one exactly (:func:`from_lelli`), and with ``sat_b = 0``, ``sat_at_zero = 0`` the correction
is exactly zero (the law above, to the last bit).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._parameters import BRIDGE, EXPONENTS, MAGNETIC
from ._motor import coulomb_friction

#: Per coefficient, the exponents it uses and the candidate values a fit chooses among (the data's best).
EXPONENT_CANDIDATES: dict[str, tuple[tuple[str, ...], tuple[tuple[float, ...], ...]]] = {
    "sat_d": (("exp_d",), ((1.0,), (2.0,), (3.0,), (4.0,), (5.0,), (6.0,))),
    "sat_q": (("exp_q",), ((1.0,), (2.0,), (3.0,), (4.0,), (5.0,), (6.0,))),
    "sat_dq": (("exp_dq_d", "exp_dq_q"), ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (2.0, 0.0), (0.0, 2.0))),
}


def _any_nonzero(motor: Any, names: tuple[str, ...]) -> bool:
    """Whether any of ``motor``'s fields ``names`` is non-zero anywhere (host-side, any batch shape)."""
    return any(bool(np.any(np.asarray(getattr(motor, n)) != 0.0)) for n in names)


def is_saturating(motor: Any) -> bool:
    """Whether any saturation coefficient of ``motor`` is non-zero (host-side, any batch shape)."""
    return _any_nonzero(motor, MAGNETIC + BRIDGE)


def _power(x: Any, e: Any) -> Any:
    """``x**e`` for ``x >= 0`` with a finite derivative everywhere (``0**0 = 1``; no ``0 * inf`` at x = 0)."""
    positive = x > 0
    safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, jnp.exp(e * jnp.log(safe)), jnp.where(e == 0, 1.0, 0.0))


def _hinkkanen_terms(psi_d: Any, psi_q: Any, motor: Any, centre_d: Any) -> tuple[Any, Any]:
    """The linear part and the self- and cross-saturation terms (A), written about the d flux ``centre_d`` (Wb)."""
    ld, lq, i_ref = motor.Ld, motor.Lq, motor.i_ref
    x = (psi_d - centre_d) / (ld * i_ref)
    y = psi_q / (lq * i_ref)
    ax, ay = jnp.abs(x), jnp.abs(y)
    s, t, u, v = motor.exp_d, motor.exp_q, motor.exp_dq_d, motor.exp_dq_q
    cross = motor.sat_dq
    g_d = 1.0 + motor.sat_d * _power(ax, s) + cross * jnp.sqrt(lq / ld) / (v + 2.0) * _power(ax, u) * _power(ay, v + 2.0)
    g_q = 1.0 + motor.sat_q * _power(ay, t) + cross * jnp.sqrt(ld / lq) / (u + 2.0) * _power(ax, u + 2.0) * _power(ay, v)
    return i_ref * x * g_d, i_ref * y * g_q


def _bridge_terms(psi_d: Any, psi_q: Any, motor: Any) -> tuple[Any, Any]:
    """The iron bridge's currents ``(b_d, b_q)`` (A): exactly zero where ``sat_b = 0``."""
    flux = motor.Ld * motor.i_ref
    bridge = psi_d - motor.psi_n
    u, v = bridge / flux, psi_q / flux
    s_w = _power(u * u + motor.k_q * v * v, 0.5 * motor.exp_b)
    g_b = motor.sat_b / motor.Ld * s_w / (1.0 + motor.sat_bp * s_w)
    return g_b * bridge, motor.k_q * g_b * psi_q


class MagnetPoint(NamedTuple):
    """What the iron bridge and a centre at zero flux add at the magnet's flux ``(lambda_m, 0)``, taken back out
    of the law (:func:`currents_of_flux`): currents (A) and the excess of their slopes over ``1/Ld``, ``1/Lq``
    (1/H). All zero (exactly) where ``sat_b = 0`` and ``sat_at_zero = 0``. Computed once per motor
    (:func:`magnet_point`), outside any time loop."""

    current_d: Any
    current_q: Any
    slope_d: Any
    slope_q: Any


def _at_magnet(terms: Any, motor: Any) -> tuple[Any, Any, Any, Any]:
    """``terms``' currents (A) at the flux ``(lambda_m, 0)`` and their slopes (1/H) there: ``(f_d, f_q, df_d/dpsi_d,
    df_q/dpsi_q)`` (the cross slopes are zero: every term is even in ``psi_q``)."""
    lam = jnp.asarray(motor.lambda_m, dtype=float)
    zero, one = jnp.zeros_like(lam), jnp.ones_like(lam)
    (f_d, f_q), (s_d, s_q) = jax.jvp(terms, (lam, zero), (one, one))
    return f_d, f_q, s_d, s_q


def _centre(motor: Any) -> Any:
    """The d flux (Wb) about which the self- and cross-saturation terms are written: 0 or ``lambda_m``."""
    return jnp.where(jnp.asarray(motor.sat_at_zero) != 0, 0.0, motor.lambda_m)


def magnet_point(motor: Any) -> MagnetPoint:
    """The law's correction at the magnet's flux (:class:`MagnetPoint`) of ``motor`` (traceable)."""
    about_zero = jnp.asarray(motor.sat_at_zero) != 0
    centre = _centre(motor)
    h_d, h_q, h_dd, h_qq = _at_magnet(lambda a, b: _hinkkanen_terms(a, b, motor, centre), motor)
    b_d, b_q, b_dd, b_qq = _at_magnet(lambda a, b: _bridge_terms(a, b, motor), motor)
    zero = jnp.zeros(())
    return MagnetPoint(jnp.where(about_zero, h_d, zero) + b_d, jnp.where(about_zero, h_q, zero) + b_q,
                       jnp.where(about_zero, h_dd - 1.0 / motor.Ld, zero) + b_dd,
                       jnp.where(about_zero, h_qq - 1.0 / motor.Lq, zero) + b_qq)


def has_bridge(motor: Any) -> bool:
    """Whether ``motor``'s law has an iron bridge or its terms about zero flux (host-side, any batch shape): where
    not, :func:`currents_of_flux` with ``bridge=False`` gives the same currents with less work."""
    return _any_nonzero(motor, ("sat_b", "sat_at_zero"))


def currents_of_flux(psi_d: Any, psi_q: Any, motor: Any, bridge: Any = True) -> tuple[Any, Any]:
    """The currents ``(i_d, i_q)`` (A) at the flux linkages ``psi_d``, ``psi_q`` (Wb): the law of the module docstring.

    Any broadcastable shapes; ``motor`` a ``MotorParams`` (traceable in every field; ``sat_at_zero`` and the
    exponents are settings). ``bridge``: True, the whole law; a :class:`MagnetPoint` of ``motor``, the whole law
    with that correction (computed once, outside a time loop); False (static), the law without the bridge and
    about the magnet's flux, which is the whole law where ``not has_bridge(motor)``, with less work.
    """
    if bridge is False:
        return _hinkkanen_terms(psi_d, psi_q, motor, motor.lambda_m)
    at_magnet = magnet_point(motor) if bridge is True else bridge
    i_d, i_q = _hinkkanen_terms(psi_d, psi_q, motor, _centre(motor))
    b_d, b_q = _bridge_terms(psi_d, psi_q, motor)
    return (i_d + b_d - (at_magnet.current_d + at_magnet.slope_d * (psi_d - motor.lambda_m)),
            i_q + b_q - (at_magnet.current_q + at_magnet.slope_q * psi_q))


def _jacobian(psi_d: Any, psi_q: Any, motor: Any, bridge: Any = True) -> tuple[Any, Any, Any, Any]:
    """``d(i_d, i_q) / d(psi_d, psi_q)`` (1/H) at one flux point: ``(dd, dq, qd, qq)``, each of the flux's shape."""
    def along(td, tq):
        return jax.jvp(lambda a, b: currents_of_flux(a, b, motor, bridge), (psi_d, psi_q), (td, tq))[1]

    one, zero = jnp.ones_like(psi_d), jnp.zeros_like(psi_d)
    (dd, qd), (dq, qq) = along(one, zero), along(zero, one)
    return dd, dq, qd, qq


def incremental_inductances(psi_d: Any, psi_q: Any, motor: Any) -> tuple[Any, Any, Any]:
    """The incremental inductances ``(L_dd, L_dq, L_qq)`` (H) at a flux point: the inverse of ``di/dpsi``.

    ``d psi = [[L_dd, L_dq], [L_dq, L_qq]] d i``; ``L_dq`` is the cross-saturation's coupling (0 in a
    linear machine). At zero current they are ``Ld``, 0, ``Lq``.
    """
    dd, dq, qd, qq = _jacobian(psi_d, psi_q, motor)
    det = dd * qq - dq * qd
    return qq / det, -0.5 * (dq + qd) / det, dd / det


def flux_of_currents(i_d: Any, i_q: Any, motor: Any, iterations: int = 12, bridge: Any = True,
                     loop: bool = False) -> tuple[Any, Any]:
    """The flux linkages ``(psi_d, psi_q)`` (Wb) at which the law gives the currents ``i_d``, ``i_q`` (A).

    Newton's method from the linear machine's flux, ``iterations`` steps (unrolled: traceable and
    differentiable; the law is monotone, so it converges to machine precision well within 12 steps at
    currents where the inductance has fallen tenfold). Zero current gives ``(lambda_m, 0)`` exactly.
    ``bridge`` as in :func:`currents_of_flux` (a :class:`MagnetPoint` computed once saves each step's).
    ``loop`` (static): the steps as a ``jax.lax.fori_loop``, the same arithmetic in a program with one
    copy of the step (JAX arrays out).
    """
    if bridge is True:
        bridge = magnet_point(motor)

    def newton(_, psi):
        psi_d, psi_q = psi
        f_d, f_q = currents_of_flux(psi_d, psi_q, motor, bridge)
        r_d, r_q = f_d - i_d, f_q - i_q
        dd, dq, qd, qq = _jacobian(psi_d, psi_q, motor, bridge)
        det = dd * qq - dq * qd
        return psi_d - (qq * r_d - dq * r_q) / det, psi_q - (dd * r_q - qd * r_d) / det

    psi = (motor.lambda_m + motor.Ld * i_d, motor.Lq * i_q)
    if loop:
        shape = jnp.broadcast_shapes(*(jnp.shape(x) for x in (*psi, i_d, i_q)))
        return jax.lax.fori_loop(0, iterations, newton, tuple(jnp.broadcast_to(jnp.asarray(x, dtype=float), shape)
                                                             for x in psi))
    for step in range(iterations):
        psi = newton(step, psi)
    return psi


def flux_torque(psi_d: Any, psi_q: Any, i_d: Any, i_q: Any, pole_pairs: Any) -> Any:
    """The air-gap torque (N*m) at flux linkages ``psi_d``, ``psi_q`` (Wb) and currents ``i_d``, ``i_q`` (A):
    ``1.5 * pole_pairs * (psi_d*i_q - psi_q*i_d)``, whatever the law that ties them."""
    return 1.5 * pole_pairs * (psi_d * i_q - psi_q * i_d)


def flux_derivatives(state: Any, v_dq: Any, motor: Any, locked: Any, resistance: Any = None,
                     friction: Any = None, currents: Any = None, bridge: Any = True) -> tuple:
    """Time derivative of the saturating machine's state ``(psi_d, psi_q, w_m, theta_m)`` (Wb, Wb, rad/s, rad).

    Args:
        state: the four state components (a sequence of scalars or arrays).
        v_dq: applied ``(v_d, v_q)`` (V).
        motor: the machine (its law, R, pole pairs and mechanics).
        locked: rotor clamped (``dw_m/dt = dtheta_m/dt = 0``).
        resistance: R (ohm) where it differs from ``motor.R`` (a warm winding), else None.
        friction: the Coulomb and load torque (N*m) at this speed when already known, else computed
            from ``motor`` (``T_load + T_coulomb * tanh(w_m / w_coulomb)``).
        currents: ``(i_d, i_q)`` (A) at the state from another current-of-flux law (an independent plant's),
            else from ``motor``'s (:func:`currents_of_flux`, with ``bridge`` as there).

    Returns:
        ``(dpsi_d/dt, dpsi_q/dt, dw_m/dt, dtheta_m/dt)`` (V, V, rad/s^2, rad/s) and the currents
        ``(i_d, i_q)`` (A) at the state, as ``(derivatives, currents)``.
    """
    psi_d, psi_q, w_m = state[0], state[1], state[2]
    i_d, i_q = currents_of_flux(psi_d, psi_q, motor, bridge) if currents is None else currents
    r = motor.R if resistance is None else resistance
    w_e = motor.pole_pairs * w_m
    dpsi_d = v_dq[0] - r * i_d + w_e * psi_q
    dpsi_q = v_dq[1] - r * i_q - w_e * psi_d
    torque = flux_torque(psi_d, psi_q, i_d, i_q, motor.pole_pairs)
    if friction is None:
        friction = motor.T_load + coulomb_friction(w_m, motor.T_coulomb, motor.w_coulomb)
    free = 1.0 - jnp.asarray(locked, dtype=float)
    dw_m = free * (torque - motor.B * w_m - friction) / motor.J
    return (dpsi_d, dpsi_q, dw_m, free * w_m), (i_d, i_q)


def hinkkanen_law(motor: Any) -> dict[str, Any]:
    """The law's coefficients in Hinkkanen's SI form, as :func:`hinkkanen_coefficients`, traceable.

    Those of the terms about the magnet's flux: with an iron bridge or terms about zero flux
    (:func:`has_bridge`) the law's slope at zero current is still ``1/Ld``, but ``a_d0`` is not.

    Ld, Lq, i_ref and the per-unit coefficients may be JAX tracers (e.g. under ``jax.jacfwd``); the
    exponents are taken as they are. Returns the same keys with arrays or numbers.
    """
    ld, lq, i_ref = motor.Ld, motor.Lq, motor.i_ref
    s, t, u, v = (getattr(motor, n) for n in EXPONENTS)
    fd, fq = ld * i_ref, lq * i_ref
    return {
        "a_d0": 1.0 / ld, "a_dd": motor.sat_d / (ld * fd ** s),
        "a_q0": 1.0 / lq, "a_qq": motor.sat_q / (lq * fq ** t),
        "a_dq": motor.sat_dq * i_ref * (lq / ld) ** 0.5 / (fd ** (u + 1) * fq ** (v + 2)),
        "S": s, "T": t, "U": u, "V": v,
    }


def hinkkanen_coefficients(motor: Any) -> dict[str, float]:
    """The law's coefficients in Hinkkanen's SI form (a machine with ``lambda_m = 0``, or about its magnet).

    ``i_d = (a_d0 + a_dd*|d|**S + a_dq/(V + 2)*|d|**U*|q|**(V + 2)) * d`` and
    ``i_q = (a_q0 + a_qq*|q|**T + a_dq/(U + 2)*|d|**(U + 2)*|q|**V) * q`` with ``d = psi_d - lambda_m``,
    ``q = psi_q`` (Wb): ``a_d0 = 1/Ld`` (1/H), ``a_dd`` (A/Wb^(S+1)), ``a_dq`` (A/Wb^(U+V+3)).
    Unbatched motors; plain floats (:func:`hinkkanen_law` is the traceable form).
    """
    return {k: float(v) for k, v in hinkkanen_law(motor).items()}


def _per_unit(motor: Any, ld: float, lq: float, i_ref: float, a_dd: float, S: float, a_qq: float, T: float,
              a_dq: float, U: float, V: float) -> Any:
    """``motor`` with Ld, Lq (H) and Hinkkanen's SI saturation coefficients in drivecal's per-unit form at ``i_ref``."""
    fd, fq = ld * i_ref, lq * i_ref
    return motor.replace(Ld=ld, Lq=lq, i_ref=float(i_ref), exp_d=float(S), exp_q=float(T), exp_dq_d=float(U),
                         exp_dq_q=float(V), sat_d=a_dd * ld * fd ** S, sat_q=a_qq * lq * fq ** T,
                         sat_dq=a_dq * fd ** (U + 1) * fq ** (V + 2) / (i_ref * np.sqrt(lq / ld)))


def from_hinkkanen(motor: Any, *, a_d0: float, a_dd: float, S: float, a_q0: float, a_qq: float, T: float,
                   a_dq: float, U: float, V: float, i_ref: float) -> Any:
    """``motor`` with the law of Hinkkanen's coefficients (SI; see :func:`hinkkanen_coefficients`), at ``i_ref`` (A).

    The inverse of :func:`hinkkanen_coefficients`: published models become drivecal motors exactly.
    """
    return _per_unit(motor, 1.0 / a_d0, 1.0 / a_q0, i_ref, a_dd, S, a_qq, T, a_dq, U, V)


def from_lelli(motor: Any, *, a_d0: float, a_dd: float, S: float, a_q0: float, a_qq: float, T: float, a_dq: float,
               U: float, V: float, a_b: float, a_bp: float, k_q: float, psi_n: float, W: float, i_ref: float) -> Any:
    """``motor`` with a PM-assisted motor's law as Lelli et al. publish it (SI), at ``i_ref`` (A).

    The published law is Hinkkanen's about zero flux plus the iron bridge, in SI coefficients::

        i_d = (a_d0 + a_dd*|psi_d|**S + a_dq/(V + 2)*|psi_d|**U*|psi_q|**(V + 2))*psi_d + G_b*(psi_d - psi_n)
        i_q = (a_q0 + a_qq*|psi_q|**T + a_dq/(U + 2)*|psi_d|**(U + 2)*|psi_q|**V)*psi_q + k_q*G_b*psi_q
        G_b = a_b*s**W / (1 + a_bp*s**W),  s = sqrt((psi_d - psi_n)**2 + k_q*psi_q**2)

    (A/Wb; ``a_b`` in A/Wb^(W+1), ``a_bp`` in 1/Wb^W, ``psi_n`` in Wb). The result's ``lambda_m`` is the d flux
    at zero current and its ``Ld``, ``Lq`` the small-signal inductances there (Newton's method on the
    published law); the module's law then equals the published one (to rounding).
    """
    def with_bridge(ld: float, lq: float, lambda_m: float) -> Any:  # the bridge per unit at the scale Ld * i_ref
        flux = ld * i_ref
        return _per_unit(motor, ld, lq, i_ref, a_dd, S, a_qq, T, a_dq, U, V).replace(
            lambda_m=lambda_m, sat_at_zero=1.0, sat_b=a_b * ld * flux ** W, sat_bp=a_bp * flux ** W, k_q=float(k_q),
            psi_n=float(psi_n), exp_b=float(W))

    published = with_bridge(1.0 / a_d0, 1.0 / a_q0, 0.0)  # the published law itself: its terms, no correction

    def law(psi_d, psi_q):  # no correction at the magnet: the published law as it stands
        return currents_of_flux(psi_d, psi_q, published, bridge=MagnetPoint(0.0, 0.0, 0.0, 0.0))

    psi = float(psi_n)
    for _ in range(60):
        (i_d, _), (slope, _) = jax.jvp(law, (jnp.asarray(psi), jnp.asarray(0.0)), (jnp.asarray(1.0), jnp.asarray(0.0)))
        psi -= float(i_d) / float(slope)
    _, (inv_ld, inv_lq) = jax.jvp(law, (jnp.asarray(psi), jnp.asarray(0.0)), (jnp.asarray(1.0), jnp.asarray(1.0)))
    return with_bridge(1.0 / float(inv_ld), 1.0 / float(inv_lq), psi)
