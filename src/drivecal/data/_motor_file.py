"""Motor files (TOML), validated with pydantic: the nominal motor, the fit's prior, and what to estimate.

Every physical value is either a plain number in SI units or a string with a
unit, e.g. ``R = "0.45 ohm"``, ``Ld = "3.2 mH"``. A wrong key or a unit of the
wrong kind is refused with one sentence naming the file, the key and the fix.
The schema is documented in docs/bench-files.md ("Motor files") and exemplified in
``examples/``. A saturating motor states its magnetic law (``physics._magnetics``) in drivecal's
per-unit keys (``sat_d``, ``sat_q``, ``sat_dq``, ``exp_*``, ``i_ref``; a PM-assisted motor's iron bridge:
``sat_b``, ``exp_b``, ``sat_bp``, ``k_q``, ``psi_n``, ``sat_at_zero``) or as published: a ``[hinkkanen]`` table of
Hinkkanen et al.'s SI coefficients (``examples/syrm_motor.toml``), or a ``[lelli]`` table of Lelli et al.'s
(``examples/pm_syrm_motor.toml``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from ..errors import DrivecalError
from ..physics import (BRIDGE, BRIDGE_SHAPE, DEFAULT_MOTOR, ESTIMABLE, ESTIMATED, EXPONENTS, MAGNETIC, MotorParams,
                       from_hinkkanen, from_lelli)
from ._tolerance import Tolerance, tolerances_of
from .._units import StrictModel, explain, quantity, read_toml


#: The keys of a motor file that describe the motor itself: a file that leaves one out gets the default
#: (48 V demo) motor's value, which is rarely what a real motor has (:attr:`MotorFile.defaulted`).
REQUIRED_KEYS = ("R", "Ld", "Lq", "lambda_m", "pole_pairs")


def _exponent(default: float):
    """A saturation exponent: a plain number from 0 to 10."""
    return Field(default=default, ge=0, le=10, allow_inf_nan=False)


def _coefficient(*, required: bool = False):
    """A saturation coefficient: a plain finite number, > 0 where ``required`` (no default), else >= 0 (default 0)."""
    if required:
        return Field(gt=0, allow_inf_nan=False)
    return Field(default=0.0, ge=0, allow_inf_nan=False)


class HinkkanenSpec(StrictModel):
    """The ``[hinkkanen]`` table: the current-of-flux law in Hinkkanen et al.'s SI coefficients.

    ``i_d = (a_d0 + a_dd*|d|**S + a_dq/(V + 2)*|d|**U*|q|**(V + 2)) * d`` and
    ``i_q = (a_q0 + a_qq*|q|**T + a_dq/(U + 2)*|d|**(U + 2)*|q|**V) * q`` with ``d = psi_d - lambda_m``,
    ``q = psi_q`` (Wb): ``a_d0 = 1/Ld``, ``a_q0 = 1/Lq`` (1/H); ``a_dd`` (A/Wb^(S+1)), ``a_qq``, ``a_dq``.
    """

    a_d0: float = _coefficient(required=True)
    a_dd: float = _coefficient()
    S: float = _exponent(float(DEFAULT_MOTOR.exp_d))
    a_q0: float = _coefficient(required=True)
    a_qq: float = _coefficient()
    T: float = _exponent(float(DEFAULT_MOTOR.exp_q))
    a_dq: float = _coefficient()
    U: float = _exponent(float(DEFAULT_MOTOR.exp_dq_d))
    V: float = _exponent(float(DEFAULT_MOTOR.exp_dq_q))


class LelliSpec(HinkkanenSpec):
    """The ``[lelli]`` table: a PM-assisted motor's current-of-flux law in Lelli et al.'s SI coefficients.

    Hinkkanen's terms about zero flux (the keys of ``[hinkkanen]``, with ``psi_d`` for ``d``) plus the iron
    bridge ``G_b*(psi_d - psi_n)`` on d and ``k_q*G_b*psi_q`` on q, ``G_b = a_b*s**W / (1 + a_bp*s**W)``,
    ``s = sqrt((psi_d - psi_n)**2 + k_q*psi_q**2)``: ``a_b`` (A/Wb^(W+1)), ``a_bp`` (1/Wb^W), ``k_q`` (-),
    ``psi_n`` (Wb). Ld, Lq and lambda_m follow from the law (``physics.from_lelli``).
    """

    a_b: float = _coefficient(required=True)
    a_bp: float = _coefficient()
    k_q: float = _coefficient()
    psi_n: float = Field(gt=0, allow_inf_nan=False)
    W: float = _exponent(float(DEFAULT_MOTOR.exp_b))


class MotorSpec(StrictModel):
    R: quantity("resistance") = float(DEFAULT_MOTOR.R)
    Ld: quantity("inductance") = float(DEFAULT_MOTOR.Ld)
    Lq: quantity("inductance") = float(DEFAULT_MOTOR.Lq)
    lambda_m: quantity("flux") = float(DEFAULT_MOTOR.lambda_m)
    pole_pairs: int = int(DEFAULT_MOTOR.pole_pairs)
    J: quantity("inertia") = float(DEFAULT_MOTOR.J)
    B: quantity("friction") = float(DEFAULT_MOTOR.B)
    T_load: quantity("torque") = 0.0
    T_coulomb: quantity("torque") = 0.0
    w_coulomb: quantity("speed") = float(DEFAULT_MOTOR.w_coulomb)
    v_dead: quantity("voltage") = 0.0
    i_dead: quantity("current") = float(DEFAULT_MOTOR.i_dead)
    offset_d: quantity("current") = 0.0
    offset_q: quantity("current") = 0.0
    offset_a: quantity("current") = 0.0
    offset_b: quantity("current") = 0.0
    alpha_R: quantity("temperature coefficient") = float(DEFAULT_MOTOR.alpha_R)
    T_ref: quantity("temperature") = float(DEFAULT_MOTOR.T_ref)
    encoder_offset: quantity("rotor angle") = 0.0
    sat_d: float = _coefficient()
    sat_q: float = _coefficient()
    sat_dq: float = _coefficient()
    exp_d: float = _exponent(float(DEFAULT_MOTOR.exp_d))
    exp_q: float = _exponent(float(DEFAULT_MOTOR.exp_q))
    exp_dq_d: float = _exponent(float(DEFAULT_MOTOR.exp_dq_d))
    exp_dq_q: float = _exponent(float(DEFAULT_MOTOR.exp_dq_q))
    i_ref: quantity("current") = float(DEFAULT_MOTOR.i_ref)
    sat_b: float = _coefficient()
    exp_b: float = _exponent(float(DEFAULT_MOTOR.exp_b))
    sat_bp: float = _coefficient()
    k_q: float = _coefficient()
    psi_n: quantity("flux") = 0.0
    sat_at_zero: Literal[0, 1] = 0
    hinkkanen: HinkkanenSpec | None = None
    lelli: LelliSpec | None = None
    delay_samples: float = Field(default=0.0, ge=0, le=100, allow_inf_nan=False)
    current_noise: quantity("current") | None = None
    speed_noise: quantity("speed") | None = None
    estimate: list[Literal["R", "Ld", "Lq", "lambda_m", "delay", "v_dead", "i_dead", "offset_d", "offset_q",
                           "offset_a", "offset_b", "alpha_R", "encoder_offset", "J", "B", "T_coulomb",
                           "T_load", "sat_d", "sat_q", "sat_dq", "sat_b", "sat_bp", "k_q",
                           "psi_n"]] | None = None


class MotorFile(BaseModel):
    """A loaded motor file: the nominal motor (the fit's prior) and what to estimate.

    Attributes:
        motor: nominal values of all parameters (bench effects included), SI.
        estimate: the parameters the user asks for, or None for "R, Ld, Lq,
            lambda_m, holding any the data cannot identify at the nominal
            value". Bench effects (v_dead, offsets, alpha_R) are estimated
            only when listed here.
        current_noise, speed_noise: the current and speed sensors' noise standard deviations (A,
            rad/s) where the file states them: they weigh a measured speed against the currents
            when the speed is a measured output (``--speed output``); else estimated from the data.
        delay_samples: the inverter's nominal PWM/computation delay (samples, may be
            fractional: 0.5, 1.5 where the PWM updates mid-period); also ``motor.delay``.
        source: the file path, for messages.
        defaulted: the keys that matter (:data:`REQUIRED_KEYS`) the file left out, which took
            the default motor's values (the CLI warns about them).
        tolerance: the specification of the ``[tolerance]`` table, ``{name: Tolerance}`` (limits in
            SI; empty: no specification, no pass/fail).
        mechanics_given: the file states J and B (the default motor has its own): a measured speed too
            coarse for an input can then be a second output, the speed simulated from them.
    """

    model_config = ConfigDict(frozen=True, arbitrary_types_allowed=True)
    motor: MotorParams
    estimate: tuple[str, ...] | None = None
    delay_samples: float = 0.0
    current_noise: float | None = None
    speed_noise: float | None = None
    source: str = "default motor"
    defaulted: tuple[str, ...] = ()
    tolerance: dict[str, Tolerance] = Field(default_factory=dict)
    mechanics_given: bool = True

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters to estimate, in drivecal's order."""
        if self.estimate is None:  # a motor without a magnet (a synchronous reluctance motor) holds lambda_m = 0
            return ESTIMATED if float(self.motor.lambda_m) != 0.0 else tuple(n for n in ESTIMATED if n != "lambda_m")
        return tuple(n for n in ESTIMABLE if n in self.estimate)


