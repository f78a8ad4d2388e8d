"""drivecal: calibrate a PMSM's R, Ld, Lq and lambda_m from bench data.

plan + motor -> bench data -> forward model -> identifiability -> fit -> calibration.
Everything numeric runs in float64 (Fisher matrices need it), so importing
drivecal switches JAX to double precision.
"""

import os as _os
from pathlib import Path as _Path


def _cache_enabled() -> bool:
    return _os.environ.get("DRIVECAL_JAX_CACHE", "1").strip().lower() not in ("0", "off", "false", "no")


if _cache_enabled():
    # XLA:CPU logs a harmless machine-feature line at ERROR level on every
    # cache hit; keep C++ logging to fatal errors unless the user chose a level.
    _os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "3")

import jax as _jax  # noqa: E402

_jax.config.update("jax_enable_x64", True)


def _enable_compilation_cache() -> None:
    """Keep compiled kernels on disk so a second drivecal process does not recompile.

    On by default; ``DRIVECAL_JAX_CACHE=0`` turns it off. Kernels go to
    ``$XDG_CACHE_HOME/drivecal/jax`` (``~/.cache/drivecal/jax``), or to
    ``DRIVECAL_JAX_CACHE_DIR``.
    """
    if not _cache_enabled():
        return
    base = _os.environ.get("XDG_CACHE_HOME") or str(_Path.home() / ".cache")
    path = _os.environ.get("DRIVECAL_JAX_CACHE_DIR") or str(_Path(base) / "drivecal" / "jax")
    _jax.config.update("jax_compilation_cache_dir", path)
    # drivecal's kernels compile in well under JAX's default 1 s threshold.
    _jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


_enable_compilation_cache()

from .bench import engine_bench, synthetic_bench  # noqa: E402
from .data import BenchData, SegmentData, bench_from_frame, load_bench  # noqa: E402
from .errors import DataError, DrivecalError, PlanError  # noqa: E402
from .demo import DemoResult, DesignRun, datasheet_guess, run_demo, write_demo_outputs  # noqa: E402
from .fit import Calibration, FitOptions, fit, fit_currents  # noqa: E402
from .gains import CurrentLoopDesign, design_current_loop  # noqa: E402
from .html import write_html_report  # noqa: E402
from .record import build_result, load_result  # noqa: E402
from .forward import Experiment, predict_currents, simulate_states  # noqa: E402
from .identify import Identifiability, assess_identifiability, check_requested, sensitivity_jacobian  # noqa: E402
from .motor import DEFAULT_MOTOR, ESTIMABLE, ESTIMATED, FIXED, NUISANCE, UNITS, MotorParams, dq_derivatives  # noqa: E402
from .plan import Plan, Segment, default_plan, locked_q_step_plan  # noqa: E402
from .config import MotorFile, load_motor, load_plan, motor_from_dict, plan_from_dict  # noqa: E402
from .design import DesignReport, assess_design  # noqa: E402
from . import fleet, waveforms  # noqa: E402
from .saturation import SaturationCheck, check_saturation  # noqa: E402
from .optimal import OptimalDesign, optimize_plan  # noqa: E402
from .autoplan import auto_design, auto_plan  # noqa: E402
from .stepbench import step_engine_bench  # noqa: E402
from .config import plan_toml, write_plan  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BenchData",
    "Calibration",
    "CurrentLoopDesign",
    "DEFAULT_MOTOR",
    "DataError",
    "DrivecalError",
    "ESTIMATED",
    "ESTIMABLE",
    "NUISANCE",
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
    "build_result",
    "default_plan",
    "design_current_loop",
    "dq_derivatives",
    "engine_bench",
    "fit",
    "fit_currents",
    "locked_q_step_plan",
    "load_result",
    "predict_currents",
    "sensitivity_jacobian",
    "simulate_states",
    "synthetic_bench",
    "write_html_report",
    "DemoResult",
    "DesignRun",
    "datasheet_guess",
    "run_demo",
    "write_demo_outputs",
    "DesignReport",
    "MotorFile",
    "assess_design",
    "check_requested",
    "bench_from_frame",
    "load_bench",
    "load_motor",
    "load_plan",
    "motor_from_dict",
    "plan_from_dict",
    "waveforms",
    "fleet",
    "SaturationCheck",
    "check_saturation",
    "OptimalDesign",
    "optimize_plan",
    "auto_design",
    "auto_plan",
    "step_engine_bench",
    "plan_toml",
    "write_plan",
    "__version__",
]
