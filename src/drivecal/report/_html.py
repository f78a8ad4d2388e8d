"""The self-contained HTML report: one file, figures embedded as PNG data URIs.

``write_html_report(result, path)`` takes only the saved-result JSON dict
(one fit from ``drivecal.report.build_result``, or a demo document with ``designs``),
so a saved JSON renders the same page as the run that saved it. The page
fetches nothing from the network and runs no script. Its only
run-dependent part is the time stamp in ``<time id="generated">``; the
figures are rendered deterministically (fixed size and dpi, no PNG metadata,
fixed ``svg.hashsalt``).

Layout per fit (:func:`fit_section_html`), plain words first: the verdict, the result in sentences, the
estimates against the prior, the main figures, the test as run, the plan, every check done or skipped
(``report._sections``); the statistics behind a disclosure; provenance (input hash, software versions).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from typing import Any, Mapping

import numpy as np

from ..identify import Identifiability
from ..physics import UNITS
from ..results import escape as _e, format_number as _fmt, summary_html
from .._io import FILE_DPI, atomic_path
from .._page import CSS, FIG_DPI, png_data_uri
from .._units import display_unit, format_value
from ._sections import checks_html, kv_table, noise_row, plain_words_html, plan_html, quantity, setup_html

#: The figures `fit --out` and `demo --out` also write as PNG files, embedded at the files' resolution
#: (``_io.FILE_DPI``) and shown at :data:`FIG_DPI`'s size: the renderer draws a figure asked for twice once, so
#: one drawing serves the page and the file.
AT_FILE_DPI = ("estimates", "convergence", "identifiability")


def verdict_html(fit: Mapping[str, Any]) -> str:
    """The verdict block of one fit: headline, then each finding."""
    from ..diagnose import verdict

    v = fit.get("verdict") or verdict(dict(fit))
    items = "".join(f"<li>{_e(d)}</li>" for d in v["details"])
    return (f'<div class="verdict {_e(v["status"])}" data-status="{_e(v["status"])}">'
            f'Verdict: <b>{_e(v["headline"])}</b>{"<ul>" + items + "</ul>" if items else ""}</div>')


def spec_html(fit: Mapping[str, Any]) -> str:
    """The judgement against the motor file's tolerances (the result's ``spec``), '' when none was given."""
    spec = fit.get("spec")
    if not spec:
        return ""
    colour = {"pass": "calibrated", "fail": "failed"}.get(spec["status"], "partial")
    params = fit.get("parameters") or {}
    rows = "".join(_spec_row(p, (params.get(p["name"]) or {}).get("se")) for p in spec["parameters"])
    head = ("<tr><th class='l'>parameter</th><th class='l'>outcome</th><th>estimate</th><th class='l'>95 % CI</th>"
            "<th class='l'>tolerance: limits</th></tr>")
    advice = "".join(f"<li>{_e(a)}</li>" for a in spec["advice"])
    return (f'<div class="verdict {colour}" data-spec="{_e(spec["status"])}">Specification: '
            f'<b>{_e(spec["headline"])}</b>{"<ul>" + advice + "</ul>" if advice else ""}</div>'
            + (f'<table class="spec">{head}{rows}</table>' if rows else ""))


def _spec_row(p: Mapping[str, Any], se: float | None) -> str:
    """One parameter's judgement in its engineering unit: the estimate and interval to the SE's second
    significant digit (as in the summary), the limits as given."""
    low, high = p["ci95"]
    half = se if low is not None and high is not None else None
    scale, unit = display_unit(p["estimate"] if low is None else max(abs(low), abs(high)), p["unit"])

    def shown(x, digits=None):
        return "-" if x is None else format_value(x, scale, digits)

    return (f'<tr><td class="l">{_e(p["name"])} [{_e(unit or "-")}]</td><td class="l">{_e(p["outcome"])}</td>'
            f'<td>{shown(p["estimate"], half)}</td><td class="l">[{shown(low, half)}, {shown(high, half)}]</td>'
            f'<td class="l">{_e(p["tolerance"])}: {shown(p["low"])} .. {shown(p["high"])}</td></tr>')


def _statistics_html(fit: Mapping[str, Any]) -> str:
    ident = fit["identifiability"]
    res = fit.get("residuals") or {}
    rows = [
        ("fit", f"{fit.get('message', '')} after {fit['iterations']} Levenberg-Marquardt steps"),
        ("residuals m (i_d and i_q)", fit["num_residuals"]),
        ("fitted parameters n", f"{len(fit['names'])} ({', '.join(fit['names'])})"),
        ("degrees of freedom m - n", fit.get("dof", "")),
        ("sigma_hat (the residuals' standard deviation)", quantity(fit["sigma_hat"], "A")),
        ("sensor noise checked against", noise_row(fit)),
        ("RSS [A^2]", _fmt(fit.get("rss"))),
        ("identifiability", Identifiability.from_dict(ident).summary()),
        ("residuals white (Ljung-Box)", "-" if not res else
         f"{'yes' if res['white'] else 'NO'} (each p >= {res['whiteness_p_threshold']:.2g} required)"),
    ]
    return kv_table(rows, "stats")


#: Figures of the statistics behind the verdict, shown in the report's disclosure (the others open).
DETAIL_FIGURES = ("convergence", "identifiability", "correlation")


def figure_jobs(fit: Mapping[str, Any], label: str) -> list[tuple[str, tuple[str, dict[str, Any]]]]:
    """(caption, figure job of ``report.plots``) of every figure of one fit, from the JSON alone: first those a
    drive engineer reads (estimates against the prior or truth, currents, residuals, flux maps), then those
    of :data:`DETAIL_FIGURES`."""
    from . import plots
    from ..results import Calibration

    cal = Calibration.from_dict(dict(fit))
    out = []
    truth = fit.get("truth")
    true_vec = np.array([truth[n]["true"] for n in cal.names]) if truth else None
    against = "the truth" if truth else "the prior (the motor file's value; a bench effect's own value)"
    out.append((f"Estimates with 95 % intervals against {against}.", plots.estimates_job(cal, truth=true_vec)))
    segments = fit.get("segments")
    if segments:
        out.append(("Excitation (top) and currents: measured (dots) and predicted by the fit (lines), per segment.",
                    plots.currents_job(segments, title=label)))
        out.append(("Residuals (measured minus predicted current) per segment and axis; dashed: the band that "
                    "holds 95 % of sensor noise (+-1.96 sigma_hat).",
                    plots.residuals_job(segments, sigma_hat=fit["sigma_hat"])))
    if fit.get("flux_maps"):
        out.append(("Flux linkages and incremental inductances of the calibrated law with 95 % bands, over the "
                    "currents the test reached (dotted where extrapolated).", plots.flux_maps_job(fit["flux_maps"])))
    if cal.history is not None:
        out.append((f"Convergence: each fitted parameter per accepted LM step, divided by "
                    f"{'the truth' if truth else 'its final value'}.", plots.convergence_job(cal, truth=true_vec)))
    out.append(("Identifiability before fitting: singular-value spectrum and per-parameter sensitivity "
                "(dead parameters marked).", plots.identifiability_job({label: cal.identifiability})))
    if len(cal.fit_names) >= 2:
        out.append(("Correlation of the fitted parameters.", plots.correlation_job(cal)))
    return out


def fit_figure_jobs(fit: Mapping[str, Any]) -> dict[str, tuple[str, dict[str, Any]]]:
    """The figure jobs of the page of one fit's result JSON (as :func:`render_html` asks for them), by figure name:
    a command that also writes some of them as PNG files (`fit --out`) asks for the same jobs, drawn once."""
    fit = json.loads(json.dumps(fit, allow_nan=False))  # as the page reads it
    return {job[0]: job for _, job in figure_jobs(fit, _label("fit", fit, False))}


def page_dpi(name: str) -> int:
    """The resolution a figure of ``report.plots`` is embedded at (dots per inch): see :data:`AT_FILE_DPI`."""
    return FILE_DPI if name in AT_FILE_DPI else FIG_DPI


def _figures_html(figures: list[tuple[str, str, bytes]]) -> str:
    """``<figure>`` elements of (caption, job name, PNG bytes); one drawn at another resolution than
    :data:`FIG_DPI` is shown at the size it would have there."""
    def size(name: str, png: bytes) -> str:
        dpi = page_dpi(name)
        if dpi == FIG_DPI or png[12:16] != b"IHDR":
            return ""
        width, height = (int.from_bytes(png[k:k + 4], "big") for k in (16, 20))
        return f' width="{round(width * FIG_DPI / dpi)}" height="{round(height * FIG_DPI / dpi)}"'

    return "".join(
        f'<figure><img alt="{_e(cap)}"{size(name, png)} src="{png_data_uri(png)}"><figcaption>{_e(cap)}</figcaption>'
        "</figure>" for cap, name, png in figures
    )


def report_title(fit: Mapping[str, Any]) -> str:
    """What a fit calibrated, for titles: ``"motor.toml from bench.csv"`` (file names), else ``""``."""
    from pathlib import PurePath

    inp = (fit.get("input") or {}).get("path") or fit.get("source")
    motor = fit.get("motor_file")
    parts = [PurePath(motor).name if motor else None, PurePath(inp).name if inp else None]
    if parts[0] and parts[1]:
        return f"{parts[0]} from {parts[1]}"
    return parts[1] or parts[0] or ""


def fit_section_html(fit: Mapping[str, Any], label: str, anchor: str,
                     figures: list[tuple[str, str, bytes]] | None = None) -> str:
    """One fit's section, plain words first: the verdict (and specification), the result in sentences, the
    estimates table with the prior and the change against it, the main figures, the test as run (files,
    sample rate, delay, speed, noise, effects), the plan, every check done or skipped; then, behind a
    disclosure, the statistics (fit statistics, convergence, identifiability, correlation, the whole prior
    and the fixed parameters); then provenance.

    ``figures``: (caption, job name, PNG bytes) of the fit's :func:`figure_jobs`, when already drawn; else
    drawn here.
    """
    if figures is None:
        from .._figures import render

        figures = [(cap, name, render(name, kwargs, page_dpi(name))) for cap, (name, kwargs) in figure_jobs(fit, label)]
    main = _figures_html([f for f in figures if f[1] not in DETAIL_FIGURES])
    detail = _figures_html([f for f in figures if f[1] in DETAIL_FIGURES])
    prior = fit.get("prior") or {n: p.get("prior") for n, p in fit["parameters"].items()}
    prior_rows = [(n, quantity(v, UNITS.get(n, "-"))) for n, v in prior.items()]
    fixed_rows = [(n, quantity(v, UNITS.get(n, "-"))) for n, v in fit.get("fixed", {}).items()]
    inp = fit.get("input") or {}
    versions = fit.get("versions") or {}
    prov = [("input SHA-256", inp.get("sha256", "-")), ("hashed", inp.get("what", "-")),
            ("input file", inp.get("path") or "-"), ("data source", fit.get("source", "-"))]
    prov += [(f"{k} version", v) for k, v in versions.items()]
    return (
        f'<section class="fit" id="{_e(anchor)}"><h2>{_e(label)}</h2>'
        f"{verdict_html(fit)}{spec_html(fit)}"
        f"<h3>The result in plain words</h3>{plain_words_html(fit)}"
        f"<h3>Estimates against the prior</h3>{summary_html(fit)}"
        f"<h3>Figures</h3>{main}"
        f"<h3>The test as run</h3>{setup_html(fit)}"
        f"<h3>Plan</h3>{plan_html(fit)}"
        f"<h3>Checks</h3>{checks_html(fit)}"
        f'<details class="statistics"><summary>The statistics behind the verdict</summary>'
        f"<h3>Fit statistics</h3>{_statistics_html(fit)}{detail}"
        f"<h3>Prior (datasheet values, start of the fit)</h3>"
        f"<p>motor file: <code>{_e(fit.get('motor_file') or 'none (built-in values)')}</code></p>"
        f"{kv_table(prior_rows, 'prior')}"
        f"<h3>Fixed parameters (not estimated)</h3>{kv_table(fixed_rows, 'fixed')}</details>"
        f"<h3>Provenance</h3>{kv_table(prov, 'provenance')}</section>"
    )


def _label(key: str, fit: Mapping[str, Any], multi: bool) -> str:
    """A fit's name in its figures' titles: the design's in a document of several, else what was calibrated."""
    return key if multi else (report_title(fit) or key)


