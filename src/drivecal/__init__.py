"""drivecal: calibrate a PMSM's R, Ld, Lq and lambda_m from bench data.

plan + motor -> bench data -> forward model -> identifiability -> fit -> calibration.
Everything numeric runs in float64 (Fisher matrices need it), so importing
drivecal switches JAX to double precision.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from .bench import engine_bench, synthetic_bench  # noqa: E402
from .data import BenchData, SegmentData  # noqa: E402
from .errors import DataError, DrivecalError, PlanError  # noqa: E402
from .fit import Calibration, FitOptions, fit, fit_currents, fit_history  # noqa: E402
from .forward import Experiment, predict_currents, simulate_states  # noqa: E402
from .identify import Identifiability, assess_identifiability, sensitivity_jacobian  # noqa: E402
from .motor import DEFAULT_MOTOR, ESTIMATED, FIXED, UNITS, MotorParams, dq_derivatives  # noqa: E402
from .plan import Plan, Segment, default_plan, locked_q_step_plan  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BenchData",
    "Calibration",
    "DEFAULT_MOTOR",
    "DataError",
    "DrivecalError",
    "ESTIMATED",
    "Experiment",
    "FIXED",
    "FitOptions",
    "Identifiability",
    "MotorParams",
    "Plan",
    "PlanError",
    "Segment",
    "SegmentData",
    "UNITS",
    "assess_identifiability",
    "default_plan",
    "dq_derivatives",
    "engine_bench",
    "fit",
    "fit_currents",
    "fit_history",
    "locked_q_step_plan",
    "predict_currents",
    "sensitivity_jacobian",
    "simulate_states",
    "synthetic_bench",
    "__version__",
]
