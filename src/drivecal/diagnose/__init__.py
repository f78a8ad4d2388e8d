"""After the fit: residual checks, unmodelled bench effects, saturation check, the verdict; ``fit``: a fit judged."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._mismatch import (ALPHA, ANGLE_EFFECTS, BRIDGE_EFFECTS, EFFECTS, MAGNETIC_EFFECTS, Score, effect_signatures,
                        prepare_unmodelled_effects, score_test, unmodelled_effects, untested_effects)
from ._judge import fit, fit_diagnostics, judge_fit, segment_traces
from ._saturation import LevelEstimate, MIN_LEVEL_RATIO, SaturationCheck, Z_LIMIT, check_saturation
from ._verdict import NOISE_FLOOR, NOISE_MIN_SAMPLES, SIGMA_RATIO_MAX, estimated_noise, residual_checks, verdict
from ._whiteness import WHITENESS_ALPHA, WHITENESS_LAGS, ljung_box, null_sf, whiteness_rule

__all__ = ["ALPHA", "ANGLE_EFFECTS", "BRIDGE_EFFECTS", "EFFECTS", "MAGNETIC_EFFECTS", "LevelEstimate", "MIN_LEVEL_RATIO",
           "NOISE_FLOOR", "NOISE_MIN_SAMPLES", "SIGMA_RATIO_MAX", "SaturationCheck", "Score", "WHITENESS_ALPHA", "WHITENESS_LAGS",
           "Z_LIMIT", "check_saturation", "effect_signatures", "estimated_noise", "fit", "fit_diagnostics", "judge_fit", "ljung_box",
           "null_sf", "prepare_unmodelled_effects", "residual_checks", "score_test", "segment_traces", "unmodelled_effects",
           "untested_effects", "verdict", "whiteness_rule"]
