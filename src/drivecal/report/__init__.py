"""Outputs: a fit's result JSON filled in (traces, diagnostics, verdict), the HTML report, current-loop gains.

Figures are in :mod:`drivecal.report.plots` (it loads matplotlib; import it when you draw).
"""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._gains import (AXES, MAX_BANDWIDTH_FRACTION, AxisGains, CurrentLoopDesign, Spread, design_current_loop,
                     loop_metrics, open_loop, pi_gains)
from ._html import CSS, FIG_DPI, figure_data_uri, fit_section_html, render_html, verdict_html, write_html_report
from ._record import build_result, segment_traces
from ..results import content_sha256, load_result, result_fits, select_fit  # TODO(lead): importers move to drivecal.results

__all__ = ["AXES", "CSS", "FIG_DPI", "MAX_BANDWIDTH_FRACTION", "AxisGains", "CurrentLoopDesign", "Spread",
           "build_result", "design_current_loop", "figure_data_uri", "fit_section_html", "loop_metrics", "open_loop",
           "pi_gains", "render_html", "segment_traces", "verdict_html", "write_html_report"]
