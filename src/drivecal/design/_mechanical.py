"""The mechanical test of an auto-plan: J, B, T_coulomb (and T_load) from the currents of one free run.

When mechanical parameters are requested, the free spin-up runs on until its
speed is steady and two or three segments continue it (``continue = true``:
the rotor keeps its speed, the currents and the delayed command carry over):

* a **low-speed run** at :data:`LOW_SPEED_FRACTION` of the spin-up voltage
  (and, when ``T_load`` is requested, a **reversed run** at minus that
  voltage, through zero speed). In a steady free run the q current carries
  the friction torque, ``1.5 p lambda_m i_q = B w_m + T_coulomb tanh(w_m /
  w_coulomb) + T_load``: the spin-up's speed and the low speed tell B from
  T_coulomb, the reversed run tells T_load (constant in sign) from the
  friction (against the speed's sign);
* a **short-circuit braking** (inverter on, ``v_d = v_q = 0``): the back-EMF
  drives a braking current, the rotor decelerates against the known
  electrical torque, which is what shows J; near zero speed the Coulomb
  friction stops it.

The braking is the coast-down: with the inverter off no current flows, so
without a measured speed such a segment leaves nothing in the currents (and
the engine bench cannot start the inverter again after it).

**Sizing.** Every run lasts :data:`SETTLE_SPIN_TIMES` spin-up times for the
speed to settle, plus :func:`friction_samples` samples of steady running: as
many as the friction torques at the runs' speeds (each measured through
``i_q`` at the sensor noise) need for B and T_coulomb (T_load) to reach a
standard error of :data:`FRICTION_SE` of their nominal values (of the
friction torque at the low speed for a nominal 0). The
mechanical time constant ``J/B`` (seconds, where the inverter is off) does not
enter: the braking decelerates the rotor in a few spin-up times. The
assessment of the whole plan (:func:`drivecal.design.assess_design`) is the
judge.
"""

from __future__ import annotations

import math

import numpy as np

from ..physics import MECHANICAL, MotorParams
from ..plan import Segment

#: Voltage of the low-speed run as a fraction of the spin-up voltage (its steady speed in proportion).
LOW_SPEED_FRACTION = 0.25
#: Target standard error of B, T_coulomb (T_load) from the steady runs, as a fraction of their nominal values.
FRICTION_SE = 0.1
#: Spin-up times each continuing run is given to settle to its new speed (and the braking to stop).
SETTLE_SPIN_TIMES = 4.0
#: Most samples of steady running per run (a friction too small for the noise is then judged weak).
MAX_FRICTION_SAMPLES = 1 << 15
#: Names of the continuing segments.
LOW_SPEED, REVERSED, BRAKING = "low-speed run", "reversed run", "short-circuit braking"
_FRICTION = ("B", "T_coulomb", "T_load")


def mechanical_requested(names: tuple[str, ...]) -> bool:
    """Whether any of J, B, T_coulomb, T_load is to be estimated."""
    return any(n in MECHANICAL for n in names)


def run_voltages(v_spin: float, names: tuple[str, ...]) -> tuple[float, ...]:
    """The q voltages (V) of the continuing runs after a spin-up at ``v_spin``: low speed, reversed (T_load), 0 V."""
    low = LOW_SPEED_FRACTION * v_spin
    return (low, -low, 0.0) if "T_load" in names else (low, 0.0)


def friction_samples(motor: MotorParams, names: tuple[str, ...], v_spin: float, noise_sigma: float) -> int:
    """Samples of steady running per run for the requested friction terms to reach :data:`FRICTION_SE`.

    The steady speed of a run at ``v_q`` is about ``v_q / (p lambda_m)``; a sample
    of ``i_q`` measures the friction torque there to ``1.5 p lambda_m sigma``. With ``n``
    samples per run, the least-squares fit of ``B w + T_coulomb tanh(w / w_coulomb)
    + T_load`` to the runs' torques has covariance ``(1.5 p lambda_m sigma)^2 / n
    (A^T A)^-1`` (rows of ``A``: one per run). 0 when no friction term is requested.
    """
    cols = [i for i, n in enumerate(_FRICTION) if n in names]
    if not cols:
        return 0
    p, lam = float(motor.pole_pairs), float(motor.lambda_m)
    speeds = [v / (p * lam) for v in (v_spin,) + run_voltages(v_spin, names)[:-1]]
    w_c = float(motor.w_coulomb)
    design = np.array([[w, math.tanh(w / w_c), 1.0] for w in speeds])[:, cols]
    unit = np.linalg.inv(design.T @ design) * (1.5 * p * lam * noise_sigma) ** 2
    low = min(abs(w) for w in speeds)
    friction_low = float(motor.B) * low + float(motor.T_coulomb) * math.tanh(low / w_c)
    need = 0.0
    for k, i in enumerate(cols):
        nominal = abs(float(getattr(motor, _FRICTION[i])))
        target = FRICTION_SE * (nominal if nominal > 0 else friction_low)
        need = max(need, unit[k, k] / target**2)
    return int(min(math.ceil(need), MAX_FRICTION_SAMPLES))


def mechanical_segments(v_spin: float, names: tuple[str, ...], counts: list[int], sample_rate: float,
                        ) -> tuple[Segment, ...]:
    """The runs that continue the spin-up: ``counts`` samples each (low speed, [reversed,] braking)."""
    labels = (LOW_SPEED, REVERSED, BRAKING) if "T_load" in names else (LOW_SPEED, BRAKING)
    return tuple(Segment(label, n / sample_rate, locked=False, v_d=0.0, v_q=v, continues=True)
                 for label, v, n in zip(labels, run_voltages(v_spin, names), counts))
