"""The demonstration: a full calibration on the synthetic bench, and a failure.

1. The default plan (locked d-step, locked q-step, free spin-up) is run on the
   Jaxonomy engine with the default motor as the truth, plus sensor noise.
2. The fit starts from a datasheet guess 40-50 % off (also the prior), checks
   identifiability, fits, and reports intervals.
3. The same with a poor plan (a locked q-step only): Ld and lambda_m are dead,
   named, held at the prior and not reported as calibrated.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..bench import engine_bench, kept_engine_bench
from ..data import BenchData
from ..fitting import fit
from ..diagnose import prepare_unmodelled_effects, untested_effects
from ..identify import assess_identifiability
from ..model import Experiment, compiled_ahead, model_experiment, side_by_side, with_experiment_delay
from ..results import Calibration, demo_document
from ..physics import DEFAULT_MOTOR, ESTIMATED, MotorParams
from ..plan import Plan, default_plan, locked_q_step_plan
from ..report import build_result
from .._io import FILE_DPI, prepare_output_dir, write_bytes, write_json

#: The datasheet guess the demo starts from, relative to the truth.
GUESS_FACTORS = {"R": 1.5, "Ld": 0.6, "Lq": 1.4, "lambda_m": 0.7}


def datasheet_guess(truth: MotorParams) -> MotorParams:
    """The demo's starting point: R +50 %, Ld -40 %, Lq +40 %, lambda_m -30 %."""
    return truth.replace(**{n: getattr(truth, n) * f for n, f in GUESS_FACTORS.items()})


@dataclasses.dataclass(frozen=True)
class DesignRun:
    """One plan taken through bench, identifiability and fit."""

    label: str
    plan: Plan
    clean: BenchData
    bench: BenchData
    calibration: Calibration

    def errors(self, truth: MotorParams) -> dict[str, dict[str, float | None]]:
        """Per parameter: error (%) and distance to the truth in standard errors."""
        cal = self.calibration
        out = {}
        for i, n in enumerate(cal.names):
            true = float(getattr(truth, n))
            err = float(cal.estimate[i]) - true
            se = float(cal.se[i])
            out[n] = {
                "true": true,
                "error_percent": 100.0 * err / true,
                "error_in_se": err / se if np.isfinite(se) else None,
                "ci_covers_truth": bool(cal.ci95[i, 0] <= true <= cal.ci95[i, 1]) if np.isfinite(se) else None,
            }
        return out

    def to_dict(self, truth: MotorParams, noise_sigma: float | None = None) -> dict[str, Any]:
        """The full result JSON of this design (``drivecal.report.build_result``) plus ``truth``.

        The input hash is that of the synthetic bench data (there is no file).
        """
        doc = build_result(self.calibration, self.bench, plan=self.plan, noise_sigma=noise_sigma)
        return {**doc, "truth": self.errors(truth)}


@dataclasses.dataclass(frozen=True)
class DemoResult:
    truth: MotorParams
    guess: MotorParams
    noise: float
    seed: int
    default: DesignRun
    poor: DesignRun

    def to_dict(self) -> dict[str, Any]:
        """The demo's result JSON (``drivecal.results.demo_document``)."""
        return demo_document(noise_sigma=self.noise, seed=self.seed, truth=self.truth.as_dict(),
                             initial=self.guess.as_dict(),
                             designs=dict(zip(("default", "locked_q_step"), _both(
                                 lambda run: run.to_dict(self.truth, self.noise), (self.default, self.poor)))))


def _both(work: Callable[[Any], Any], items: tuple) -> list:
    """``[work(x) for x in items]``, each in a thread of its own (``model.side_by_side``).

    A first run spends most of its time compiling (XLA releases the GIL while it compiles),
    so the two designs' kernels compile side by side on a machine with two cores. The work
    is the same as one after the other, and so are the numbers.
    """
    return side_by_side([functools.partial(work, x) for x in items])


def _compile_design(plan: Plan, guess: MotorParams) -> None:
    """Compile (or load) the kernels a design's fit and result document run, from the plan alone: the fit's
    identifiability check and steps, its score tests and predicted currents (``diagnose.unmodelled_effects``).

    The experiment of the plan has the shapes of the bench's (the engine records the plan's commands), and
    the identifiability check at the guess, which picks the parameters fitted, reads no measured current.
    """
    experiment = Experiment.from_plan(plan)
    prior = with_experiment_delay(guess, experiment)
    names = assess_identifiability(model_experiment(experiment, prior, ESTIMATED), prior).fit_names
    if names:
        prepare_unmodelled_effects(prior, names, experiment, untested_effects(names, experiment))