def render_html(result: Mapping[str, Any], *, generated: str | None = None, renderer=None) -> str:
    """The whole page as a string.

    Args:
        result: one fit's result JSON, or a demo document with ``designs``.
        generated: the time stamp to print (default: now, UTC, ISO 8601).
        renderer: a started ``drivecal._figures.FigureRenderer`` to draw the figures in (default: drawn
            here, in this process: workers started for one page cost more than they save).
    """
    from .._figures import FigureRenderer

    from ..results import result_fits

    # Render from exactly what a saved file holds (tuples become lists, numpy
    # scalars plain floats): a fresh result and its saved JSON give one page.
    result = json.loads(json.dumps(result, allow_nan=False))
    stamp = generated or _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    fits = result_fits(dict(result))
    multi = len(fits) > 1
    overview = ""
    if multi:
        items = "".join(
            f'<li><a href="#fit-{_e(k)}">{_e(k)}</a>: <b>{_e((f.get("verdict") or {}).get("headline", ""))}</b></li>'
            for k, f in fits.items()
        )
        overview = f"<h2>Verdicts</h2><ul class='overview'>{items}</ul>"
    jobs = {k: figure_jobs(f, _label(k, f, multi)) for k, f in fits.items()}
    flat = [(name, kwargs, page_dpi(name)) for k in fits for _, (name, kwargs) in jobs[k]]
    pngs = iter((renderer or FigureRenderer(0)).render_all(flat))
    sections = "".join(fit_section_html(f, k if multi else "Result", f"fit-{k}",
                                        [(cap, name, next(pngs)) for cap, (name, _) in jobs[k]])
                       for k, f in fits.items())
    what = "" if multi else report_title(next(iter(fits.values())))
    title = f"Calibration of {what}" if what else "drivecal calibration report"
    extra = ""
    if "noise_sigma" in result and "seed" in result:
        extra = (f"<p>Synthetic bench on the Jaxonomy engine: sensor noise {result['noise_sigma']:g} A, "
                 f"seed {result['seed']}.</p>")
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>"
        f"<h1>{_e(title)}</h1>"
        f'<p class="stamp">drivecal calibration report, generated <time id="generated">{_e(stamp)}</time></p>'
        f"{overview}{extra}{sections}</body></html>\n"
    )


def write_html_report(result: Mapping[str, Any], path: str | os.PathLike, *, generated: str | None = None,
                      renderer=None) -> None:
    """Write the self-contained HTML report of a saved result dict to ``path``, atomically.

    Args:
        result: the result JSON as a dict (``json.load`` of a saved file, or
            ``drivecal.report.build_result(...)`` passed through JSON).
        path: the ``.html`` file to write.
        generated: time stamp to print (default: now).
        renderer: a started ``drivecal._figures.FigureRenderer`` for the figures (see :func:`render_html`).
    """
    page = render_html(result, generated=generated, renderer=renderer)
    with atomic_path(path) as tmp:
        tmp.write_text(page, encoding="utf-8")
