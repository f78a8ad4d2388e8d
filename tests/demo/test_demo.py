"""The demo compiles ahead from its plans alone (drivecal/demo/_demo.py): what it compiles beside the engine is
what each design's fit and result document then run."""

from __future__ import annotations

import jax

import drivecal as dc
from drivecal.bench import engine_bench
from drivecal.demo import _demo


def test_compiling_a_design_ahead_compiles_what_its_fit_and_result_document_run():
    """After ``_compile_design`` (the plan alone, no data), the design's fit and its result JSON compile nothing:
    the same kernels, for the parameters the identifiability check leaves to fit (the locked q-step: R and Lq).

    Also after ``jax.clear_caches()`` (as tests/conftest.py does at a worker's memory-map limit): compiling the
    design again compiles what the clearing dropped, though this process prepared its score tests before."""
    plan, truth = dc.locked_q_step_plan(), dc.DEFAULT_MOTOR
    guess = _demo.datasheet_guess(truth)
    clean = engine_bench(plan, truth)
    _demo._compile_design(plan, guess)
    jax.clear_caches()
    _demo._compile_design(plan, guess)
    compiled, listening = [], [True]

    def on_duration(event: str, seconds: float, **_) -> None:
        if listening[0] and event.endswith("backend_compile_duration"):
            compiled.append(event)

    jax.monitoring.register_event_duration_secs_listener(on_duration)
    try:
        run = _demo._fit_design("locked q-step only", plan, clean, guess, 0.02, 2)
        doc = run.to_dict(truth, 0.02)
    finally:
        listening[0] = False
    assert run.calibration.fit_names == ("R", "Lq")
    assert doc["residuals"]["unmodelled_effects"]  # the score tests ran
    assert compiled == []
