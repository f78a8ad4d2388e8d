"""Identifiability before fitting: sensitivity Jacobian, rank, condition number, dead and weak parameters."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._identifiability import (COND_MAX, CORR_MAX, DEAD_TOL, Identifiability, WEAK_RELATIVE_CI,
                               assess_identifiability, check_requested, identifiability_report, structural_reason)
from ._jacobian import ADDITIVE, PROBE_COMPILER_OPTIONS, jacobian_and_outputs, sensitivity_jacobian
from ._magnetic_reasons import MAGNETIC_FIX, current_levels, magnetic_reasons

__all__ = ["ADDITIVE", "COND_MAX", "CORR_MAX", "DEAD_TOL", "Identifiability", "MAGNETIC_FIX", "PROBE_COMPILER_OPTIONS",
           "WEAK_RELATIVE_CI", "assess_identifiability", "check_requested", "current_levels",
           "identifiability_report", "jacobian_and_outputs", "magnetic_reasons", "sensitivity_jacobian",
           "structural_reason"]
