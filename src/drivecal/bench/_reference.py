"""A published saturating machine and a plan that identifies its law: the reference of tests and benchmarks.

Hinkkanen et al., "Sensorless self-commissioning of synchronous reluctance motors at standstill without
rotor locking", IEEE Trans. Ind. Appl. 2017 (doi 10.1109/TIA.2016.2644624): a 6.7-kW, 2-pole-pair
synchronous reluctance motor, R = 0.54 ohm, J = 0.015 kg*m^2, its current-of-flux law in SI form (the
coefficients as published, e.g. in Aalto's motulator).
"""

from __future__ import annotations

from ..physics import MotorParams, from_hinkkanen
from ..plan import Plan, Segment

#: The SyRM's published law (SI: a_d0, a_q0 in 1/H; a_dd, a_qq, a_dq in A/Wb^k; S, T, U, V the exponents).
HINKKANEN_SYRM: dict[str, float] = dict(a_d0=17.4, a_dd=373.0, S=5, a_q0=52.1, a_qq=658.0, T=1, a_dq=1120.0, U=1,
                                        V=0)

#: Locked steps at three levels per axis and two combined d+q steps, 10 ms each at 10 kHz (to about 10 A on d
#: and 39 A on the SyRM's q axis): every coefficient of the law identifiable.
SATURATION_LEVELS_PLAN = Plan(
    tuple(Segment(name, 0.01, True, v_d=v_d, v_q=v_q) for name, v_d, v_q in (
        ("d 15 V", 15.0, 0.0), ("d 30 V", 30.0, 0.0), ("d 45 V", 45.0, 0.0), ("q 10 V", 0.0, 10.0),
        ("q 20 V", 0.0, 20.0), ("q 30 V", 0.0, 30.0), ("d+q", 20.0, 20.0), ("d-q", 30.0, -30.0))),
    sample_rate=10000.0, v_dc=540.0, current_limit=80.0)


def hinkkanen_syrm(i_ref: float = 20.0) -> MotorParams:
    """Hinkkanen's SyRM as a drivecal motor, its law's coefficients per unit at ``i_ref`` (A)."""
    return from_hinkkanen(MotorParams(R=0.54, pole_pairs=2.0, J=0.015, lambda_m=0.0), i_ref=i_ref, **HINKKANEN_SYRM)
