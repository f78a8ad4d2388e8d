"""A fit's result JSON filled in: the traces, the residual diagnostics and the verdict of one fit.

:func:`build_result` computes what a saved result needs beyond the fit itself
(predicted currents per segment, residual checks, the unmodelled-effects
tests, the verdict: :func:`drivecal.diagnose.fit_diagnostics`) and hands the parts to
:func:`drivecal.results.result_document`, the one owner of the JSON's keys.
"""

from __future__ import annotations

import os
from typing import Any

from ..data import BenchData, Tolerance
from ..diagnose import fit_diagnostics
from ..maps import flux_maps
from ..model import Experiment
from ..physics import BRIDGE, MAGNETIC, is_saturating
from ..plan import Plan, plan_to_dict
from ..results import NOT_RECORDED, Calibration, Status, bench_sha256, file_sha256, judge_spec, result_document


def build_result(
    calibration: Calibration,
    bench: BenchData,
    *,
    plan: Plan | None = None,
    experiment: Experiment | None = None,
    noise_sigma: float | None = None,
    noise_source: str = "stated",
    input_path: str | os.PathLike | None = None,
    input_sha256: str | None = None,
    motor_file: str | os.PathLike | None = None,
    measured_speed: Any = NOT_RECORDED,
    saturation: Any = NOT_RECORDED,
    effects: Any = NOT_RECORDED,
    tolerance: dict[str, Tolerance] | None = None,
    flux_maps: Any = None,
    speed: Any = NOT_RECORDED,
) -> dict[str, Any]:
    """The full result JSON of one fit (a plain, JSON-ready dict).

    Args:
        calibration: the fit.
        bench: the data it was fitted to.
        plan: the plan that produced the data, if known.
        experiment: the experiment the fit used, if not ``bench.experiment()``
            (e.g. with measured speed as an input): the predictions must match the fit.
        noise_sigma: the stated current-sensor noise (A) the residuals are
            judged against; None when unknown: then against the noise estimated from
            the samples (``drivecal.diagnose.estimated_noise``), and where that cannot
            be estimated only their whiteness is judged (the verdict says why).
        noise_source: where ``noise_sigma`` comes from, in words (e.g. ``"--noise"``).
        input_path: the bench file; its bytes are hashed unless ``input_sha256`` is given.
        input_sha256: hash of the input; default the file's, or the bench data's.
        motor_file: path of the motor TOML the prior came from.
        measured_speed: whether a measured speed drove the model (``drivecal fit`` records it).
        saturation: the saturation check's dict, or None (``drivecal fit`` records it).
        effects: the bench-effect selection's dict (``EffectSelection.to_dict()``; ``drivecal fit`` records it).
        tolerance: the motor file's specification (``MotorFile.tolerance``): when given (non-empty) the
            result's ``spec`` section judges the estimates against it (:func:`drivecal.results.judge_spec`).
        flux_maps: the maps' section (``drivecal.maps.FluxMaps.to_dict()``) when already computed; else
            computed here over the bench's currents where the calibrated law saturates.
        speed: what the fit made of the measured speed (``drivecal.data.SpeedChoice.to_dict()``; ``drivecal
            fit`` records it): a speed too coarse for the exact input it was used as is named by the verdict.
    """
    # The traces, residual checks and verdict (drivecal.diagnose.fit_diagnostics: also what drivecal.fit
    # attaches to its Calibration); the document is assembled (keys and order) in one place.
    segments, residuals, judged = fit_diagnostics(calibration, bench, experiment=experiment, noise_sigma=noise_sigma,
                                                  noise_source=noise_source,
                                                  effects=None if effects is NOT_RECORDED else effects,
                                                  speed=None if speed is NOT_RECORDED else speed)
    fit = calibration.to_dict()
    if input_sha256 is None:
        input_sha256 = file_sha256(input_path) if input_path is not None else bench_sha256(bench)
    return result_document(fit, segments=segments, residuals=residuals, verdict=judged,
                           plan=plan_to_dict(plan) if plan is not None else None, motor_file=motor_file,
                           input_sha256=input_sha256, input_path=input_path, measured_speed=measured_speed,
                           saturation=saturation, effects=effects, speed=speed,
                           flux_maps=_maps_section(calibration, bench, flux_maps),
                           spec=NOT_RECORDED if not tolerance else judge_spec(
                               calibration.names, calibration.estimate, calibration.ci95, calibration.identifiable,
                               tolerance, Status(judged["status"])).to_dict())


def _maps_section(calibration: Calibration, bench: BenchData, given: Any) -> Any:
    """The ``flux_maps`` section: ``given``, else computed where the calibrated law saturates, else not recorded."""
    if given is not None:
        return given
    if not (is_saturating(calibration.motor) or set(MAGNETIC + BRIDGE) & set(calibration.names)):
        return NOT_RECORDED
    return flux_maps(calibration, bench.currents).to_dict()
