"""The fit: options, Levenberg-Marquardt solve (single, batched, tiled), start from the data, the Calibration result."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._fit import (Calibration, FitOptions, LINEARISED_TANGENTS_MAX_BATCH, SHARED_JACOBIAN_PROBE, SOLVE_TILE, fit, fit_currents, result_message)
from ._initial import (SPAN, START_TILE, equation_error_start, start_from_data)

__all__ = ["Calibration", "FitOptions", "LINEARISED_TANGENTS_MAX_BATCH", "SHARED_JACOBIAN_PROBE", "SOLVE_TILE", "SPAN", "START_TILE", "equation_error_start", "fit", "fit_currents", "result_message", "start_from_data"]
