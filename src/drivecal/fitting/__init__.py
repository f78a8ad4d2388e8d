"""The fit: options, the Levenberg-Marquardt solve (single, batched, tiled) and its start from the data.

Produces :class:`drivecal.results.Calibration` (re-exported here for the old import path).
"""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ..results import Calibration
from ._fit import fit, fit_currents, fit_setup
from ._initial import SPAN, START_TILE, equation_error_start, start_from_data
from ._options import FitOptions
from ._solver import LINEARISED_TANGENTS_MAX_BATCH, SHARED_JACOBIAN_PROBE, SOLVE_TILE

__all__ = ["Calibration", "FitOptions", "LINEARISED_TANGENTS_MAX_BATCH", "SHARED_JACOBIAN_PROBE", "SOLVE_TILE", "SPAN",
           "START_TILE", "equation_error_start", "fit", "fit_currents", "fit_setup", "start_from_data"]
