"""The synthetic bench on the Jaxonomy engine, and the engine blocks it is built from."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._blocks import pmsm_block
from ._engine import ENGINE_ATOL, ENGINE_RTOL, engine_bench, run_held_voltages, synthetic_bench
from ._reference import HINKKANEN_SYRM, SATURATION_LEVELS_PLAN, hinkkanen_syrm
from ._step import step_engine_bench

__all__ = ["HINKKANEN_SYRM", "SATURATION_LEVELS_PLAN", "hinkkanen_syrm", "ENGINE_ATOL", "ENGINE_RTOL", "engine_bench", "pmsm_block", "run_held_voltages", "step_engine_bench",
           "synthetic_bench"]
