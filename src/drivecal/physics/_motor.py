"""The PMSM: its parameters and the dq equations (the only copy of the physics).

Rotor dq frame, amplitude-invariant, SI units. State ``x = [i_d, i_q, w_m,
theta_m]`` (A, A, rad/s, rad), input ``v = [v_d, v_q]`` (V), electrical speed
``w_e = pole_pairs * w_m``::

    Ld * di_d/dt = v_d - R*i_d + w_e*Lq*i_q
    Lq * di_q/dt = v_q - R*i_q - w_e*(Ld*i_d + lambda_m)
    Te = 1.5*pole_pairs*(lambda_m*i_q + (Ld - Lq)*i_d*i_q)
    J * dw_m/dt = Te - B*w_m - T_coulomb*tanh(w_m/w_coulomb) - T_load ;  dtheta_m/dt = w_m

With the rotor locked (standstill bench) ``dw_m/dt = dtheta_m/dt = 0``.
These are exactly the equations of ``jaxonomy.library.drives.PMSM``; the
conformance test in ``tests/physics/test_motor.py`` holds the two together.
Coulomb friction (:func:`coulomb_friction`, a smooth sign so that the Jacobian
exists) is not in the block: the engine bench feeds it to the block's load port
from the same function.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from .._parameters import ADDITIVE_SCALE, DEFAULT_VALUES, ESTIMATED, FIXED, UNITS
from .._pytree import pytree_dataclass


@pytree_dataclass
class MotorParams:
    """Electrical and mechanical parameters of a PMSM, SI units.

    A frozen pytree: every field is a leaf, so a batch of motors is the same
    object with a leading axis on each field.

    Attributes:
        R: stator phase resistance (ohm).
        Ld: d-axis inductance (H).
        Lq: q-axis inductance (H).
        lambda_m: permanent-magnet flux linkage (Wb = V*s).
        pole_pairs: pole pairs (-); electrical speed = pole_pairs * mechanical.
        J: rotor inertia (kg*m^2).
        B: viscous friction (N*m*s).
        T_load: constant load torque (N*m); zero on an unloaded bench.
        T_coulomb: Coulomb (dry) friction torque (N*m), against the speed's
            sign: ``T_coulomb * tanh(w_m / w_coulomb)`` (:func:`coulomb_friction`).
        w_coulomb: speed (rad/s) over which the Coulomb friction's smooth sign
            turns (tanh: 76 % of ``T_coulomb`` at ``w_coulomb``); a setting.
        delay: the inverter's command delay (samples, may be fractional):
            the voltage commanded at sample k acts from ``(k + delay) * T_s``
            (computation delay plus the PWM's effective update instant).
        v_dead: inverter voltage error (V) each phase loses against its
            current's direction: dead time plus the devices' forward drop
            (see ``_inverter.py``); 0 for an ideal inverter.
        i_dead: current width (A) of the smooth sign in the dead-time error
            (the switches' capacitance, and the sampled current's chatter
            about a switching edge); the PWM ripple's dead zone around zero
            current is computed from the period's voltages (``_inverter.py``).
        offset_d, offset_q: current-sensor offsets (A) seen on i_d and i_q.
        offset_a, offset_b: phase current-sensor offsets (A) of a phase (abc)
            bench file; they reach dq rotated by the rotor angle.
        alpha_R: temperature coefficient of R (1/K); copper 3.93e-3.
        T_ref: winding temperature (degC) at which R is stated:
            ``R(T) = R * (1 + alpha_R * (T - T_ref))``.
        encoder_offset: electrical angle (rad) by which the encoder's zero is
            off the rotor's d axis: a phase bench file's angle column reads
            ``theta_e + encoder_offset``, so its Park transform turns every dq
            quantity by ``-encoder_offset`` (``_sensors.encoder_frame``) and the
            true rotor-frame angle is the column minus the offset.
        sat_d, sat_q, sat_dq: magnetic saturation (dimensionless; 0: a linear
            machine): the d- and q-axis self-saturation and the cross-saturation of
            the current-of-flux law in ``_magnetics`` (Ld, Lq, lambda_m are then the
            small-signal values at zero current).
        exp_d, exp_q, exp_dq_d, exp_dq_q: that law's exponents (Hinkkanen's S, T,
            U, V; settings).
        i_ref: the current (A) at which the saturation coefficients are stated
            (``sat_d = 1``: the d-axis secant inductance halved at i_ref).
        sat_b: the iron bridge's saturation (dimensionless; 0: no bridge) of a PM-assisted motor
            (Lelli et al.'s law in ``_magnetics``), per unit as ``sat_d``.
        exp_b, sat_bp, k_q, psi_n: the bridge's shape: its exponent (Lelli's W, a setting), its own
            saturation (Lelli's a_bp, per unit), the weight of the q flux in it (k_q, -) and the flux (Wb)
            of the magnet's Norton equivalent it carries.
        sat_at_zero: 1 where the self- and cross-saturation terms are written about zero flux (Hinkkanen's
            and Lelli's form), 0 (drivecal's) about the magnet's flux ``lambda_m`` (a setting).

    The defaults are the 48 V interior PMSM of the drivecal tutorial bench on
    an ideal inverter and ideal sensors.
    """

    R: Any = DEFAULT_VALUES["R"]
    Ld: Any = DEFAULT_VALUES["Ld"]
    Lq: Any = DEFAULT_VALUES["Lq"]
    lambda_m: Any = DEFAULT_VALUES["lambda_m"]
    pole_pairs: Any = DEFAULT_VALUES["pole_pairs"]
    J: Any = DEFAULT_VALUES["J"]
    B: Any = DEFAULT_VALUES["B"]
    T_load: Any = DEFAULT_VALUES["T_load"]
    T_coulomb: Any = DEFAULT_VALUES["T_coulomb"]
    w_coulomb: Any = DEFAULT_VALUES["w_coulomb"]
    delay: Any = DEFAULT_VALUES["delay"]
    v_dead: Any = DEFAULT_VALUES["v_dead"]
    i_dead: Any = DEFAULT_VALUES["i_dead"]
    offset_d: Any = DEFAULT_VALUES["offset_d"]
    offset_q: Any = DEFAULT_VALUES["offset_q"]
    offset_a: Any = DEFAULT_VALUES["offset_a"]
    offset_b: Any = DEFAULT_VALUES["offset_b"]
    alpha_R: Any = DEFAULT_VALUES["alpha_R"]
    T_ref: Any = DEFAULT_VALUES["T_ref"]
    encoder_offset: Any = DEFAULT_VALUES["encoder_offset"]
    sat_d: Any = DEFAULT_VALUES["sat_d"]
    sat_q: Any = DEFAULT_VALUES["sat_q"]
    sat_dq: Any = DEFAULT_VALUES["sat_dq"]
    exp_d: Any = DEFAULT_VALUES["exp_d"]
    exp_q: Any = DEFAULT_VALUES["exp_q"]
    exp_dq_d: Any = DEFAULT_VALUES["exp_dq_d"]
    exp_dq_q: Any = DEFAULT_VALUES["exp_dq_q"]
    i_ref: Any = DEFAULT_VALUES["i_ref"]
    sat_b: Any = DEFAULT_VALUES["sat_b"]
    exp_b: Any = DEFAULT_VALUES["exp_b"]
    sat_bp: Any = DEFAULT_VALUES["sat_bp"]
    k_q: Any = DEFAULT_VALUES["k_q"]
    psi_n: Any = DEFAULT_VALUES["psi_n"]
    sat_at_zero: Any = DEFAULT_VALUES["sat_at_zero"]

    def replace(self, **changes: Any) -> MotorParams:
        """A copy with the named fields changed, e.g. ``motor.replace(R=0.5)``."""
        return dataclasses.replace(self, **changes)

    def with_vector(self, names: tuple[str, ...], values: Any) -> MotorParams:
        """A copy with ``names[i]`` set to ``values[..., i]`` (traceable)."""
        return self.replace(**{name: values[..., i] for i, name in enumerate(names)})

    def vector(self, names: tuple[str, ...] = ESTIMATED) -> jnp.ndarray:
        """The named parameters stacked along the last axis, shape (..., len(names))."""
        return parameter_values(self, names, jnp)

    def as_dict(self) -> dict[str, float]:
        """Plain ``{name: float}`` of the seven motor parameters (unbatched motors only)."""
        return {n: float(getattr(self, n)) for n in ESTIMATED + FIXED}

    def all_values(self) -> dict[str, float]:
        """Plain ``{name: float}`` of every field, bench effects included (unbatched only)."""
        return {f.name: float(getattr(self, f.name)) for f in dataclasses.fields(self)}

    def _shown(self) -> list[tuple[str, Any]]:
        """The fields worth showing: the seven motor parameters, then any other that differs from the default."""
        default = {f.name: f.default for f in dataclasses.fields(self)}
        out = []
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            try:
                changed = np.shape(v) != () or float(v) != float(default[f.name])
            except Exception:  # a tracer (printed inside jit): show it
                changed = True
            if f.name in ESTIMATED + FIXED or changed:
                out.append((f.name, v))
        return out

    def __repr__(self) -> str:
        """``MotorParams(R=0.45, Ld=0.0032, ...)``: plain numbers (shapes for a batch), SI units."""
        def text(v):
            try:
                return f"{float(v)!r}" if np.shape(v) == () else f"<array {np.shape(v)}>"
            except Exception:  # a tracer
                return type(v).__name__
        return "MotorParams(" + ", ".join(f"{n}={text(v)}" for n, v in self._shown()) + ")"

    def __str__(self) -> str:
        """One line per parameter with its unit, e.g. ``R = 450 mΩ``, ``Ld = 3.2 mH`` (a batch: its shape)."""
        from .._units import format_quantity

        shape = np.shape(self.R)
        if shape != ():
            return f"MotorParams batch of shape {shape}"
        try:
            values = [(n, float(v)) for n, v in self._shown()]
        except Exception:  # a tracer (printed inside jit)
            return repr(self)
        return "MotorParams:\n" + "\n".join(f"    {n:<10} = {format_quantity(v, UNITS[n])}"
                                             for n, v in values)


class DqCoefficients(NamedTuple):
    """The dq equations' parameter groups, each computed once from a motor (SI units).

    With them the equations are sums of products (no division), and under
    ``jax.jvp`` a parameter's tangent meets each group once, outside any time
    loop, instead of at every stage of every step. Any field may be an array
    (e.g. ``r_ld``, ``r_lq`` per sample when R follows the temperature).

    Attributes:
        inv_ld: 1 / Ld (1/H).
        r_ld: R / Ld (1/s).
        wq_ld: pole_pairs * Lq / Ld (-), times ``w_m * i_q``.
        inv_lq: 1 / Lq (1/H).
        r_lq: R / Lq (1/s).
        wd_lq: pole_pairs * Ld / Lq (-), times ``w_m * i_d``.
        wf_lq: pole_pairs * lambda_m / Lq (A), times ``w_m``.
        tq_j: 1.5 * pole_pairs * lambda_m / J (1/(A*s^2)), times ``i_q``.
        tr_j: 1.5 * pole_pairs * (Ld - Lq) / J (1/(A^2*s^2)), times ``i_d * i_q``.
        b_j: B / J (1/s).
        load_j: T_load / J (rad/s^2).
        coulomb_j: T_coulomb / J (rad/s^2), times ``tanh(w_m / w_coulomb)``.
        w_coulomb: the Coulomb friction's speed width (rad/s).
    """

    inv_ld: Any
    r_ld: Any
    wq_ld: Any
    inv_lq: Any
    r_lq: Any
    wd_lq: Any
    wf_lq: Any
    tq_j: Any
    tr_j: Any
    b_j: Any
    load_j: Any
    coulomb_j: Any = 0.0
    w_coulomb: Any = 1.0


def dq_coefficients(motor: MotorParams) -> DqCoefficients:
    """The parameter groups of the dq equations of ``motor`` (see :class:`DqCoefficients`)."""
    p, ld, lq, j = motor.pole_pairs, motor.Ld, motor.Lq, motor.J
    return DqCoefficients(
        inv_ld=1.0 / ld,
        r_ld=motor.R / ld,
        wq_ld=p * lq / ld,
        inv_lq=1.0 / lq,
        r_lq=motor.R / lq,
        wd_lq=p * ld / lq,
        wf_lq=p * motor.lambda_m / lq,
        tq_j=1.5 * p * motor.lambda_m / j,
        tr_j=1.5 * p * (ld - lq) / j,
        b_j=motor.B / j,
        load_j=motor.T_load / j,
        coulomb_j=motor.T_coulomb / j,
        w_coulomb=motor.w_coulomb,
    )


def coulomb_friction(w_m: Any, T_coulomb: Any, w_coulomb: Any) -> Any:
    """Coulomb (dry) friction torque (N*m) at mechanical speed ``w_m`` (rad/s): ``T_coulomb * tanh(w_m / w_coulomb)``.

    Against the speed's sign; a smooth sign of speed width ``w_coulomb`` (rad/s) so that the
    Jacobian exists. At rest it is zero: the model has no stiction.
    """
    return T_coulomb * jnp.tanh(w_m / w_coulomb)


def dq_derivatives_from(coefficients: DqCoefficients, state: Any, v_dq: Any, locked: Any) -> tuple:
    """Time derivative of the PMSM state from precomputed :func:`dq_coefficients`.

    The equations of the module docstring, divided through by Ld, Lq and J.
    Arguments and result as :func:`dq_derivatives`.
    """
    c = coefficients
    i_d, i_q, w_m = state[0], state[1], state[2]
    v_d, v_q = v_dq[0], v_dq[1]
    di_d = c.inv_ld * v_d - c.r_ld * i_d + c.wq_ld * w_m * i_q
    di_q = c.inv_lq * v_q - c.r_lq * i_q - c.wd_lq * w_m * i_d - c.wf_lq * w_m
    free = 1.0 - jnp.asarray(locked, dtype=float)
    dw_m = free * (c.tq_j * i_q + c.tr_j * i_d * i_q - c.b_j * w_m - c.load_j
                   - coulomb_friction(w_m, c.coulomb_j, c.w_coulomb))
    return di_d, di_q, dw_m, free * w_m


def dq_derivatives(state: Any, v_dq: Any, motor: MotorParams, locked: Any) -> tuple:
    """Time derivative of the PMSM state.

    Args:
        state: ``(i_d, i_q, w_m, theta_m)`` (A, A, rad/s, rad): an array of
            shape (4,) or any sequence of four scalars/arrays.
        v_dq: applied ``(v_d, v_q)`` (V), same convention.
        motor: the machine's parameters.
        locked: rotor clamped (standstill test); a Python or traced boolean.

    Returns:
        ``(di_d/dt, di_q/dt, dw_m/dt, dtheta_m/dt)`` (A/s, A/s, rad/s^2, rad/s)
        as a tuple (``jnp.stack`` it for an array). Keeping the four
        components apart lets a batched rollout work on contiguous arrays.
    """
    return dq_derivatives_from(dq_coefficients(motor), state, v_dq, locked)


def with_d_flux(motor: MotorParams, i_d: Any, flux_d: Any, inductance_d: Any) -> MotorParams:
    """The linear motor whose dq equations at d current ``i_d`` are those of a machine with a saturating d axis.

    Where the d-axis flux ``psi_d(i_d)`` bends with current, the equations of
    the module docstring hold with ``Ld`` the incremental inductance
    ``d psi_d / d i_d`` in ``di_d/dt`` and the flux ``psi_d`` where
    ``Ld*i_d + lambda_m`` stands (back-EMF and torque)::

        L_inc * di_d/dt = v_d - R*i_d + w_e*Lq*i_q
        Lq * di_q/dt = v_q - R*i_q - w_e*psi_d
        Te = 1.5*pole_pairs*(psi_d*i_q - Lq*i_d*i_q)

    Both hold for the linear motor with ``Ld = inductance_d`` (H) and
    ``lambda_m = flux_d - inductance_d * i_d`` (Wb), so :func:`dq_derivatives`
    of the result, at that state, are the saturating machine's: its equations
    are these ones, not a copy.

    Args:
        motor: the other parameters (R, Lq, pole_pairs, J, B, T_load).
        i_d: d current (A) of the state the result serves.
        flux_d: d-axis flux ``psi_d(i_d)`` (Wb), magnet included.
        inductance_d: incremental d inductance ``d psi_d / d i_d`` at ``i_d`` (H).
    """
    return motor.replace(Ld=inductance_d, lambda_m=flux_d - inductance_d * i_d)


def resistance_at(motor: MotorParams, temperature: Any) -> Any:
    """Winding resistance (ohm) at ``temperature`` (degC): ``R * (1 + alpha_R * (T - T_ref))``.

    NaN temperature means "not recorded": the stated R.
    """
    rise = jnp.where(jnp.isnan(temperature), 0.0, temperature - motor.T_ref)
    return motor.R * (1.0 + motor.alpha_R * rise)


def parameter_values(motor: MotorParams, names: tuple[str, ...], xp: Any = jnp) -> Any:
    """``motor``'s named parameters stacked along the last axis, shape (..., len(names)), in ``xp`` arrays."""
    return xp.stack([xp.asarray(getattr(motor, n), dtype=float) for n in names], axis=-1)


def search_scale(motor: MotorParams, names: tuple[str, ...], xp: Any = jnp) -> tuple[Any, Any]:
    """How a fit searches ``names`` around ``motor``: ``theta = theta0 * exp(z)`` or ``theta0 + s * z``.

    Args:
        xp: the array module, ``jax.numpy`` (traceable, the default) or ``numpy``
            (host-side bookkeeping without dispatching JAX operations).

    Returns:
        ``(is_log, scale)``, each shape (..., len(names)): whether the name is
        searched in ``z = ln(theta/theta0)`` (positive parameters), and
        ``d theta / d z`` at z = 0 (theta0 for those, the additive step of
        :data:`ADDITIVE_SCALE` for the others).
    """
    theta0 = parameter_values(motor, names, xp)
    is_log = xp.asarray([n not in ADDITIVE_SCALE for n in names])
    step = xp.asarray([ADDITIVE_SCALE.get(n, 1.0) for n in names], dtype=float)
    return xp.broadcast_to(is_log, theta0.shape), xp.where(is_log, theta0, step)


def from_search(motor: MotorParams, names: tuple[str, ...], z: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """Parameters ``theta`` (their units) at search coordinates ``z``, and ``d theta / d z`` (``xp`` as above)."""
    theta0 = parameter_values(motor, names, xp)
    is_log, scale = search_scale(motor, names, xp)
    with np.errstate(over="ignore", invalid="ignore"):  # a diverged search's z on the host: inf, reported as such
        theta = xp.where(is_log, theta0 * xp.exp(z), theta0 + scale * z)
    return theta, xp.where(is_log, theta, scale)


def to_search(motor: MotorParams, names: tuple[str, ...], theta: Any, xp: Any = np) -> Any:
    """Search coordinates ``z`` of parameters ``theta`` (inverse of :func:`from_search`; ``xp`` numpy by default)."""
    theta0 = parameter_values(motor, names, xp)
    is_log, scale = search_scale(motor, names, xp)
    theta = xp.asarray(theta, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        return xp.where(is_log, xp.log(theta / theta0), (theta - theta0) / scale)


DEFAULT_MOTOR = MotorParams()
