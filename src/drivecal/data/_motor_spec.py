"""A motor file's table read and checked as plain numbers: the schema of every key, the checks of every value.

Plain Python and pydantic, no JAX: ``data._motor_file`` builds the motor (``physics.MotorParams``) from what
:func:`read_motor_table` returns, and a command that only needs the nominal values and the ``[tolerance]`` limits
of a motor file (``drivecal fleet-report --motor``) reads them from here (``data._nominal``) and loads no JAX.
"""

from __future__ import annotations

import math
from typing import Any, Literal, NamedTuple

from pydantic import Field, ValidationError

from ..errors import DrivecalError
from .._parameters import BRIDGE, BRIDGE_SHAPE, DEFAULT_VALUES as _D, EXPONENTS, MAGNETIC
from .._schema import StrictModel, explain, quantity


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
    S: float = _exponent(_D["exp_d"])
    a_q0: float = _coefficient(required=True)
    a_qq: float = _coefficient()
    T: float = _exponent(_D["exp_q"])
    a_dq: float = _coefficient()
    U: float = _exponent(_D["exp_dq_d"])
    V: float = _exponent(_D["exp_dq_q"])


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
    W: float = _exponent(_D["exp_b"])


class MotorSpec(StrictModel):
    R: quantity("resistance") = _D["R"]
    Ld: quantity("inductance") = _D["Ld"]
    Lq: quantity("inductance") = _D["Lq"]
    lambda_m: quantity("flux") = _D["lambda_m"]
    pole_pairs: int = int(_D["pole_pairs"])
    J: quantity("inertia") = _D["J"]
    B: quantity("friction") = _D["B"]
    T_load: quantity("torque") = 0.0
    T_coulomb: quantity("torque") = 0.0
    w_coulomb: quantity("speed") = _D["w_coulomb"]
    v_dead: quantity("voltage") = 0.0
    i_dead: quantity("current") = _D["i_dead"]
    offset_d: quantity("current") = 0.0
    offset_q: quantity("current") = 0.0
    offset_a: quantity("current") = 0.0
    offset_b: quantity("current") = 0.0
    alpha_R: quantity("temperature coefficient") = _D["alpha_R"]
    T_ref: quantity("temperature") = _D["T_ref"]
    encoder_offset: quantity("rotor angle") = 0.0
    sat_d: float = _coefficient()
    sat_q: float = _coefficient()
    sat_dq: float = _coefficient()
    exp_d: float = _exponent(_D["exp_d"])
    exp_q: float = _exponent(_D["exp_q"])
    exp_dq_d: float = _exponent(_D["exp_dq_d"])
    exp_dq_q: float = _exponent(_D["exp_dq_q"])
    i_ref: quantity("current") = _D["i_ref"]
    sat_b: float = _coefficient()
    exp_b: float = _exponent(_D["exp_b"])
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


class MotorTable(NamedTuple):
    """A motor file's table, checked (:func:`read_motor_table`).

    Attributes:
        spec: the validated keys (units converted to SI).
        values: the motor's parameters and settings as the file gives them, SI floats (every
            ``physics.MotorParams`` field but ``delay``, which is ``spec.delay_samples``); a law table
            (``spec.hinkkanen``, ``spec.lelli``) changes some of them when the motor is built.
        data: the table without its ``[tolerance]`` table.
        tolerance_table: the ``[tolerance]`` table as written, or None.
        defaulted: the keys of :data:`REQUIRED_KEYS` the file (and its law table) leaves out.
    """

    spec: MotorSpec
    values: dict[str, float]
    data: dict[str, Any]
    tolerance_table: Any
    defaulted: tuple[str, ...]


def read_motor_table(data: dict, source: str = "motor") -> MotorTable:
    """Check the TOML table ``data`` of a motor file; a wrong key or value is one sentence naming ``source``.

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
    if spec.hinkkanen is not None and spec.lelli is not None:
        raise DrivecalError(f"{source}: the [hinkkanen] and [lelli] tables both give the magnetic law; keep one "
                            "([lelli] for a PM-assisted motor with iron bridges, [hinkkanen] for one without).")
    if spec.estimate is not None and not spec.estimate:
        raise DrivecalError(f"{source}: 'estimate' is empty; list at least one of R, Ld, Lq, lambda_m.")
    if spec.lelli is None:  # else the law gives lambda_m: checked once the motor is built
        check_estimate_lambda_m(spec.estimate, values["lambda_m"], source)
    given = set(data) | ({"Ld", "Lq"} if spec.hinkkanen is not None else set()) | (
        {"Ld", "Lq", "lambda_m"} if spec.lelli is not None else set())
    return MotorTable(spec, {k: float(v) for k, v in values.items()}, data, tolerance_table,
                      tuple(k for k in REQUIRED_KEYS if k not in given))


def check_estimate_lambda_m(estimate: list[str] | tuple[str, ...] | None, lambda_m: float, source: str) -> None:
    """Refuse an ``estimate`` that names lambda_m for a motor without a magnet (``lambda_m`` 0, Wb)."""
    if estimate is not None and "lambda_m" in estimate and lambda_m == 0.0:
        raise DrivecalError(f"{source}: 'estimate' names lambda_m but 'lambda_m' is 0 (no magnet); give the nominal "
                            "flux linkage, or leave lambda_m out of 'estimate' for a synchronous reluctance motor.")
