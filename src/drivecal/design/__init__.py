"""Experiment design: a plan's feasibility and predicted intervals, automatic plans, optimal excitation."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._assess import DesignReport, MAX_ELECTRICAL_STEP, SegmentPrediction, assess_design, predict_segments
from ._bench_limits import (DEAD_TIME_MARGIN, DEFAULT_DEAD_TIME, DEFAULT_SAMPLE_RATE, MAX_RAMP_SAMPLES,
                            RIPPLE_FRACTION, SAMPLE_RATES,
                            SPIN_SPEED_FRACTION, TORQUE_MARGIN, BenchLimits, choose_sample_rate, clamp_current,
                            dead_time_drop, expected_dead_voltage, expected_dead_width,
                            margin_problems, min_durations)
from ._autoplan import (CURRENT_MARGIN, LOCKED_TIME_CONSTANTS, MAX_SAMPLE_RATE, MIN_LOCKED_TIME_CONSTANTS,
                        MIN_SAMPLES_PER_TIME_CONSTANT, MIN_SAMPLE_RATE, MIN_SEGMENT_SAMPLES, MIN_SPIN_TIME_CONSTANTS,
                        MotorTimes, NOISE_FRACTION, PLAN_MAX_ELECTRICAL_STEP, SAMPLES_PER_TIME_CONSTANT,
                        SPEED_FRACTION, SPIN_TIME_CONSTANTS, STEP_CURRENT_FRACTION, VOLTAGE_FRACTION, auto_design,
                        auto_plan, with_saturation_steps)
from ._design_space import COLLAPSED_AMPLITUDE, MIN_DURATION_FRACTION, infer_waveforms, load_plan_waveforms
from ._mechanical import (FRICTION_SE, LOW_SPEED_FRACTION, MAX_FRICTION_SAMPLES, SETTLE_SPIN_TIMES, friction_samples,
                          mechanical_segments)
from ._saturation_plan import (COMBINED_SIGNS, SATURATED_INDUCTANCE_FRACTION, SATURATION_LEVELS,
                               SATURATION_TOP_FRACTION)
from ._optimal import (BUDGET_ROOM, LIMIT_MARGIN, PEAK_WINDOW_SHARPNESS, SCALE_SHARPNESS, SOFTMAX_SHARPNESS,
                       OptimalDesign, optimize_plan, predicted_covariance, speed_limit)

__all__ = ["assess_design", "auto_design", "auto_plan", "BenchLimits", "BUDGET_ROOM", "choose_sample_rate",
           "clamp_current", "COLLAPSED_AMPLITUDE", "COMBINED_SIGNS", "CURRENT_MARGIN", "dead_time_drop",
           "DEAD_TIME_MARGIN", "DEFAULT_DEAD_TIME", "DEFAULT_SAMPLE_RATE", "DesignReport", "expected_dead_voltage",
           "expected_dead_width", "friction_samples", "FRICTION_SE", "infer_waveforms", "LIMIT_MARGIN",
           "load_plan_waveforms", "LOCKED_TIME_CONSTANTS", "LOW_SPEED_FRACTION", "margin_problems",
           "MAX_ELECTRICAL_STEP", "MAX_RAMP_SAMPLES", "MAX_FRICTION_SAMPLES", "MAX_SAMPLE_RATE", "mechanical_segments",
           "MIN_DURATION_FRACTION", "min_durations", "MIN_LOCKED_TIME_CONSTANTS", "MIN_SAMPLE_RATE",
           "MIN_SAMPLES_PER_TIME_CONSTANT", "MIN_SEGMENT_SAMPLES", "MIN_SPIN_TIME_CONSTANTS", "MotorTimes",
           "NOISE_FRACTION", "OptimalDesign", "optimize_plan", "PEAK_WINDOW_SHARPNESS", "PLAN_MAX_ELECTRICAL_STEP",
           "predict_segments", "predicted_covariance", "RIPPLE_FRACTION", "SAMPLE_RATES",
           "SAMPLES_PER_TIME_CONSTANT", "SATURATED_INDUCTANCE_FRACTION", "SATURATION_LEVELS",
           "SATURATION_TOP_FRACTION", "SCALE_SHARPNESS", "SegmentPrediction", "SETTLE_SPIN_TIMES",
           "SOFTMAX_SHARPNESS", "SPEED_FRACTION", "speed_limit", "SPIN_SPEED_FRACTION", "SPIN_TIME_CONSTANTS",
           "STEP_CURRENT_FRACTION", "TORQUE_MARGIN", "VOLTAGE_FRACTION", "with_saturation_steps"]
