"""The result JSON: its one owner.

Every key of a saved result is written here. A single fit's document is the
Calibration's own section (``Calibration.to_dict()``, the DESIGN.md keys:
parameters, names, covariance, correlation, sigma_hat, converged, iterations,
identifiability, fixed, ...) plus the sections :func:`result_document` adds:

* ``segments``: per bench segment, ``t`` (s), ``v_d``, ``v_q`` (V), measured
  ``i_d``, ``i_q`` and predicted ``i_d_pred``, ``i_q_pred`` (A) at the estimate
  (residuals are measured - predicted);
* ``residuals``: residual diagnostics (``drivecal.diagnose.residual_checks``);
* ``verdict``: ``{status, headline, details}``, ``status`` a :class:`Status` key
  (these two are also the Calibration's own when ``drivecal.fit`` judged it:
  ``Calibration.diagnostics`` and ``.verdict``; the document's are computed here afresh);
* ``plan`` (or null), ``motor_file`` (path of the prior's TOML, or null);
* ``input``: ``{sha256, what, path}``: the hash of the input file's bytes, or
  for the synthetic bench of its bench-file CSV bytes;
* ``measured_speed``, ``speed``, ``saturation`` and ``drivecal_version`` when
  the fit came from a bench file (``drivecal fit``);
* ``flux_maps`` where the calibrated law saturates: ``psi_d``, ``psi_q``, ``L_dd``,
  ``L_dq``, ``L_qq`` on a current grid with their 95 % bands (``drivecal.maps``);
* ``versions``: drivecal, jax, jaxonomy, jaxterity, optimistix, numpy,
  matplotlib, python.

A demo's document holds one such result per design under ``designs``
(:func:`demo_document`). :func:`load_result` reads both back.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from ..data import BenchData
from ..errors import DataError
from ..physics import ESTIMABLE, FIXED, UNITS
from ._checks import _Check, _key

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
    return hashlib.sha256(bench.to_csv_text().encode()).hexdigest()


def json_ready(x: Any) -> Any:
    """A copy of ``x`` in plain JSON values: dicts (text keys), lists, text, booleans and numbers; NaN and
    infinities as null (the result JSON's "undefined"), numpy scalars and arrays as Python's, tuples as lists."""
    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [json_ready(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def segment_residuals(segments: list[dict[str, Any]]) -> list[tuple[str, np.ndarray]]:
    """``(name, measured - predicted)`` per segment, shape (N, 2) A, from the ``segments`` section."""
    return [(s["name"], np.stack([np.asarray(s["i_d"]) - np.asarray(s["i_d_pred"]),
                                  np.asarray(s["i_q"]) - np.asarray(s["i_q_pred"])], axis=1)) for s in segments]


def result_document(fit: dict[str, Any], *, segments: list[dict[str, Any]], residuals: dict[str, Any],
                    verdict: dict[str, Any], plan: dict[str, Any] | None, motor_file: str | os.PathLike | None,
                    input_sha256: str, input_path: str | os.PathLike | None, measured_speed: Any = NOT_RECORDED,
                    saturation: Any = NOT_RECORDED, effects: Any = NOT_RECORDED, spec: Any = NOT_RECORDED,
                    flux_maps: Any = NOT_RECORDED, speed: Any = NOT_RECORDED) -> dict[str, Any]:
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
        effects: the bench-effect selection (``drivecal.selection.EffectSelection.to_dict()``):
            the mode, and per effect whether it was included, the evidence and the estimate.
        spec: the judgement against the motor file's tolerances (``SpecJudgement.to_dict()``), recorded
            only when the motor file has a ``[tolerance]`` table.
        flux_maps: the flux and incremental-inductance maps with their bands (``drivecal.maps.FluxMaps.to_dict()``),
            recorded where the calibrated law saturates.
        speed: what the fit made of the measured speed and why (``drivecal.data.SpeedChoice.to_dict()``: mode,
            requested, flagged, input_error_ratio, resolution, reason; bench files only).
    """
    doc = {k: v for k, v in fit.items() if k not in ("residuals", "verdict")}  # a judged fit's: set below
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
    if speed is not NOT_RECORDED:
        doc["speed"] = speed
    if saturation is not NOT_RECORDED:
        doc["saturation"] = saturation
    if effects is not NOT_RECORDED:
        doc["effects"] = effects
    if spec is not NOT_RECORDED:
        doc["spec"] = spec
    if flux_maps is not NOT_RECORDED:
        doc["flux_maps"] = flux_maps
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


#: The fix for a file that is not a drivecal result at all.
RESULT_HINT = "give a result JSON written by `drivecal fit` or `drivecal demo --out DIR` (DIR/report.json)"
#: Keys every single fit holds.
REQUIRED_FIT_KEYS = ("parameters", "names", "covariance", "sigma_hat", "converged", "identifiability",
                     "num_residuals", "iterations")
#: Bench-trace columns of each ``segments`` entry.
_TRACES = ("t", "v_d", "v_q", "i_d", "i_q", "i_d_pred", "i_q_pred")


def check_covariance(cov: np.ndarray, names: list[str], source: str, field: str = "covariance") -> None:
    """Refuse a finite covariance that is not symmetric positive semi-definite (a null/NaN one is left alone).

    The test runs on the matrix scaled to unit diagonal (the correlation it implies), so it does not
    depend on the parameters' units; the message gives the covariance's own smallest eigenvalue too.
    """
    check = _Check(source)
    diag = np.diag(cov)
    for i, n in enumerate(names):
        if diag[i] < 0:
            check.fail(f"{field}[{i}][{i}]", f"(the variance of {n}) is negative, {diag[i]:.3g}")
    if cov.size == 0 or not np.all(np.isfinite(cov)):
        return
    fix = "refit, or restore the covariance the fit wrote"
    scale = np.sqrt(np.where(diag > 0, diag, 1.0))
    with np.errstate(all="ignore"):
        corr = cov / np.outer(scale, scale)
        sym = 0.5 * (cov + cov.T)
    if not (np.all(np.isfinite(corr)) and np.all(np.isfinite(sym))):
        check.fail(field, "is not positive semi-definite (a correlation beyond +/-1)", fix)
    if float(np.max(np.abs(corr - corr.T))) > 1e-6:
        check.fail(field, "is not symmetric", fix)
    try:
        lam = float(np.min(np.linalg.eigvalsh(0.5 * (corr + corr.T))))
        lam_cov = float(np.min(np.linalg.eigvalsh(sym)))
    except np.linalg.LinAlgError:
        check.fail(field, "has no eigenvalues (the decomposition does not converge)", fix)
    if lam < -1e-9:
        check.fail(field, f"is not positive semi-definite (smallest eigenvalue {lam_cov:.3g}, {lam:.3g} "
                          "scaled to unit variances: a correlation beyond +/-1)", fix)


def validate_fit(d: Any, source: str = "result", prefix: str = "", *, sections: bool = True) -> None:
    """Check one fit's result JSON (:meth:`Calibration.to_dict` plus :func:`result_document`'s sections).

    Accepts what drivecal writes, nulls included where a value may be undefined
    (the SE and CI of a parameter that is not identifiable, a covariance that
    is not finite); ``sections=False`` checks only what ``Calibration.from_dict``
    reads (the verdict and the residual diagnostics included).

    Raises:
        DataError: a key missing, a value null where a number is needed, of
            the wrong type or shape, or a covariance not symmetric positive
            semi-definite; one sentence naming ``source`` and the field.
    """
    c = _Check(source)
    missing = [k for k in REQUIRED_FIT_KEYS if not isinstance(d, dict) or k not in d]
    if missing:
        raise DataError(f"{source}: not a drivecal result (no '{prefix}{missing[0]}' field); {RESULT_HINT}.")
    params = c.obj(d["parameters"], f"{prefix}parameters")
    if not params:
        c.fail(f"{prefix}parameters", "is empty")
    has_prior = d.get("prior") is not None
    for n, p in params.items():
        f = f"{prefix}parameters.{_key(n)}"
        if n not in ESTIMABLE:
            c.fail(f"{prefix}parameters", f"names {_key(n)}, not a parameter drivecal estimates "
                                          f"({', '.join(ESTIMABLE)})")
        c.obj(p, f)
        for k in ("estimate", "se", "identifiable"):
            if k not in p:
                c.fail(f"{f}.{k}", "is missing")
        c.num(p["estimate"], f"{f}.estimate")
        c.num(p["se"], f"{f}.se")
        c.boolean(p["identifiable"], f"{f}.identifiable")
        if p.get("ci95") is not None:
            c.nums(p["ci95"], f"{f}.ci95", length=2)
        c.num(p.get("initial"), f"{f}.initial")
        c.num(p.get("prior"), f"{f}.prior", null=has_prior, finite=not has_prior)
        c.string(p.get("unit", ""), f"{f}.unit")
        c.string(p.get("reason", ""), f"{f}.reason")
    names = c.strings(d["names"], f"{prefix}names")
    for i, n in enumerate(names):
        if n not in params:
            c.fail(f"{prefix}names[{i}]", f"is {_key(n)}, which is not in parameters")
        if names.index(n) != i:
            c.fail(f"{prefix}names[{i}]", f"repeats {_key(n)}")
    cov = c.matrix(d["covariance"], f"{prefix}covariance", len(names))
    check_covariance(cov, names, source, f"{prefix}covariance")
    if d.get("correlation") is not None:
        corr = c.matrix(d["correlation"], f"{prefix}correlation", len(names))
        if np.any(np.abs(corr[np.isfinite(corr)]) > 1 + 1e-6):
            c.fail(f"{prefix}correlation", "holds a value beyond +/-1")
    c.num(d["sigma_hat"], f"{prefix}sigma_hat")
    c.num(d.get("rss"), f"{prefix}rss")
    c.boolean(d["converged"], f"{prefix}converged")
    c.string(d.get("message", ""), f"{prefix}message")
    c.integer(d.get("result_code", 0), f"{prefix}result_code", -1, 1000)
    c.integer(d["iterations"], f"{prefix}iterations")
    m = c.integer(d["num_residuals"], f"{prefix}num_residuals")
    if m <= len(names):
        c.fail(f"{prefix}num_residuals", f"is {m}, not more than the {len(names)} fitted parameters")
    if d.get("t_factor") is not None and not c.num(d["t_factor"], f"{prefix}t_factor", finite=True) > 0:
        c.fail(f"{prefix}t_factor", "is not positive")
    c.num(d.get("dof"), f"{prefix}dof")
    _validate_identifiability(c, d["identifiability"], f"{prefix}identifiability")
    if has_prior:
        for k, v in c.obj(d["prior"], f"{prefix}prior").items():
            if k not in UNITS:
                c.fail(f"{prefix}prior", f"names {_key(k)}, not a motor parameter")
            c.num(v, f"{prefix}prior.{k}", null=False, finite=True)
    fixed = c.obj(d.get("fixed", {}), f"{prefix}fixed", null=has_prior) or {}
    for k, v in fixed.items():
        c.num(v, f"{prefix}fixed.{_key(k)}", null=has_prior, finite=not has_prior and k in FIXED)
    if not has_prior and "fixed" not in d:
        c.fail(f"{prefix}prior", "is missing (and so is fixed)")
    hist = c.obj(d.get("history"), f"{prefix}history", null=True)
    if hist is not None:
        width = len(c.strings(hist["names"], f"{prefix}history.names")) if "names" in hist else None
        rows = c.lst(hist.get("values"), f"{prefix}history.values")
        for i, row in enumerate(rows):
            width = len(c.lst(row, f"{prefix}history.values[{i}]")) if width is None else width
            c.nums(row, f"{prefix}history.values[{i}]", length=width)
    c.string(d.get("source", ""), f"{prefix}source")
    delay = c.num(d.get("delay_samples", 0), f"{prefix}delay_samples", null=False, finite=True)
    if not 0 <= delay <= 100_000:
        c.fail(f"{prefix}delay_samples", f"is {delay:g}, outside 0 to 100000 samples")
    # The verdict and the residual diagnostics: a Calibration carries them too (Calibration.verdict, .diagnostics).
    c.verdict(d.get("verdict"), f"{prefix}verdict")
    residuals = c.obj(d.get("residuals"), f"{prefix}residuals", null=True) or {}
    for k in ("sigma_ratio", "sigma_stated", "sigma_hat"):
        c.num(residuals.get(k), f"{prefix}residuals.{k}")
    for k in ("sigma_source", "noise_check_off"):  # absent from results saved before they were recorded
        c.string(residuals.get(k), f"{prefix}residuals.{k}", null=True)
    effects = c.lst(residuals.get("unmodelled_effects"), f"{prefix}residuals.unmodelled_effects", null=True) or []
    for i, e in enumerate(effects):
        c.obj(e, f"{prefix}residuals.unmodelled_effects[{i}]")
    if sections:
        _validate_sections(c, d, prefix)


def _validate_identifiability(c: _Check, ident: Any, f: str) -> None:
    c.obj(ident, f)
    for k in ("rank", "identifiable"):
        if k not in ident:
            c.fail(f"{f}.{k}", "is missing")
    c.integer(ident["rank"], f"{f}.rank")
    c.boolean(ident["identifiable"], f"{f}.identifiable")
    for k in ("names", "fit_names"):  # null: taken from the sensitivities
        if ident.get(k) is not None:
            c.strings(ident[k], f"{f}.{k}")
    for k in ("weak_params", "dead_params", "confounded_params"):
        c.strings(ident.get(k, []), f"{f}.{k}")
    for k, v in c.obj(ident.get("reasons", {}), f"{f}.reasons").items():
        c.string(v, f"{f}.reasons.{_key(k)}")
    c.nums(ident.get("singular_values", []), f"{f}.singular_values")
    for k in ("sensitivity", "predicted_se", "predicted_ci95", "variance_inflation"):
        c.number_map(ident.get(k), f"{f}.{k}")
    for k in ("condition_number", "noise_sigma"):
        c.num(ident.get(k), f"{f}.{k}")
    for k in ("num_residuals", "num_params"):
        c.integer(ident.get(k, 0), f"{f}.{k}")


def _validate_sections(c: _Check, d: dict, prefix: str) -> None:
    """What the report reads beyond the Calibration: traces, provenance, effects, specification, truth."""
    for i, seg in enumerate(c.lst(d.get("segments"), f"{prefix}segments", null=True) or []):
        f = f"{prefix}segments[{i}]"
        c.obj(seg, f)
        c.string(seg.get("name"), f"{f}.name")
        c.boolean(seg.get("locked"), f"{f}.locked")
        length = len(c.lst(seg.get("t"), f"{f}.t"))
        for k in _TRACES:
            c.nums(seg.get(k), f"{f}.{k}", length=length)
    c.obj(d.get("plan"), f"{prefix}plan", null=True)
    c.string(d.get("motor_file"), f"{prefix}motor_file", null=True)
    for k in ("input", "versions", "saturation", "flux_maps", "speed"):
        c.obj(d.get(k), f"{prefix}{k}", null=True)
    chosen = c.obj(d.get("effects"), f"{prefix}effects", null=True) or {}
    c.string(chosen.get("mode", "auto"), f"{prefix}effects.mode")
    for i, e in enumerate(c.lst(chosen.get("effects"), f"{prefix}effects.effects", null=True) or []):
        f = f"{prefix}effects.effects[{i}]"
        c.obj(e, f)
        c.string(e.get("effect"), f"{f}.effect")
        c.boolean(e.get("included"), f"{f}.included")
    spec = c.obj(d.get("spec"), f"{prefix}spec", null=True) or {}
    if spec:
        c.string(spec.get("status"), f"{prefix}spec.status")
        c.strings(spec.get("failed"), f"{prefix}spec.failed")
        for i, p in enumerate(c.lst(spec.get("parameters"), f"{prefix}spec.parameters")):
            c.string(c.obj(p, f"{prefix}spec.parameters[{i}]").get("outcome"), f"{prefix}spec.parameters[{i}].outcome")
    for n, t in (c.obj(d.get("truth"), f"{prefix}truth", null=True) or {}).items():
        c.num(c.obj(t, f"{prefix}truth.{_key(n)}").get("true"), f"{prefix}truth.{_key(n)}.true", null=False)


def validate_result(doc: Any, source: str = "result") -> None:
    """Check a result document: one fit (:func:`validate_fit`), or a demo's with one fit per design.

    Raises:
        DataError: one sentence naming ``source`` and the field, with the fix.
    """
    if isinstance(doc, dict) and "designs" in doc:
        designs = _Check(source).obj(doc["designs"], "designs")
        if not designs:
            _Check(source).fail("designs", "is empty")
        for name, fit_doc in designs.items():
            validate_fit(fit_doc, source, f"designs.{_key(name)}.")
        for k in ("noise_sigma", "seed"):
            _Check(source).num(doc.get(k), k)
        return
    validate_fit(doc, source)


def load_result(path: str | os.PathLike) -> dict[str, Any]:
    """Read a saved drivecal result JSON (one fit, or a demo with ``designs``) and check it (:func:`validate_result`).

    Raises:
        DataError: missing file, not JSON, not a drivecal result, or a field
            missing, null where a number is needed, of the wrong type or shape, or a
            covariance that is not symmetric positive semi-definite (one sentence
            naming the file and the field, with the fix).
    """
    p = Path(path)
    if not p.is_file():
        raise DataError(f"{p}: no such file; {RESULT_HINT}.")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise DataError(f"{p}: not a text file, so not a result JSON; {RESULT_HINT}.")
    except json.JSONDecodeError as exc:
        raise DataError(f"{p}: not valid JSON (line {exc.lineno}: {exc.msg}); {RESULT_HINT}.")
    except (RecursionError, ValueError) as exc:  # nesting too deep; an integer too long to read
        raise DataError(f"{p}: not a readable JSON document ({type(exc).__name__}); {RESULT_HINT}.")
    validate_result(doc, str(p))
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
        raise DataError(f"{source}: no design '{design}'; choose one of: {', '.join(fits)}.")
    return design, fits[design]
