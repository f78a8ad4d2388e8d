"""The synthetic bench on the Jaxonomy engine, the engine blocks it is built from, and the independent
switching-level PWM plant (carrier comparison, dead time, device drops, sampling at the carrier peak)."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._blocks import pmsm_block
from ._encoder import encoder_readings
from ._engine import ENGINE_ATOL, ENGINE_RTOL, engine_bench, kept_engine_bench, run_held_voltages, synthetic_bench
from ._pwm import MODULATIONS, pwm_bench, simulate_segment
from ._reference import HINKKANEN_SYRM, SATURATION_LEVELS_PLAN, hinkkanen_syrm
from ._step import step_engine_bench

__all__ = ["HINKKANEN_SYRM", "SATURATION_LEVELS_PLAN", "hinkkanen_syrm", "ENGINE_ATOL", "ENGINE_RTOL", "encoder_readings",
           "engine_bench", "kept_engine_bench", "MODULATIONS", "pmsm_block", "pwm_bench", "run_held_voltages",
           "simulate_segment", "step_engine_bench", "synthetic_bench"]
