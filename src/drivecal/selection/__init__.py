"""Model selection: which bench effects (delay, dead time, sensor offsets) the data support."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._select import MODES, EffectChoice, EffectSelection, parse_effects, select_effects

__all__ = ["EffectChoice", "EffectSelection", "MODES", "parse_effects", "select_effects"]
