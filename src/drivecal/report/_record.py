"""The saved result: one fit's JSON with everything its report needs.

``build_result`` extends ``Calibration.to_dict()`` (the DESIGN.md keys) with
new sections, so a saved file alone reproduces the HTML report and the
controller hand-off:

* ``segments``: per bench segment, ``t`` (s), ``v_d``, ``v_q`` (V), measured
  ``i_d``, ``i_q`` and predicted ``i_d_pred``, ``i_q_pred`` (A) at the estimate
  (residuals are measured - predicted);
* ``residuals``: residual diagnostics (see ``verdict.residual_checks``);
* ``verdict``: ``{status, headline, details}``;
* ``plan`` (or null), ``motor_file`` (path of the prior's TOML, or null);
* ``input``: ``{sha256, what, path}``: the hash of the input file's bytes, or
  for the synthetic bench of its bench-file CSV bytes;
* ``versions``: drivecal, jax, jaxonomy, jaxterity, optimistix, numpy,
  matplotlib, python.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from ..data import BenchData
from ..errors import DrivecalError
from ..fitting import Calibration
from ..diagnose import unmodelled_effects
from ..model import Experiment, model_experiment, predicted_currents
from ..plan import Plan
from ..plan import plan_to_dict
from ..diagnose import residual_checks, verdict

#: Packages whose versions a result records.
VERSIONED = ("drivecal", "jax", "jaxonomy", "jaxterity", "optimistix", "numpy", "matplotlib")


def software_versions() -> dict[str, str]:
    """Installed versions of drivecal and the stack it computes with, plus Python's."""
    out = {}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    out["python"] = platform.python_version()
    return out


def content_sha256(content: bytes) -> str:
    """SHA-256 (hex) of a bench file's bytes already read: equal to :func:`file_sha256` of that file."""
    return hashlib.sha256(content).hexdigest()


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes: the identity of a bench file."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def bench_sha256(bench: BenchData) -> str:
    """SHA-256 (hex) of bench data as bench-file CSV bytes (``%.17g``: every float exact).

    Used where there is no input file (the synthetic bench): the same data
    always gives the same hash.
    """
    csv = bench.to_frame().to_csv(index=False, float_format="%.17g", lineterminator="\n")
    return hashlib.sha256(csv.encode()).hexdigest()


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


def segment_residuals(segments: list[dict[str, Any]]) -> list[tuple[str, np.ndarray]]:
    """``(name, measured - predicted)`` per segment, shape (N, 2) A, from the ``segments`` section."""
    return [(s["name"], np.stack([np.asarray(s["i_d"]) - np.asarray(s["i_d_pred"]),
                                  np.asarray(s["i_q"]) - np.asarray(s["i_q_pred"])], axis=1)) for s in segments]


def build_result(
    calibration: Calibration,
    bench: BenchData,
    *,
    plan: Plan | None = None,
    experiment: Experiment | None = None,
    noise_sigma: float | None = None,
    input_path: str | os.PathLike | None = None,
    input_sha256: str | None = None,
    motor_file: str | os.PathLike | None = None,
) -> dict[str, Any]:
    """The full result JSON of one fit (a plain, JSON-ready dict).

    Args:
        calibration: the fit.
        bench: the data it was fitted to.
        plan: the plan that produced the data, if known.
        experiment: the experiment the fit used, if not ``bench.experiment()``
            (e.g. with measured speed as an input): the predictions must match the fit.
        noise_sigma: the stated current-sensor noise (A) the residuals are
            judged against; None when unknown (then only their whiteness is judged).
        input_path: the bench file; its bytes are hashed unless ``input_sha256`` is given.
        input_sha256: hash of the input; default the file's, or the bench data's.
        motor_file: path of the motor TOML the prior came from.
    """
    doc = calibration.to_dict()
    segments = segment_traces(calibration, bench, experiment)
    stated = float(noise_sigma) if noise_sigma is not None else None
    doc["segments"] = segments
    doc["residuals"] = residual_checks(segment_residuals(segments), float(calibration.sigma_hat), stated)
    if bool(calibration.converged):
        used = bench.experiment(delay_samples=calibration.delay_samples) if experiment is None else experiment
        doc["residuals"]["unmodelled_effects"] = unmodelled_effects(
            calibration.motor, calibration.fit_names, used, bench.currents, float(calibration.sigma_hat),
            calibration.delay_samples, used.with_extra_delay(1),
            predicted=np.concatenate([np.stack([s["i_d_pred"], s["i_q_pred"]], axis=1) for s in segments]))
    doc["verdict"] = verdict(doc)
    doc["plan"] = plan_to_dict(plan) if plan is not None else None
    doc["motor_file"] = None if motor_file is None else str(motor_file)
    if input_sha256 is None:
        input_sha256 = file_sha256(input_path) if input_path is not None else bench_sha256(bench)
    doc["input"] = {
        "sha256": input_sha256,
        "what": "bench file bytes" if input_path is not None else "bench data as bench-file CSV (%.17g)",
        "path": None if input_path is None else str(input_path),
    }
    doc["versions"] = software_versions()
    return doc


def load_result(path: str | os.PathLike) -> dict[str, Any]:
    """Read a saved drivecal result JSON (one fit, or a demo with ``designs``).

    Raises:
        DrivecalError: missing file, not JSON, or not a drivecal result (one sentence, with the fix).
    """
    p = Path(path)
    hint = "give a result JSON written by `drivecal fit` or `drivecal demo --out DIR` (DIR/report.json)"
    if not p.is_file():
        raise DrivecalError(f"{p}: no such file; {hint}.")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise DrivecalError(f"{p}: not a text file, so not a result JSON; {hint}.")
    except json.JSONDecodeError as exc:
        raise DrivecalError(f"{p}: not valid JSON (line {exc.lineno}: {exc.msg}); {hint}.")
    fits = list(doc["designs"].values()) if isinstance(doc, dict) and isinstance(doc.get("designs"), dict) else [doc]
    required = ("parameters", "names", "covariance", "sigma_hat", "converged", "identifiability", "num_residuals")
    for fit_doc in fits:
        missing = [k for k in required if not isinstance(fit_doc, dict) or k not in fit_doc]
        if missing:
            raise DrivecalError(f"{p}: not a drivecal result (no '{missing[0]}' field); {hint}.")
    return doc


def result_fits(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The single-fit results in a document: ``{design: result}`` (``{"fit": doc}`` for one fit)."""
    if isinstance(doc.get("designs"), dict):
        return dict(doc["designs"])
    return {"fit": doc}


def select_fit(doc: dict[str, Any], design: str | None, source: str = "result") -> tuple[str, dict[str, Any]]:
    """One fit out of a document: ``design`` by name, or the first one."""
    fits = result_fits(doc)
    if design is None:
        return next(iter(fits.items()))
    if design not in fits:
        raise DrivecalError(f"{source}: no design '{design}'; choose one of: {', '.join(fits)}.")
    return design, fits[design]
