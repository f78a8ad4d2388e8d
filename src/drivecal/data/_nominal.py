"""A motor file's nominal values and specification, read without JAX where the file allows it.

``drivecal fleet-report --motor`` draws the nominal values and the ``[tolerance]`` limits; they are what
``load_motor`` gives, but a plain motor file's values need no motor model (``physics``, JAX): they are read and
checked as plain numbers (``data._motor_spec``). A file that states its magnetic law as published
(``[hinkkanen]``, ``[lelli]``) is loaded whole: that law gives the motor's Ld, Lq (and lambda_m).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from ._motor_spec import read_motor_table
from ._tolerance import Tolerance, tolerances_of
from .._units import read_toml


class MotorNominal(NamedTuple):
    """A motor file's nominal motor and specification (:func:`motor_nominal`).

    Attributes:
        values: every parameter's and setting's nominal value, SI (``physics.MotorParams.all_values()``).
        tolerance: the ``[tolerance]`` table's limits, ``{name: Tolerance}`` (SI; empty: no specification).
        defaulted: the keys of ``data._motor_spec.REQUIRED_KEYS`` the file leaves out (they took the default
            motor's values).
    """

    values: dict[str, float]
    tolerance: dict[str, Tolerance]
    defaulted: tuple[str, ...]


def motor_nominal(path: str | Path) -> MotorNominal:
    """The nominal values, tolerance limits and defaulted keys of the motor file at ``path``, as ``load_motor``
    gives them; without JAX unless the file states its law as published (``[hinkkanen]``, ``[lelli]``)."""
    table = read_motor_table(read_toml(path), str(path))
    if table.spec.hinkkanen is not None or table.spec.lelli is not None:
        from ._motor_file import motor_file_of

        motor_file = motor_file_of(table, str(path))
        return MotorNominal(motor_file.motor.all_values(), motor_file.tolerance, motor_file.defaulted)
    values = {**table.values, "delay": float(table.spec.delay_samples)}
    tolerance = {} if table.tolerance_table is None else tolerances_of(table.tolerance_table, values, str(path))
    return MotorNominal(values, tolerance, table.defaulted)
