"""Bench plans: segments, waveforms (one definition), plan files (TOML in and out)."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._files import (ChirpSpec, MotorFile, MotorSpec, MultisineSpec, PlanSpec, PrbsSpec, SamplesSpec, SegmentSpec, StepSpec, load_motor, load_plan, motor_from_dict, parse_quantity, plan_from_dict, plan_to_dict, plan_toml, read_toml, write_plan)
from ._plan import (Plan, Segment, default_plan, locked_q_step_plan)
from ._waveforms import (GENERATORS, chirp, maximal_length_sequence, multisine, prbs, samples, step)
from . import _waveforms as waveforms

__all__ = ["ChirpSpec", "GENERATORS", "MotorFile", "MotorSpec", "MultisineSpec", "Plan", "PlanSpec", "PrbsSpec", "SamplesSpec", "Segment", "SegmentSpec", "StepSpec", "chirp", "default_plan", "load_motor", "load_plan", "locked_q_step_plan", "maximal_length_sequence", "motor_from_dict", "multisine", "parse_quantity", "plan_from_dict", "plan_to_dict", "plan_toml", "prbs", "read_toml", "samples", "step", "waveforms", "write_plan"]
