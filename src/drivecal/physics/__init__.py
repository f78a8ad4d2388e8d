"""The motor's laws, once: the dq equations, parameters and units, the Clarke/Park transforms, the inverter's
voltage error and delay, the magnetic saturation (flux linkages as states), the current sensors' offsets, the encoder's offset."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._inverter import bridge_error, dead_time_error, stable_dead_width, switching_ripple
from .._parameters import (ADDITIVE_SCALE, BRIDGE, BRIDGE_SHAPE, DESCRIPTIONS, ESTIMABLE, ESTIMATED, EXPONENTS, FIXED,
                           MAGNETIC, MECHANICAL, NUISANCE, SETTINGS, UNITS)
from ._magnetics import (EXPONENT_CANDIDATES, MagnetPoint, currents_of_flux, flux_derivatives, flux_of_currents,
                         flux_torque, from_hinkkanen, from_lelli, has_bridge, hinkkanen_coefficients, hinkkanen_law,
                         incremental_inductances, is_saturating, magnet_point)
from ._motor import (DEFAULT_MOTOR, DqCoefficients, MotorParams, coulomb_friction, dq_coefficients, dq_derivatives,
                     dq_derivatives_from, from_search, parameter_values, resistance_at, search_scale, to_search,
                     with_d_flux)
from ._sensors import delayed, encoder_frame, rotor_frame, sensor_offsets, with_dq_offsets
from ._transforms import abc_to_dq, clarke, dq_to_abc, inverse_clarke, inverse_park, park

__all__ = ["BRIDGE", "BRIDGE_SHAPE", "EXPONENT_CANDIDATES", "EXPONENTS", "MAGNETIC", "MagnetPoint", "currents_of_flux",
           "flux_derivatives", "flux_of_currents", "flux_torque", "from_hinkkanen", "from_lelli", "has_bridge",
           "hinkkanen_coefficients", "hinkkanen_law", "incremental_inductances", "is_saturating", "magnet_point",
           "ADDITIVE_SCALE", "DEFAULT_MOTOR", "DESCRIPTIONS", "DqCoefficients", "ESTIMABLE", "ESTIMATED", "FIXED",
           "MECHANICAL", "MotorParams", "NUISANCE", "SETTINGS", "UNITS", "abc_to_dq", "clarke", "coulomb_friction",
           "bridge_error", "dead_time_error", "stable_dead_width", "switching_ripple", "delayed", "encoder_frame",
           "dq_coefficients", "dq_derivatives", "dq_derivatives_from", "dq_to_abc", "from_search", "inverse_clarke",
           "inverse_park", "parameter_values", "park", "resistance_at", "rotor_frame", "search_scale",
           "sensor_offsets", "to_search", "with_d_flux", "with_dq_offsets"]
