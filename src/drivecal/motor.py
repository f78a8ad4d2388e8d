"""The PMSM: its parameters and the dq equations (the only copy of the physics).

Rotor dq frame, amplitude-invariant, SI units. State ``x = [i_d, i_q, w_m,
theta_m]`` (A, A, rad/s, rad), input ``v = [v_d, v_q]`` (V), electrical speed
``w_e = pole_pairs * w_m``::

    Ld * di_d/dt = v_d - R*i_d + w_e*Lq*i_q
    Lq * di_q/dt = v_q - R*i_q - w_e*(Ld*i_d + lambda_m)
    Te = 1.5*pole_pairs*(lambda_m*i_q + (Ld - Lq)*i_d*i_q)
    J * dw_m/dt = Te - B*w_m - T_load ;  dtheta_m/dt = w_m

With the rotor locked (standstill bench) ``dw_m/dt = dtheta_m/dt = 0``.
These are exactly the equations of ``jaxonomy.library.drives.PMSM``; the
conformance test in ``tests/test_motor.py`` holds the two together.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import jax.numpy as jnp

#: Parameters a calibration estimates by default, in this order.
ESTIMATED: tuple[str, ...] = ("R", "Ld", "Lq", "lambda_m")
#: Parameters held fixed by default (known from the datasheet or unobservable
#: from currents alone).
FIXED: tuple[str, ...] = ("pole_pairs", "J", "B")

#: SI unit of every parameter, for tables and JSON.
UNITS: dict[str, str] = {
    "R": "ohm",
    "Ld": "H",
    "Lq": "H",
    "lambda_m": "Wb",
    "pole_pairs": "-",
    "J": "kg*m^2",
    "B": "N*m*s",
}

#: One-line meaning of every parameter.
DESCRIPTIONS: dict[str, str] = {
    "R": "stator phase resistance",
    "Ld": "d-axis inductance",
    "Lq": "q-axis inductance",
    "lambda_m": "permanent-magnet flux linkage",
    "pole_pairs": "pole pairs",
    "J": "rotor inertia",
    "B": "viscous friction",
}


class MotorParams(eqx.Module):
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

    The defaults are the 48 V interior PMSM of the drivecal tutorial bench.
    """

    R: Any = 0.45
    Ld: Any = 3.2e-3
    Lq: Any = 5.8e-3
    lambda_m: Any = 0.0533
    pole_pairs: Any = 4.0
    J: Any = 1.2e-3
    B: Any = 8.0e-5
    T_load: Any = 0.0

    def replace(self, **changes: Any) -> MotorParams:
        """A copy with the named fields changed, e.g. ``motor.replace(R=0.5)``."""
        return dataclasses.replace(self, **changes)

    def with_vector(self, names: tuple[str, ...], values: Any) -> MotorParams:
        """A copy with ``names[i]`` set to ``values[..., i]`` (traceable)."""
        return self.replace(**{name: values[..., i] for i, name in enumerate(names)})

    def vector(self, names: tuple[str, ...] = ESTIMATED) -> jnp.ndarray:
        """The named parameters stacked along the last axis, shape (..., len(names))."""
        return jnp.stack([jnp.asarray(getattr(self, n), dtype=float) for n in names], axis=-1)

    def as_dict(self) -> dict[str, float]:
        """Plain ``{name: float}`` of the seven motor parameters (unbatched motors only)."""
        return {n: float(getattr(self, n)) for n in ESTIMATED + FIXED}


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
    i_d, i_q, w_m = state[0], state[1], state[2]
    v_d, v_q = v_dq[0], v_dq[1]
    w_e = motor.pole_pairs * w_m
    di_d = (v_d - motor.R * i_d + w_e * motor.Lq * i_q) / motor.Ld
    di_q = (v_q - motor.R * i_q - w_e * (motor.Ld * i_d + motor.lambda_m)) / motor.Lq
    torque = electromagnetic_torque(i_d, i_q, motor)
    free = 1.0 - jnp.asarray(locked, dtype=float)
    dw_m = free * (torque - motor.B * w_m - motor.T_load) / motor.J
    return di_d, di_q, dw_m, free * w_m


def electromagnetic_torque(i_d: Any, i_q: Any, motor: MotorParams) -> Any:
    """Electromagnetic torque ``1.5*p*(lambda_m*i_q + (Ld - Lq)*i_d*i_q)`` (N*m)."""
    return 1.5 * motor.pole_pairs * (motor.lambda_m * i_q + (motor.Ld - motor.Lq) * i_d * i_q)


DEFAULT_MOTOR = MotorParams()
