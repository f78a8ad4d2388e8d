"""Bench plans: segments, waveforms (one definition), plan files (TOML in and out).

The plan files' names (``load_plan``, ``PlanSpec``, ...) are loaded from ``_files`` on first use: their schemas are
pydantic's (~0.2 s to import), which a command that reads no plan file never loads.
"""

from typing import TYPE_CHECKING

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from .._lazy import lazy_names as _lazy_names
from .._units import parse_quantity, read_toml
from ._plan import (INVERTER_MODELS, INVERTER_MODULATIONS, Inverter, Plan, Segment, default_plan,
                    inverter_setting_error, locked_q_step_plan, plan_to_dict)
from ._waveforms import (FLAT_SWEEP_RATE, GENERATORS, chirp, maximal_length_sequence, multisine, prbs, ramp,
                         samples, schroeder_tones, step)
from . import _waveforms as waveforms

if TYPE_CHECKING:  # loaded at run time by __getattr__
    from ._files import (ChirpSpec, InverterSpec, MultisineSpec, PlanSpec, PrbsSpec, RampSpec, SamplesSpec,
                         SegmentSpec, StepSpec, load_plan, plan_from_dict, plan_toml, write_plan)

__all__ = ["ChirpSpec", "FLAT_SWEEP_RATE", "GENERATORS", "INVERTER_MODELS", "INVERTER_MODULATIONS", "Inverter",
           "inverter_setting_error",
           "InverterSpec", "MultisineSpec", "Plan", "PlanSpec", "PrbsSpec", "RampSpec",
           "SamplesSpec", "Segment", "SegmentSpec", "StepSpec", "chirp", "default_plan", "load_plan",
           "locked_q_step_plan", "maximal_length_sequence", "multisine", "parse_quantity", "plan_from_dict",
           "plan_to_dict", "plan_toml", "prbs", "ramp", "read_toml", "samples", "schroeder_tones", "step", "waveforms",
           "write_plan"]

__getattr__, __dir__ = _lazy_names(__name__, {"_files": (
    "ChirpSpec", "InverterSpec", "MultisineSpec", "PlanSpec", "PrbsSpec", "RampSpec", "SamplesSpec", "SegmentSpec",
    "StepSpec", "load_plan", "plan_from_dict", "plan_toml", "write_plan")})
