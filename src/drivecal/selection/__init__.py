"""Model selection: which bench effects (delay, dead time, sensor offsets) and saturation terms the data support."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._choices import MATERIAL_SATURATION, EffectChoice, saturation_size
from ._select import MAGNETICS, MODES, EffectSelection, parse_effects, select_effects

__all__ = ["EffectChoice", "EffectSelection", "MAGNETICS", "MATERIAL_SATURATION", "MODES", "parse_effects",
           "saturation_size", "select_effects"]
