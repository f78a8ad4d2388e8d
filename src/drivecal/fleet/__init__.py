"""Many motors: batch calibration of bench files, process placement, fleet checks and the fleet report."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._batch import (BatchSummary, STATUS_CALIBRATED, STATUS_INVALID, STATUS_NOT_CONVERGED, STATUS_PARTIAL,
                     calibrate_files, parts_dir, run_batch)
from ._inputs import discover, motors_in
from ._checks import DEFAULT_OUTLIER_Z, fleet_checks, residual_diagnostics, spec_checks
from ._report import fleet_histograms, fleet_trends, load_results, render_fleet_html, write_fleet_report
from ._runners import tune_for_batch
from ._synthetic import predict_currents_and_speed, synthetic_fleet

__all__ = ["BatchSummary", "DEFAULT_OUTLIER_Z", "STATUS_CALIBRATED", "STATUS_INVALID", "STATUS_NOT_CONVERGED",
           "STATUS_PARTIAL", "calibrate_files", "discover", "motors_in", "fleet_checks", "fleet_histograms", "fleet_trends",
           "load_results", "parts_dir", "predict_currents_and_speed", "render_fleet_html", "residual_diagnostics",
           "run_batch", "spec_checks", "synthetic_fleet", "tune_for_batch", "write_fleet_report"]
