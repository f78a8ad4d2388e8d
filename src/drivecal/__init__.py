"""drivecal: calibrate a PMSM's R, Ld, Lq and lambda_m from bench data.

The package follows the data flow; each sub-package imports only those before it::

    physics -> plan -> model -> data -> bench -> identify -> fitting -> diagnose
            -> design -> report -> fleet -> demo -> cli

The public API below is re-exported from the sub-packages and loaded on first
use, so ``import drivecal`` (and ``drivecal --help``) does not start JAX.
Everything numeric runs in float64 (Fisher matrices need it): the first
sub-package that loads switches JAX to double precision for the process
(``drivecal._setup``).
"""

from __future__ import annotations

import importlib as _importlib
import sys as _sys

from . import _legacy
from ._version import __version__
from .errors import DataError, DrivecalError, PlanError

# name -> the sub-package that defines it (loaded on first access).
_API: dict[str, str] = {
    "BenchData": "data",
    "Calibration": "results",
    "CurrentLoopDesign": "report",
    "DEFAULT_MOTOR": "physics",
    "DemoResult": "demo",
    "DesignReport": "design",
    "DesignRun": "demo",
    "ESTIMABLE": "physics",
    "ESTIMATED": "physics",
    "Experiment": "model",
    "FIXED": "physics",
    "FitOptions": "fitting",
    "Identifiability": "identify",
    "MotorFile": "data",
    "MotorParams": "physics",
    "NUISANCE": "physics",
    "MECHANICAL": "physics",
    "OptimalDesign": "design",
    "Plan": "plan",
    "SaturationCheck": "diagnose",
    "Segment": "plan",
    "SegmentData": "data",
    "UNITS": "physics",
    "Verdict": "results",
    "assess_design": "design",
    "assess_identifiability": "identify",
    "auto_design": "design",
    "auto_plan": "design",
    "bench_from_frame": "data",
    "build_result": "report",
    "check_requested": "identify",
    "check_saturation": "diagnose",
    "datasheet_guess": "demo",
    "default_plan": "plan",
    "design_current_loop": "report",
    "dq_derivatives": "physics",
    "engine_bench": "bench",
    "fit": "diagnose",
    "fit_currents": "fitting",
    "judge_fit": "diagnose",
    "fleet": None,
    "load_bench": "data",
    "load_motor": "data",
    "load_plan": "plan",
    "load_result": "results",
    "locked_q_step_plan": "plan",
    "motor_from_dict": "data",
    "optimize_plan": "design",
    "plan_from_dict": "plan",
    "plan_toml": "plan",
    "predict_currents": "model",
    "run_demo": "demo",
    "sensitivity_jacobian": "identify",
    "simulate_states": "model",
    "step_engine_bench": "bench",
    "synthetic_bench": "bench",
    "waveforms": "plan",
    "write_demo_outputs": "demo",
    "write_html_report": "report",
    "write_plan": "plan",
}

__all__ = sorted([*_API, "DataError", "DrivecalError", "PlanError", "__version__"])


def __getattr__(name: str):
    if name not in _API:
        raise AttributeError(f"module 'drivecal' has no attribute {name!r}")
    sub = _API[name]
    if sub is None:  # a sub-package exported as itself
        value = _importlib.import_module(f"{__name__}.{name}")
    else:
        value = getattr(_importlib.import_module(f"{__name__}.{sub}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))


# Old flat module paths (drivecal.forward, drivecal.fit, ...) keep importing for one release.
_legacy.install(_sys.modules[__name__])
