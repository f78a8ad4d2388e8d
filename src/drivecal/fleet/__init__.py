"""Many motors: batch calibration of bench files, process placement, fleet checks and the fleet report.

The names below are loaded from their modules on first use: the fleet report (``_report``) is plain
pandas and matplotlib, so ``drivecal fleet-report`` loads nothing of JAX or the fitting stack; the
batch's modules load them (each through the sub-packages it imports, which set up JAX first).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names as _lazy_names

if TYPE_CHECKING:  # the names' origins, for type checkers and the API reference; loaded at run time by __getattr__
    from ._batch import (BatchSummary, STATUS_CALIBRATED, STATUS_INVALID, STATUS_NOT_CONVERGED, STATUS_PARTIAL,
                         calibrate_files, parts_dir, run_batch)
    from ._checks import fleet_checks, residual_diagnostics, spec_checks
    from ._inputs import discover, motors_in
    from ._report import fleet_histograms, fleet_trends, load_results, render_fleet_html, write_fleet_report
    from ._report_stats import DEFAULT_OUTLIER_Z
    from ._runners import tune_for_batch
    from ._synthetic import predict_currents_and_speed, synthetic_fleet

# The module of this package that defines each name (loaded on first access), as imported above.
_MODULES: dict[str, tuple[str, ...]] = {
    "_batch": ("BatchSummary", "STATUS_CALIBRATED", "STATUS_INVALID", "STATUS_NOT_CONVERGED", "STATUS_PARTIAL",
               "calibrate_files", "parts_dir", "run_batch"),
    "_checks": ("fleet_checks", "residual_diagnostics", "spec_checks"),
    "_inputs": ("discover", "motors_in"),
    "_report": ("fleet_histograms", "fleet_trends", "load_results", "render_fleet_html", "write_fleet_report"),
    "_report_stats": ("DEFAULT_OUTLIER_Z",),
    "_runners": ("tune_for_batch",),
    "_synthetic": ("predict_currents_and_speed", "synthetic_fleet"),
}

__all__ = ["BatchSummary", "DEFAULT_OUTLIER_Z", "STATUS_CALIBRATED", "STATUS_INVALID", "STATUS_NOT_CONVERGED",
           "STATUS_PARTIAL", "calibrate_files", "discover", "motors_in", "fleet_checks", "fleet_histograms",
           "fleet_trends", "load_results", "parts_dir", "predict_currents_and_speed", "render_fleet_html",
           "residual_diagnostics", "run_batch", "spec_checks", "synthetic_fleet", "tune_for_batch", "write_fleet_report"]


__getattr__, __dir__ = _lazy_names(__name__, _MODULES)