def motor_from_dict(data: dict, source: str = "motor") -> MotorFile:
    """A :class:`MotorFile` from the TOML table ``data``.

    Missing keys take the default motor's values; those of :data:`REQUIRED_KEYS` are listed in
    ``defaulted``. An empty table is refused: it would silently be the demo motor.
    """
    if not isinstance(data, dict):
        raise DrivecalError(f"{source}: a motor file is a TOML table of keys such as R, Ld, Lq, lambda_m, "
                            f"got {type(data).__name__}.")
    if not data:
        raise DrivecalError(f"{source}: the motor file is empty; give at least {', '.join(REQUIRED_KEYS)} of the "
                            "motor (see examples/motor.toml), or leave out --motor to use the built-in demo motor.")
    data = dict(data)
    tolerance_table = data.pop("tolerance", None)
    try:
        spec = MotorSpec.model_validate(data)
    except ValidationError as exc:
        tables = {"hinkkanen": HinkkanenSpec, "lelli": LelliSpec}
        in_law = [t for t in tables if all(e["loc"][:1] == (t,) for e in exc.errors())]  # a law table's own keys
        keys = (", ".join(tables[in_law[0]].model_fields) + f" (in [{in_law[0]}])" if in_law
                else ", ".join(MotorSpec.model_fields) + ", [tolerance]")
        raise explain(exc, source, "motor", keys) from None
    if not 1 <= spec.pole_pairs <= 1000:
        shown = spec.pole_pairs if abs(spec.pole_pairs) < 10**12 else "a huge number"
        raise DrivecalError(f"{source}: 'pole_pairs' must be a whole number from 1 to 1000, got {shown}.")
    values = spec.model_dump(exclude={"estimate", "delay_samples", "current_noise", "speed_noise", "hinkkanen",
                                      "lelli"})
    for key in ("current_noise", "speed_noise"):
        value = getattr(spec, key)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise DrivecalError(f"{source}: '{key}' is a noise standard deviation and must be positive, got {value!r}.")
    signed = ("T_load", "offset_d", "offset_q", "offset_a", "offset_b", "T_ref", "encoder_offset")
    zero_allowed = ("v_dead", "T_coulomb", "lambda_m") + MAGNETIC + EXPONENTS + BRIDGE + BRIDGE_SHAPE
    for name, value in values.items():
        if not math.isfinite(value):
            raise DrivecalError(f"{source}: '{name}' must be a finite number, got {value!r}.")
        if name == "v_dead" and value < 0:
            raise DrivecalError(f"{source}: 'v_dead' is a voltage magnitude and must be >= 0, got {value!r}.")
        if name == "lambda_m" and value < 0:
            raise DrivecalError(f"{source}: 'lambda_m' is the magnet's flux linkage and must be >= 0 (0: a "
                                f"synchronous reluctance motor, no magnet), got {value!r}.")
        if name == "T_coulomb" and value < 0:
            raise DrivecalError(f"{source}: 'T_coulomb' is a friction torque magnitude (it acts against the speed's "
                                f"sign) and must be >= 0, got {value!r}.")
        if not value > 0 and name not in signed + zero_allowed:
            raise DrivecalError(f"{source}: '{name}' must be a positive number, got {value!r}.")
    motor = MotorParams(**{k: float(v) for k, v in values.items()}, delay=float(spec.delay_samples))
    if spec.hinkkanen is not None and spec.lelli is not None:
        raise DrivecalError(f"{source}: the [hinkkanen] and [lelli] tables both give the magnetic law; keep one "
                            "([lelli] for a PM-assisted motor with iron bridges, [hinkkanen] for one without).")
    if spec.hinkkanen is not None or spec.lelli is not None:
        motor = _with_published_law(motor, spec.hinkkanen or spec.lelli, data, source)
    estimate = None if spec.estimate is None else tuple(spec.estimate)
    if estimate is not None and not estimate:
        raise DrivecalError(f"{source}: 'estimate' is empty; list at least one of R, Ld, Lq, lambda_m.")
    if estimate is not None and "lambda_m" in estimate and float(motor.lambda_m) == 0.0:
        raise DrivecalError(f"{source}: 'estimate' names lambda_m but 'lambda_m' is 0 (no magnet); give the nominal "
                            "flux linkage, or leave lambda_m out of 'estimate' for a synchronous reluctance motor.")
    given = set(data) | ({"Ld", "Lq"} if spec.hinkkanen is not None else set()) | (
        {"Ld", "Lq", "lambda_m"} if spec.lelli is not None else set())
    defaulted = tuple(k for k in REQUIRED_KEYS if k not in given)
    tolerance = {} if tolerance_table is None else tolerances_of(tolerance_table, motor.all_values(), source)
    return MotorFile(motor=motor, estimate=estimate, delay_samples=spec.delay_samples, current_noise=spec.current_noise,
                     speed_noise=spec.speed_noise, source=source,
                     defaulted=defaulted, tolerance=tolerance, mechanics_given="J" in data and "B" in data)


