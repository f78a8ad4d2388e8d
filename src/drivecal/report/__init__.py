"""Outputs: a fit's result JSON filled in (traces, diagnostics, verdict), the HTML report, current-loop gains.

Figures are in :mod:`drivecal.report.plots` (it loads matplotlib; import it when you draw).
"""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._firmware_loop import (MIN_PHASE_MARGIN, design_gains, loop_figures, loop_gain_for, loop_metrics, open_loop,
                             pi_gains, reachable)
from ._gains import AXES, MAX_BANDWIDTH_FRACTION, SPECS, AxisGains, CurrentLoopDesign, Spread, design_current_loop
from ._firmware import SQRT3, FirmwareConstant, FirmwareGains, firmware_gains, to_fixed
from ._firmware_header import c_header
from ._html import FILE_DPI, fit_figure_jobs, fit_section_html, render_html, spec_html, verdict_html, write_html_report
from .._page import CSS, FIG_DPI, figure_data_uri  # the HTML pages' (the fleet report's too)
from ._record import build_result
from ..diagnose import segment_traces  # its home before drivecal.diagnose computed the verdicts
# drivecal 0.1's flat `drivecal.report` module (atomic output, the plan as JSON) and `drivecal.record`'s readers,
# importable from here for one release; their homes are drivecal._io, drivecal.plan and drivecal.results.
from .._io import atomic_path, prepare_output_dir, save_figure, write_json
from ..plan import plan_to_dict
from ..results import load_result, result_fits, select_fit

__all__ = ["AXES", "AxisGains", "CSS", "CurrentLoopDesign", "FIG_DPI", "FILE_DPI", "FirmwareConstant", "FirmwareGains",
           "MAX_BANDWIDTH_FRACTION", "MIN_PHASE_MARGIN", "SPECS", "SQRT3", "Spread", "atomic_path", "build_result",
           "c_header", "design_current_loop", "design_gains", "figure_data_uri", "firmware_gains", "fit_figure_jobs", "fit_section_html",
           "load_result", "loop_figures", "loop_gain_for", "loop_metrics", "open_loop", "pi_gains", "plan_to_dict",
           "prepare_output_dir", "reachable", "render_html", "result_fits", "save_figure", "segment_traces",
           "select_fit", "spec_html", "to_fixed", "verdict_html", "write_html_report", "write_json"]