def _fit_design(label: str, plan: Plan, clean: BenchData, guess: MotorParams, noise: float, seed: int) -> DesignRun:
    bench = clean.add_noise(noise, seed)
    return DesignRun(label, plan, clean, bench, fit(bench, guess))


def run_demo(
    *,
    noise: float = 0.02,
    seed: int = 1,
    truth: MotorParams = DEFAULT_MOTOR,
    progress: Callable[[str], None] = lambda message: None,
) -> DemoResult:
    """Run the demonstration.

    Args:
        noise: current-sensor noise (A).
        seed: noise seed; the poor design uses ``seed + 1``.
        truth: the motor on the bench.
        progress: called with a short message before each stage.
    """
    guess = datasheet_guess(truth)
    designs = (("default plan", default_plan(), seed), ("locked q-step only", locked_q_step_plan(), seed + 1))
    progress("engine bench: the default plan and a locked q-step alone")
    cleans = [kept_engine_bench(plan, truth) for _, plan, _ in designs]  # kept by an earlier demo
    if any(clean is None for clean in cleans):
        # What the fits and their result documents compile depends on the plans' shapes, not on the data:
        # it compiles beside the engine's runs (one after the other). Where the engine's runs are kept, so
        # are the kernels, and each design's thread loads its own.
        with compiled_ahead(side_by_side, [functools.partial(_compile_design, plan, guess) for _, plan, _ in designs]):
            cleans = [engine_bench(plan, truth) if clean is None else clean
                      for clean, (_, plan, _) in zip(cleans, designs)]
    progress("identifiability and fit of both designs")
    good, poor = _both(lambda k: _fit_design(designs[k][0], designs[k][1], cleans[k], guess, noise, designs[k][2]),
                       (0, 1))
    return DemoResult(truth=truth, guess=guess, noise=noise, seed=seed, default=good, poor=poor)


def write_demo_outputs(result: DemoResult, out_dir: str | Path, renderer=None) -> list[Path]:
    """Write ``report.json``, ``report.html`` and the PNG figures into ``out_dir``; return the paths.

    The HTML is rendered from the JSON document exactly as saved (passed
    through ``json``), so ``drivecal report DIR/report.json --html X`` gives
    the same page apart from its time stamp. The figures are drawn in
    ``renderer``'s worker processes (a started ``drivecal._figures.FigureRenderer``),
    the PNG files' while the result JSON is built; without one, in this process.
    """
    from .._figures import FigureRenderer
    from ..report import plots
    from ..report import write_html_report

    if renderer is None:  # drawn here: workers pay off when started early, as `drivecal demo --out` does
        renderer = FigureRenderer(0)
    out = prepare_output_dir(out_dir)
    truth = result.truth.vector(result.default.calibration.names)
    jobs = {}
    for run, tag in ((result.default, "default"), (result.poor, "locked_q_step")):
        jobs[f"excitation_{tag}.png"] = plots.excitation_job(run.clean, run.bench, title=run.label)
        jobs[f"convergence_{tag}.png"] = plots.convergence_job(run.calibration, truth=truth)
        jobs[f"estimates_{tag}.png"] = plots.estimates_job(run.calibration, truth=truth)
    jobs["identifiability.png"] = plots.identifiability_job(
        {result.default.label: result.default.calibration.identifiability,
         result.poor.label: result.poor.calibration.identifiability})
    pending = {name: renderer.submit(kind, kwargs, dpi=FILE_DPI) for name, (kind, kwargs) in jobs.items()}
    doc = json.loads(json.dumps(result.to_dict(), allow_nan=False))
    write_json(out / "report.json", doc)
    # The page's figures queue behind the files' (the workers take those first, this process draws the page's
    # from their end), so no process waits while another still draws.
    write_html_report(doc, out / "report.html", renderer=renderer)
    for name, job in pending.items():
        write_bytes(out / name, job.result())
    return [out / name for name in pending] + [out / "report.json", out / "report.html"]
