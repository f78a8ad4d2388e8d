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

The saturation of the PM machines' iron bridges (Lelli, Hinkkanen, Giulii Capponi, ICEM 2024) is
asymmetric in ``i_d``; about the operating point its leading terms are these ones.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from ._motor import EXPONENTS, MAGNETIC, coulomb_friction

#: Per coefficient, the exponents it uses and the candidate values a fit chooses among (the data's best).
EXPONENT_CANDIDATES: dict[str, tuple[tuple[str, ...], tuple[tuple[float, ...], ...]]] = {
    "sat_d": (("exp_d",), ((1.0,), (2.0,), (3.0,), (4.0,), (5.0,), (6.0,))),
    "sat_q": (("exp_q",), ((1.0,), (2.0,), (3.0,), (4.0,), (5.0,), (6.0,))),
    "sat_dq": (("exp_dq_d", "exp_dq_q"), ((0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (2.0, 0.0), (0.0, 2.0))),
}


def is_saturating(motor: Any) -> bool:
    """Whether any saturation coefficient of ``motor`` is non-zero (host-side, any batch shape)."""
    return any(bool(np.any(np.asarray(getattr(motor, n)) != 0.0)) for n in MAGNETIC)


def _power(x: Any, e: Any) -> Any:
    """``x**e`` for ``x >= 0`` with a finite derivative everywhere (``0**0 = 1``; no ``0 * inf`` at x = 0)."""
    positive = x > 0
    safe = jnp.where(positive, x, 1.0)
    return jnp.where(positive, jnp.exp(e * jnp.log(safe)), jnp.where(e == 0, 1.0, 0.0))


def currents_of_flux(psi_d: Any, psi_q: Any, motor: Any) -> tuple[Any, Any]:
    """The currents ``(i_d, i_q)`` (A) at the flux linkages ``psi_d``, ``psi_q`` (Wb): the law of the module docstring.

    Any broadcastable shapes; ``motor`` a ``MotorParams`` (traceable in every field).
    """
    ld, lq, i_ref = motor.Ld, motor.Lq, motor.i_ref
    x = (psi_d - motor.lambda_m) / (ld * i_ref)
    y = psi_q / (lq * i_ref)
    ax, ay = jnp.abs(x), jnp.abs(y)
    s, t, u, v = motor.exp_d, motor.exp_q, motor.exp_dq_d, motor.exp_dq_q
    cross = motor.sat_dq
    g_d = 1.0 + motor.sat_d * _power(ax, s) + cross * jnp.sqrt(lq / ld) / (v + 2.0) * _power(ax, u) * _power(ay, v + 2.0)
    g_q = 1.0 + motor.sat_q * _power(ay, t) + cross * jnp.sqrt(ld / lq) / (u + 2.0) * _power(ax, u + 2.0) * _power(ay, v)
    return i_ref * x * g_d, i_ref * y * g_q


def _jacobian(psi_d: Any, psi_q: Any, motor: Any) -> tuple[Any, Any, Any, Any]:
    """``d(i_d, i_q) / d(psi_d, psi_q)`` (1/H) at one flux point: ``(dd, dq, qd, qq)``, each of the flux's shape."""
    def along(td, tq):
        return jax.jvp(lambda a, b: currents_of_flux(a, b, motor), (psi_d, psi_q), (td, tq))[1]

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


def flux_of_currents(i_d: Any, i_q: Any, motor: Any, iterations: int = 12) -> tuple[Any, Any]:
    """The flux linkages ``(psi_d, psi_q)`` (Wb) at which the law gives the currents ``i_d``, ``i_q`` (A).

    Newton's method from the linear machine's flux, ``iterations`` steps (unrolled: traceable and
    differentiable; the law is monotone, so it converges to machine precision well within 12 steps at
    currents where the inductance has fallen tenfold). Zero current gives ``(lambda_m, 0)`` exactly.
    """
    psi_d = motor.lambda_m + motor.Ld * i_d
    psi_q = motor.Lq * i_q
    for _ in range(iterations):
        f_d, f_q = currents_of_flux(psi_d, psi_q, motor)
        r_d, r_q = f_d - i_d, f_q - i_q
        dd, dq, qd, qq = _jacobian(psi_d, psi_q, motor)
        det = dd * qq - dq * qd
        psi_d = psi_d - (qq * r_d - dq * r_q) / det
        psi_q = psi_q - (dd * r_q - qd * r_d) / det
    return psi_d, psi_q


def flux_torque(psi_d: Any, psi_q: Any, i_d: Any, i_q: Any, pole_pairs: Any) -> Any:
    """The air-gap torque (N*m) at flux linkages ``psi_d``, ``psi_q`` (Wb) and currents ``i_d``, ``i_q`` (A):
    ``1.5 * pole_pairs * (psi_d*i_q - psi_q*i_d)``, whatever the law that ties them."""
    return 1.5 * pole_pairs * (psi_d * i_q - psi_q * i_d)


def flux_derivatives(state: Any, v_dq: Any, motor: Any, locked: Any, resistance: Any = None,
                     friction: Any = None, currents: Any = None) -> tuple:
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
            else from ``motor``'s (:func:`currents_of_flux`).

    Returns:
        ``(dpsi_d/dt, dpsi_q/dt, dw_m/dt, dtheta_m/dt)`` (V, V, rad/s^2, rad/s) and the currents
        ``(i_d, i_q)`` (A) at the state, as ``(derivatives, currents)``.
    """
    psi_d, psi_q, w_m = state[0], state[1], state[2]
    i_d, i_q = currents_of_flux(psi_d, psi_q, motor) if currents is None else currents
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


def from_hinkkanen(motor: Any, *, a_d0: float, a_dd: float, S: float, a_q0: float, a_qq: float, T: float,
                   a_dq: float, U: float, V: float, i_ref: float) -> Any:
    """``motor`` with the law of Hinkkanen's coefficients (SI; see :func:`hinkkanen_coefficients`), at ``i_ref`` (A).

    The inverse of :func:`hinkkanen_coefficients`: published models become drivecal motors exactly.
    """
    ld, lq = 1.0 / a_d0, 1.0 / a_q0
    fd, fq = ld * i_ref, lq * i_ref
    return motor.replace(Ld=ld, Lq=lq, i_ref=float(i_ref), exp_d=float(S), exp_q=float(T), exp_dq_d=float(U),
                         exp_dq_q=float(V), sat_d=a_dd * ld * fd ** S, sat_q=a_qq * lq * fq ** T,
                         sat_dq=a_dq * fd ** (U + 1) * fq ** (V + 2) / (i_ref * np.sqrt(lq / ld)))
