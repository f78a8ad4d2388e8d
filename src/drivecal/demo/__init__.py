"""The demo: both sides of a bench test on the synthetic bench."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._demo import DemoResult, DesignRun, GUESS_FACTORS, datasheet_guess, run_demo, write_demo_outputs

__all__ = ["DemoResult", "DesignRun", "GUESS_FACTORS", "datasheet_guess", "run_demo", "write_demo_outputs"]
