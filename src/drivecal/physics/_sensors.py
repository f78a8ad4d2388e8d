"""What stands between the motor and the bench log: the inverter's command delay, the current sensors' offsets,
the encoder's offset.

Encoder offset, sign convention: the encoder's angle reads ``theta_enc = theta_e + encoder_offset``
(electrical, rad; ``theta_e`` the true angle of the rotor's d axis from phase a). A phase bench file's
Park transform at ``theta_enc`` turns every quantity whose rotor-frame components are ``x`` into
``Rot(-encoder_offset) x`` (:func:`encoder_frame`), currents and voltages alike; the true components are
``Rot(+encoder_offset)`` of the file's (:func:`rotor_frame`). Correcting the file means a Park transform at
``theta_enc - encoder_offset``; the model does the same by turning the file's voltages into the rotor
frame before the rollout and its currents back after it.

The forward model (``drivecal.model``) and the synthetic bench on the engine
(``drivecal.bench``) both apply these, so a fit and its synthetic truth see
the same bench.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np

from ._motor import MotorParams
from ._transforms import abc_to_dq, inverse_park, park


def delayed(voltages: np.ndarray, delay_samples: int, *, at_rest: bool | np.ndarray = True) -> np.ndarray:
    """The voltages an inverter with a ``delay_samples`` PWM/computation delay applies, shape (..., N, 2) (V).

    Command k acts at sample k + delay_samples; before the first command acts
    the inverter applies 0 V (a segment from rest) or the first command (a
    segment that starts moving, whose earlier command is unknown); ``at_rest``
    is one flag, or one per dataset of a stack (the leading axes).
    """
    if int(delay_samples) != delay_samples or delay_samples < 0:
        raise ValueError(f"delay_samples must be a whole number of samples >= 0, got {delay_samples!r}")
    d = int(delay_samples)
    v = np.asarray(voltages, dtype=float)
    if d == 0:
        return v
    # Per dataset of a stack (leading axes): 0 V from rest, else the first command.
    rest = np.asarray(at_rest, dtype=bool)[..., None, None]
    pad = np.where(rest, 0.0, np.broadcast_to(v[..., :1, :], v.shape[:-2] + (d, 2)))
    return np.concatenate([pad, v], axis=-2)[..., : v.shape[-2], :]


def with_dq_offsets(i_d: Any, i_q: Any, motor: MotorParams) -> tuple[Any, Any]:
    """Currents (A) as the sensors report them without phase offsets: plus the dq offsets."""
    return i_d + motor.offset_d, i_q + motor.offset_q


def sensor_offsets(theta_e: Any, motor: MotorParams) -> tuple[Any, Any]:
    """What the current sensors add to ``(i_d, i_q)`` (A) at electrical angle ``theta_e`` (rad).

    The dq offsets, plus the phase offsets of two phase sensors (``i_c = -i_a - i_b``)
    taken into dq by the amplitude-invariant Clarke and Park transforms (:func:`abc_to_dq`).
    """
    d_offset, q_offset = abc_to_dq(motor.offset_a, motor.offset_b, None, theta_e)
    return with_dq_offsets(d_offset, q_offset, motor)


def encoder_frame(d: Any, q: Any, encoder_offset: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """Rotor-frame ``(d, q)`` as a Park transform at the encoder's angle gives them: turned by ``-encoder_offset``.

    ``Park(theta_e + offset) = Rot(-offset) Park(theta_e)``: :func:`park` of ``(d, q)`` at the offset (rad).
    ``xp``: the array module (JAX's by default).
    """
    return park(d, q, encoder_offset, xp)


def rotor_frame(d: Any, q: Any, encoder_offset: Any, xp: Any = jnp) -> tuple[Any, Any]:
    """A phase file's ``(d, q)`` in the rotor frame: turned by ``+encoder_offset`` (inverse of :func:`encoder_frame`)."""
    return inverse_park(d, q, encoder_offset, xp)
