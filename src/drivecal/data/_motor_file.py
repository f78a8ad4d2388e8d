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

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

from ..errors import DrivecalError
from ..physics import (BRIDGE, BRIDGE_SHAPE, DEFAULT_MOTOR, ESTIMABLE, ESTIMATED, EXPONENTS, MAGNETIC, MotorParams,
                       from_hinkkanen, from_lelli)
from ._tolerance import Tolerance, tolerances_of
from .._units import read_toml

if TYPE_CHECKING:  # the file's schema (pydantic) is imported where a file is read: the default motor needs none
    from ._motor_spec import HinkkanenSpec, MotorTable


@dataclasses.dataclass(frozen=True)
class MotorFile:
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

    motor: MotorParams
    estimate: tuple[str, ...] | None = None
    delay_samples: float = 0.0
    current_noise: float | None = None
    speed_noise: float | None = None
    source: str = "default motor"
    defaulted: tuple[str, ...] = ()
    tolerance: dict[str, Tolerance] = dataclasses.field(default_factory=dict)
    mechanics_given: bool = True

    def replace(self, **changes: object) -> MotorFile:
        """A copy with the named fields changed, e.g. ``motor_file.replace(estimate=("R", "Ld"))``."""
        return dataclasses.replace(self, **changes)

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters to estimate, in drivecal's order."""
        if self.estimate is None:  # a motor without a magnet (a synchronous reluctance motor) holds lambda_m = 0
            return ESTIMATED if float(self.motor.lambda_m) != 0.0 else tuple(n for n in ESTIMATED if n != "lambda_m")
        return tuple(n for n in ESTIMABLE if n in self.estimate)


def motor_from_dict(data: dict, source: str = "motor") -> MotorFile:
    """A :class:`MotorFile` from the TOML table ``data`` (checked by :func:`read_motor_table`).

    Missing keys take the default motor's values; those of :data:`REQUIRED_KEYS` are listed in
    ``defaulted``. An empty table is refused: it would silently be the demo motor.
    """
    from ._motor_spec import read_motor_table

    return motor_file_of(read_motor_table(data, source), source)


def motor_file_of(table: MotorTable, source: str) -> MotorFile:
    """The :class:`MotorFile` of a checked motor table (:func:`read_motor_table`): the motor built, its law applied."""
    from ._motor_spec import check_estimate_lambda_m

    spec = table.spec
    motor = MotorParams(**table.values, delay=float(spec.delay_samples))
    if spec.hinkkanen is not None or spec.lelli is not None:
        motor = _with_published_law(motor, spec.hinkkanen or spec.lelli, table.data, source)
    if spec.lelli is not None:  # the law gave lambda_m
        check_estimate_lambda_m(spec.estimate, float(motor.lambda_m), source)
    tolerance = ({} if table.tolerance_table is None
                 else tolerances_of(table.tolerance_table, motor.all_values(), source))
    return MotorFile(motor=motor, estimate=None if spec.estimate is None else tuple(spec.estimate),
                     delay_samples=spec.delay_samples, current_noise=spec.current_noise,
                     speed_noise=spec.speed_noise, source=source, defaulted=table.defaulted, tolerance=tolerance,
                     mechanics_given="J" in table.data and "B" in table.data)


def _with_published_law(motor: MotorParams, law: HinkkanenSpec, data: dict, source: str) -> MotorParams:
    """``motor`` with a ``[hinkkanen]`` or ``[lelli]`` table's law (stated at the file's ``i_ref``); a key that would
    say it twice is refused."""
    from ._motor_spec import LelliSpec

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
