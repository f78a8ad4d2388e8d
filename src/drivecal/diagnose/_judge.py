"""A fit judged: its residual diagnostics and verdict, computed from the bench data it was fitted to.

:func:`fit_diagnostics` is what a saved result and ``drivecal fit`` record (``drivecal.report.build_result``
calls it); :func:`judge_fit` attaches its verdict and diagnostics to the Calibration, and :func:`fit` (the
package's ``drivecal.fit``) is ``drivecal.fitting.fit`` followed by :func:`judge_fit`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from ..data import BenchData, MotorFile
from ..errors import DrivecalError
from ..fitting import FitOptions, fit_currents, fit_setup
from ..model import Experiment, model_experiment, predicted_currents
from ..physics import MotorParams
from ..results import Calibration, Verdict, json_ready, segment_residuals
from ._mismatch import unmodelled_effects
from ._verdict import estimated_noise, residual_checks, verdict


def segment_traces(calibration: Calibration, bench: BenchData, experiment: Experiment | None = None
                   ) -> list[dict[str, Any]]:
    """Per segment: time, voltages, measured and predicted currents as JSON lists.

    Args:
        calibration: the fit; the prediction is at its estimate.
        bench: the data it was fitted to.
        experiment: the experiment the fit used (default ``bench.experiment()``).
    """
    if experiment is None:
        experiment = bench.experiment(delay_samples=calibration.delay_samples)
    experiment = model_experiment(experiment, calibration.motor, calibration.names)
    predicted = predicted_currents(calibration.motor, experiment)
    out, k = [], 0
    for seg in bench.segments:
        n = seg.num_samples
        pred = predicted[k : k + n]
        k += n
        out.append({
            "name": seg.name,
            "locked": bool(seg.locked),
            "t": seg.t.tolist(),
            "v_d": seg.voltages[:, 0].tolist(),
            "v_q": seg.voltages[:, 1].tolist(),
            "i_d": seg.currents[:, 0].tolist(),
            "i_q": seg.currents[:, 1].tolist(),
            "i_d_pred": pred[:, 0].tolist(),
            "i_q_pred": pred[:, 1].tolist(),
        })
    return out


def fit_diagnostics(
    calibration: Calibration,
    bench: BenchData,
    *,
    experiment: Experiment | None = None,
    noise_sigma: float | None = None,
    noise_source: str = "stated",
    effects: dict[str, Any] | None = None,
    speed: dict[str, Any] | None = None,
) -> tuple[list[dict[str, Any]], dict[str, Any], dict[str, Any]]:
    """The traces, residual diagnostics and verdict of one fit: what its result JSON records.

    Args:
        calibration: the fit (one, not a batch).
        bench: the data it was fitted to.
        experiment: the experiment the fit used, if not ``bench.experiment()``
            (e.g. with measured speed as an input): the predictions must match the fit.
        noise_sigma: the stated current-sensor noise (A) the residuals are judged against; None:
            against the noise estimated from the samples (:func:`estimated_noise`), and where that
            cannot be estimated only their whiteness is judged (the verdict says why).
        noise_source: where ``noise_sigma`` comes from, in words (e.g. ``"--noise"``).
        effects: the bench-effect selection's dict (``EffectSelection.to_dict()``), whose fitted
            effects the verdict names.
        speed: what the fit made of the measured speed (``drivecal.data.SpeedChoice.to_dict()``): a speed
            too coarse for the exact input it was used as is named by the verdict.

    Returns:
        ``(segments, residuals, verdict)``: the result JSON's ``segments``, ``residuals`` and ``verdict``.
    """
    if calibration.batch_shape:
        raise TypeError("a fit's diagnostics are for one fit; index the batch first")
    segments = segment_traces(calibration, bench, experiment)
    if noise_sigma is not None:
        stated, source, why_off = float(noise_sigma), noise_source, None
    else:  # judged against the noise in the samples, or the check is off and the verdict says why
        stated, how = estimated_noise(bench)
        source, why_off = (how, None) if stated is not None else (None, how)
    residuals = residual_checks(segment_residuals(segments), float(calibration.sigma_hat), stated,
                                sigma_source=source, estimated=noise_sigma is None, noise_check_off=why_off)
    if bool(calibration.converged):
        used = bench.experiment(delay_samples=calibration.delay_samples) if experiment is None else experiment
        residuals["unmodelled_effects"] = unmodelled_effects(
            calibration.motor, calibration.fit_names, used, bench.currents, float(calibration.sigma_hat),
            predicted=np.concatenate([np.stack([s["i_d_pred"], s["i_q_pred"]], axis=1) for s in segments]))
    # The verdict reads the fit and its residuals.
    judged = verdict({**calibration.to_dict(), "segments": segments, "residuals": residuals, "effects": effects,
                      "speed": speed})
    return segments, residuals, judged


def judge_fit(calibration: Calibration, bench: BenchData, *, experiment: Experiment | None = None,
              noise_sigma: float | None = None, noise_source: str = "stated",
              speed: dict[str, Any] | None = None) -> Calibration:
    """``calibration`` with its verdict and residual diagnostics attached (:func:`fit_diagnostics`).

    The same verdict as the result JSON that ``drivecal.build_result`` (and ``drivecal fit``) writes
    for this fit; ``Calibration.verdict``, ``.diagnostics``, ``to_dict()`` and ``print(cal)`` carry it.
    Arguments as :func:`fit_diagnostics`.
    """
    _, residuals, judged = fit_diagnostics(calibration, bench, experiment=experiment, noise_sigma=noise_sigma,
                                           noise_source=noise_source, speed=speed)
    return dataclasses.replace(calibration, verdict=Verdict.from_dict(judged), diagnostics=json_ready(residuals))


def fit(
    bench: BenchData,
    prior: MotorParams | MotorFile,
    *,
    initial: MotorParams | np.ndarray | None = None,
    names: tuple[str, ...] | None = None,
    options: FitOptions = FitOptions(),
    measured_speed: bool | None = None,
    delay_samples: float | None = None,
    speed: str | None = None,
    noise: float | None = None,
) -> Calibration:
    """Calibrate a motor from bench data and judge the fit: the package's ``drivecal.fit``.

    ``drivecal.fitting.fit`` (identifiability at ``prior``, the LM fit, the intervals; its arguments
    are this one's), then :func:`judge_fit`: the returned Calibration carries the verdict (``.verdict``:
    calibrated, partial, mismatch or failed, as ``drivecal fit`` reports it) and the residual diagnostics
    (``.diagnostics``), which ``print(cal)`` leads with and ``to_dict()`` records.

    Args:
        noise: the current sensor's noise standard deviation (A) the residuals are judged against;
            default the motor file's ``current_noise`` (``prior`` a loaded motor file), else the noise
            estimated from the samples (as ``drivecal fit`` without ``--noise``).
    """
    if noise is not None and not (isinstance(noise, (int, float, np.floating)) and not isinstance(noise, bool)
                                  and math.isfinite(noise) and noise > 0):
        raise DrivecalError(f"noise is {noise!r}; give the current sensor's noise as a positive number of "
                            "amperes, or leave it out to judge against the noise estimated from the samples.")
    experiment, motor, fitted, choice = fit_setup(bench, prior, names=names, measured_speed=measured_speed,
                                                  delay_samples=delay_samples, speed=speed)
    cal = fit_currents(experiment, bench.currents, motor, initial=initial, names=fitted, options=options,
                       source=bench.source, delay_samples=float(motor.delay))
    source = "the noise argument"
    if noise is None and isinstance(prior, MotorFile) and prior.current_noise is not None:
        noise, source = prior.current_noise, "the motor file's current_noise"
    return judge_fit(cal, bench, experiment=experiment, noise_sigma=noise, noise_source=source,
                     speed=choice.to_dict())
