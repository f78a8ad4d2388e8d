"""The result JSON: its one owner.

Every key of a saved result is written here. A single fit's document is the
Calibration's own section (``Calibration.to_dict()``, the DESIGN.md keys:
parameters, names, covariance, correlation, sigma_hat, converged, iterations,
identifiability, fixed, ...) plus the sections :func:`result_document` adds:

* ``segments``: per bench segment, ``t`` (s), ``v_d``, ``v_q`` (V), measured
  ``i_d``, ``i_q`` and predicted ``i_d_pred``, ``i_q_pred`` (A) at the estimate
  (residuals are measured - predicted);
* ``residuals``: residual diagnostics (``drivecal.diagnose.residual_checks``);
* ``verdict``: ``{status, headline, details}``, ``status`` a :class:`Status` key;
* ``plan`` (or null), ``motor_file`` (path of the prior's TOML, or null);
* ``input``: ``{sha256, what, path}``: the hash of the input file's bytes, or
  for the synthetic bench of its bench-file CSV bytes;
* ``measured_speed``, ``saturation`` and ``drivecal_version`` when the fit
  came from a bench file (``drivecal fit``);
* ``versions``: drivecal, jax, jaxonomy, jaxterity, optimistix, numpy,
  matplotlib, python.

A demo's document holds one such result per design under ``designs``
(:func:`demo_document`). :func:`load_result` reads both back.
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

from .._version import __version__
from ..data import BenchData
from ..errors import DrivecalError

#: Default of the optional sections: the key is left out of the document (a null would be a value).
NOT_RECORDED = object()


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


def segment_residuals(segments: list[dict[str, Any]]) -> list[tuple[str, np.ndarray]]:
    """``(name, measured - predicted)`` per segment, shape (N, 2) A, from the ``segments`` section."""
    return [(s["name"], np.stack([np.asarray(s["i_d"]) - np.asarray(s["i_d_pred"]),
                                  np.asarray(s["i_q"]) - np.asarray(s["i_q_pred"])], axis=1)) for s in segments]


def result_document(fit: dict[str, Any], *, segments: list[dict[str, Any]], residuals: dict[str, Any],
                    verdict: dict[str, Any], plan: dict[str, Any] | None, motor_file: str | os.PathLike | None,
                    input_sha256: str, input_path: str | os.PathLike | None, measured_speed: Any = NOT_RECORDED,
                    saturation: Any = NOT_RECORDED) -> dict[str, Any]:
    """One fit's full result JSON from its parts (each already JSON-ready).

    Args:
        fit: ``Calibration.to_dict()``.
        segments: the traces (see the module docstring).
        residuals: ``drivecal.diagnose.residual_checks`` (with ``unmodelled_effects``).
        verdict: ``drivecal.diagnose.verdict`` of the document.
        plan: the plan as JSON (``drivecal.plan.plan_to_dict``), or None.
        motor_file: path of the motor TOML the prior came from, or None.
        input_sha256: hash of the input file's bytes, or of the bench data (:func:`bench_sha256`).
        input_path: the input file, or None for the synthetic bench.
        measured_speed: whether a measured speed drove the model (bench files only).
        saturation: the saturation check's dict, or None (bench files only).
    """
    doc = dict(fit)
    doc["segments"] = segments
    doc["residuals"] = residuals
    doc["verdict"] = verdict
    doc["plan"] = plan
    doc["motor_file"] = None if motor_file is None else str(motor_file)
    doc["input"] = {
        "sha256": input_sha256,
        "what": "bench file bytes" if input_path is not None else "bench data as bench-file CSV (%.17g)",
        "path": None if input_path is None else str(input_path),
    }
    doc["versions"] = software_versions()
    if measured_speed is not NOT_RECORDED:
        doc["measured_speed"] = bool(measured_speed)
        doc["drivecal_version"] = __version__
    if saturation is not NOT_RECORDED:
        doc["saturation"] = saturation
    return doc


def demo_document(*, noise_sigma: float, seed: int, truth: dict[str, float], initial: dict[str, float],
                  designs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The demo's JSON: one result (:func:`result_document` plus ``truth``) per design."""
    return {
        "drivecal_version": __version__,
        "noise_sigma": noise_sigma,
        "seed": seed,
        "truth": truth,
        "initial": initial,
        "designs": designs,
        "versions": software_versions(),
    }


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
