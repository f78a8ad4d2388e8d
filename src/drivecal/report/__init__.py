"""Outputs: the result JSON, HTML report, figures, current-loop gains."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._gains import (AXES, AxisGains, CurrentLoopDesign, MAX_BANDWIDTH_FRACTION, Spread, design_current_loop, loop_metrics, open_loop, pi_gains)
from ._html import (CSS, FIG_DPI, figure_data_uri, fit_section_html, render_html, summary_html, verdict_html, write_html_report)
from ._record import (VERSIONED, bench_sha256, build_result, content_sha256, file_sha256, load_result, result_fits, segment_residuals, segment_traces, select_fit, software_versions)

__all__ = ["AXES", "AxisGains", "CSS", "CurrentLoopDesign", "FIG_DPI", "MAX_BANDWIDTH_FRACTION", "Spread", "VERSIONED", "bench_sha256", "build_result", "content_sha256", "design_current_loop", "figure_data_uri", "file_sha256", "fit_section_html", "load_result", "loop_metrics", "open_loop", "pi_gains", "render_html", "result_fits", "segment_residuals", "segment_traces", "select_fit", "software_versions", "summary_html", "verdict_html", "write_html_report"]
