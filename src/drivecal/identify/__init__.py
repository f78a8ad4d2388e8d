"""Identifiability before fitting: sensitivity Jacobian, rank, condition number, dead and weak parameters."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._identifiability import (COND_MAX, CORR_MAX, DEAD_TOL, Identifiability, WEAK_RELATIVE_CI,
                               assess_identifiability, check_requested, identifiability_report, sensitivity_jacobian,
                               structural_reason)

__all__ = ["COND_MAX", "CORR_MAX", "DEAD_TOL", "Identifiability", "WEAK_RELATIVE_CI", "assess_identifiability",
           "check_requested", "identifiability_report", "sensitivity_jacobian", "structural_reason"]
