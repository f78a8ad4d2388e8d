"""The forward model: the experiment on the sample grid, RK4 rollouts, compiled entry points and their on-disk cache."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._experiment import (Experiment, SEGMENT_KINDS, in_rotor_frame, model_experiment, stack_experiments,
                          with_experiment_delay)
from ._rollout import (current_parts, join_current_parts, measured_currents, predict_current_parts, predict_currents,
                       predicted_currents, rk4_step, simulate_states, simulated_states)
from ._saturation_columns import start_saturation_columns
from ._ahead import ahead_of_need, compiled_ahead, outputs_unused, side_by_side
from ._lowered_cache import (LEGACY_EMITTERS, RUN_ONCE, call as cached_call, directory as lowered_cache_directory,
                             keep_result, kept_result, result_key, run_once_options)
from ._steps import delay_inputs

__all__ = ["Experiment", "LEGACY_EMITTERS", "RUN_ONCE", "SEGMENT_KINDS", "ahead_of_need", "cached_call",
           "compiled_ahead", "current_parts", "delay_inputs", "in_rotor_frame", "join_current_parts", "keep_result",
           "kept_result", "lowered_cache_directory", "measured_currents", "model_experiment", "outputs_unused",
           "predict_current_parts", "predict_currents", "predicted_currents", "result_key", "rk4_step",
           "run_once_options", "side_by_side", "simulate_states", "simulated_states", "start_saturation_columns",
           "stack_experiments", "with_experiment_delay"]