def _with_published_law(motor: MotorParams, law: HinkkanenSpec, data: dict, source: str) -> MotorParams:
    """``motor`` with a ``[hinkkanen]`` or ``[lelli]`` table's law (stated at the file's ``i_ref``); a key that would
    say it twice is refused."""
    lelli = isinstance(law, LelliSpec)
    table = "lelli" if lelli else "hinkkanen"
    own = ("Ld", "Lq") + MAGNETIC + EXPONENTS + ((("lambda_m",) + BRIDGE + BRIDGE_SHAPE) if lelli else ())
    twice = [k for k in own if k in data]
    if twice:
        given = ("Ld, Lq and lambda_m from the law at zero current, the saturation and the bridge from the "
                 "table" if lelli else "Ld = 1/a_d0, Lq = 1/a_q0, the saturation from a_dd, a_qq, a_dq")
        raise DrivecalError(f"{source}: '{twice[0]}' and the [{table}] table both give the magnetic law; leave "
                            f"'{twice[0]}' out ({given}).")
    build = from_lelli if lelli else from_hinkkanen
    return build(motor, i_ref=float(motor.i_ref), **law.model_dump())


def load_motor(path: str | Path | None) -> MotorFile:
    """Read a motor TOML file; ``None`` gives the default 48 V motor."""
    if path is None:
        return MotorFile(motor=DEFAULT_MOTOR)
    return motor_from_dict(read_toml(path), str(path))
