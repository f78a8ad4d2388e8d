"""The results of a calibration: the Calibration type, the result JSON (its one owner) and the status vocabulary.

Reading, printing or saving a result needs nothing of the solver: this layer
sits below :mod:`drivecal.fitting`, which produces Calibrations.
"""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._calibration import NOT_JUDGED, Calibration, result_message
from ._html import escape, format_number, summary_html
from ._record import (NOT_RECORDED, VERSIONED, bench_sha256, content_sha256, demo_document, file_sha256, json_ready,
                      load_result, result_document, result_fits, segment_residuals, select_fit, software_versions)
from ._spec import FAIL, INCONCLUSIVE, PASS, ParameterJudgement, SpecJudgement, judge_arrays, judge_spec, motor_outcome
from ._verdict import Verdict
from .._status import Spec, Status, solver_code, solver_message

__all__ = ["Calibration", "FAIL", "INCONCLUSIVE", "NOT_JUDGED", "NOT_RECORDED", "PASS", "ParameterJudgement", "Spec", "SpecJudgement", "Status", "VERSIONED", "Verdict",
           "bench_sha256", "content_sha256", "demo_document", "escape", "file_sha256", "format_number", "json_ready", "judge_arrays",
           "judge_spec", "load_result", "motor_outcome", "result_document", "result_fits", "result_message",
           "segment_residuals", "select_fit", "software_versions", "solver_code", "solver_message", "summary_html"]
