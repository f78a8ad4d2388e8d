"""The motor's laws, once: the dq equations, parameters and units, the inverter's voltage error."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._inverter import (dead_time_error)
from ._motor import (ADDITIVE_SCALE, DEFAULT_MOTOR, DESCRIPTIONS, DqCoefficients, ESTIMABLE, ESTIMATED, FIXED, MotorParams, NUISANCE, SETTINGS, UNITS, dq_coefficients, dq_derivatives, dq_derivatives_from, from_search, parameter_values, resistance_at, search_scale, to_search)

__all__ = ["ADDITIVE_SCALE", "DEFAULT_MOTOR", "DESCRIPTIONS", "DqCoefficients", "ESTIMABLE", "ESTIMATED", "FIXED", "MotorParams", "NUISANCE", "SETTINGS", "UNITS", "dead_time_error", "dq_coefficients", "dq_derivatives", "dq_derivatives_from", "from_search", "parameter_values", "resistance_at", "search_scale", "to_search"]
