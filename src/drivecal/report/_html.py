"""The self-contained HTML report: one file, figures embedded as PNG data URIs.

``write_html_report(result, path)`` takes only the saved-result JSON dict
(one fit from ``drivecal.report.build_result``, or a demo document with ``designs``),
so a saved JSON renders the same page as the run that saved it. The page
fetches nothing from the network and runs no script. Its only
run-dependent part is the time stamp in ``<time id="generated">``; the
figures are rendered deterministically (fixed size and dpi, no PNG metadata,
fixed ``svg.hashsalt``).

Layout per fit: verdict first, then the summary table, fit statistics, the
figures, the plan, the prior and fixed parameters, and provenance (input
hash, software versions).
"""

from __future__ import annotations

import base64
import datetime as _dt
import io
import json
import os
from typing import Any, Mapping

import numpy as np

from ..identify import Identifiability
from ..physics import UNITS
from ..results import escape as _e, format_number as _fmt, summary_html
from .._io import atomic_path
from .._units import display_unit, format_quantity, format_value

#: Resolution of the embedded figures (dots per inch); fixed for byte-identical PNGs.
FIG_DPI = 80

CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:1.5em auto;max-width:1250px;color:#222;
     padding:0 1em;line-height:1.4}
h1{margin-bottom:.1em} .stamp{color:#666;font-size:.9em;margin-top:0}
.verdict{border-left:8px solid;padding:.6em 1em;margin:.8em 0;font-size:1.15em;background:#f6f6f6}
.verdict.calibrated{border-color:#2a9d3f} .verdict.partial{border-color:#e0a100}
.verdict.mismatch,.verdict.failed{border-color:#c62828}
.verdict b{font-size:1.15em} .verdict ul{margin:.3em 0 0 0;font-size:.85em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right} th{background:#eee}
td.l,th.l{text-align:left} tr.no td{color:#999}
figure{margin:1em 0} figure img{max-width:100%;height:auto;border:1px solid #ddd}
figcaption{color:#555;font-size:.9em}
section.fit{border-top:3px solid #444;margin-top:2em}
code{font-size:.9em}
"""


def figure_data_uri(fig) -> str:
    """PNG of a matplotlib figure as a ``data:`` URI; the figure is closed.

    Deterministic: fixed dpi, tight bounding box, no ``Software`` metadata.
    """
    from .. import _figures

    return png_data_uri(_figures.png_bytes(fig, FIG_DPI))


def png_data_uri(png: bytes) -> str:
    """PNG bytes as a ``data:`` URI."""
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


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


def _quantity(value: Any, unit: str) -> str:
    """A value of the result JSON for a person (engineering units), '-' where there is none."""
    return format_quantity(value, unit) if isinstance(value, (int, float)) and np.isfinite(value) else "-"


def _kv_table(rows: list[tuple[str, Any]], cls: str = "kv") -> str:
    body = "".join(f'<tr><th class="l">{_e(k)}</th><td class="l">{_e(v)}</td></tr>' for k, v in rows)
    return f'<table class="{cls}">{body}</table>'


def _statistics_html(fit: Mapping[str, Any]) -> str:
    ident = fit["identifiability"]
    res = fit.get("residuals") or {}
    rows = [
        ("fit", f"{fit.get('message', '')} after {fit['iterations']} Levenberg-Marquardt steps"),
        ("samples m (i_d and i_q)", fit["num_residuals"]),
        ("fitted parameters n", f"{len(fit['names'])} ({', '.join(fit['names'])})"),
        ("degrees of freedom m - n", fit.get("dof", "")),
        ("sigma_hat", _quantity(fit["sigma_hat"], "A")),
        ("sensor noise checked against", _noise_row(res)),
        ("RSS [A^2]", _fmt(fit.get("rss"))),
        ("identifiability", Identifiability.from_dict(ident).summary()),
        ("residuals white (Ljung-Box)", "-" if not res else
         f"{'yes' if res['white'] else 'NO'} (each p >= {res['whiteness_p_threshold']:.2g} required)"),
    ]
    return _kv_table(rows, "stats")


def _noise_row(res: Mapping[str, Any]) -> str:
    """The noise sigma_hat was checked against and where it came from, or why the check was off."""
    if not res:
        return "-"
    if res.get("sigma_stated") is None:
        return f"none: the noise check is off ({res.get('noise_check_off') or 'no sensor noise was stated'})"
    how = "estimated from the samples" if res.get("sigma_estimated") else "stated"
    source = f", {res['sigma_source']}" if res.get("sigma_source") else ""
    return f"{_quantity(res['sigma_stated'], 'A')} ({how}{source})"


def _plan_html(plan: Mapping[str, Any] | None) -> str:
    if not plan:
        return "<p>No plan recorded (data from a bench file without a plan).</p>"

    def volts(v):
        if isinstance(v, list):
            return f"sequence of {len(v)} values in [{min(v):.4g}, {max(v):.4g}]"
        return f"{v:.6g}"

    rows = "".join(
        f'<tr><td class="l">{_e(s["name"])}</td><td>{s["duration"]:.6g}</td><td class="l">'
        f'{"locked" if s["locked"] else "free"}</td><td class="l">{_e(volts(s["v_d"]))}</td>'
        f'<td class="l">{_e(volts(s["v_q"]))}</td></tr>' for s in plan["segments"]
    )
    head = ("<tr><th class='l'>segment</th><th>duration [s]</th><th class='l'>rotor</th>"
            "<th class='l'>v_d [V]</th><th class='l'>v_q [V]</th></tr>")
    return (f"<p>sample rate {plan['sample_rate']:.6g} Hz, V_dc {plan['v_dc']:.6g} V, current limit "
            f"{plan['current_limit']:.6g} A</p><table class='plan'>{head}{rows}</table>")


def figure_jobs(fit: Mapping[str, Any], label: str) -> list[tuple[str, tuple[str, dict[str, Any]]]]:
    """(caption, figure job of ``report.plots``) of every figure of one fit, from the JSON alone."""
    from . import plots
    from ..results import Calibration

    cal = Calibration.from_dict(dict(fit))
    out = []
    segments = fit.get("segments")
    if segments:
        out.append(("Excitation (top) and currents: measured (dots) and predicted by the fit (lines), per segment.",
                    plots.currents_job(segments, title=label)))
        out.append(("Residuals per segment and axis; dashed: +-1.96 sigma_hat.",
                    plots.residuals_job(segments, sigma_hat=fit["sigma_hat"])))
    if cal.history is not None:
        out.append(("Convergence: each fitted parameter per accepted LM step, divided by its final value.",
                    plots.convergence_job(cal)))
    truth = fit.get("truth")
    true_vec = np.array([truth[n]["true"] for n in cal.names]) if truth else None
    out.append((f"Estimates with 95 % intervals, as deviation from the {'truth' if truth else 'estimate'}.",
                plots.estimates_job(cal, truth=true_vec)))
    out.append(("Identifiability before fitting: singular-value spectrum and per-parameter sensitivity "
                "(dead parameters marked).", plots.identifiability_job({label: cal.identifiability})))
    if len(cal.fit_names) >= 2:
        out.append(("Correlation of the fitted parameters.", plots.correlation_job(cal)))
    if fit.get("flux_maps"):
        out.append(("Flux linkages and incremental inductances of the calibrated law with 95 % bands, over the "
                    "currents the test reached (dotted where extrapolated).", plots.flux_maps_job(fit["flux_maps"])))
    return out


def _figures_html(figures: list[tuple[str, bytes]]) -> str:
    return "".join(
        f'<figure><img alt="{_e(cap)}" src="{png_data_uri(png)}"><figcaption>{_e(cap)}</figcaption></figure>'
        for cap, png in figures
    )


def fit_section_html(fit: Mapping[str, Any], label: str, anchor: str,
                     figures: list[tuple[str, bytes]] | None = None) -> str:
    """One fit's section: verdict first, then table, statistics, figures, plan, prior, provenance.

    ``figures``: (caption, PNG bytes) of the fit's :func:`figure_jobs`, when already drawn; else drawn here.
    """
    if figures is None:
        from .._figures import render

        figures = [(cap, render(name, kwargs, FIG_DPI)) for cap, (name, kwargs) in figure_jobs(fit, label)]
    figs = _figures_html(figures)
    prior = fit.get("prior") or {n: p.get("prior") for n, p in fit["parameters"].items()}
    prior_rows = [(n, _quantity(v, UNITS.get(n, "-"))) for n, v in prior.items()]
    fixed_rows = [(n, _quantity(v, UNITS.get(n, "-"))) for n, v in fit.get("fixed", {}).items()]
    inp = fit.get("input") or {}
    versions = fit.get("versions") or {}
    prov = [("input SHA-256", inp.get("sha256", "-")), ("hashed", inp.get("what", "-")),
            ("input file", inp.get("path") or "-"), ("data source", fit.get("source", "-"))]
    prov += [(f"{k} version", v) for k, v in versions.items()]
    return (
        f'<section class="fit" id="{_e(anchor)}"><h2>{_e(label)}</h2>'
        f"{verdict_html(fit)}{spec_html(fit)}"
        f"<h3>Summary</h3>{summary_html(fit)}"
        f"<h3>Fit statistics</h3>{_statistics_html(fit)}"
        f"<h3>Figures</h3>{figs}"
        f"<h3>Plan</h3>{_plan_html(fit.get('plan'))}"
        f"<h3>Prior (datasheet values, start of the fit)</h3>"
        f"<p>motor file: <code>{_e(fit.get('motor_file') or 'none (built-in values)')}</code></p>"
        f"{_kv_table(prior_rows, 'prior')}"
        f"<h3>Fixed parameters (not estimated)</h3>{_kv_table(fixed_rows, 'fixed')}"
        f"<h3>Provenance</h3>{_kv_table(prov, 'provenance')}</section>"
    )


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
    jobs = {k: figure_jobs(f, k) for k, f in fits.items()}
    flat = [(name, kwargs, FIG_DPI) for k in fits for _, (name, kwargs) in jobs[k]]
    pngs = iter((renderer or FigureRenderer(0)).render_all(flat))
    sections = "".join(fit_section_html(f, k, f"fit-{k}", [(cap, next(pngs)) for cap, _ in jobs[k]])
                       for k, f in fits.items())
    extra = ""
    if "noise_sigma" in result and "seed" in result:
        extra = (f"<p>Synthetic bench on the Jaxonomy engine: sensor noise {result['noise_sigma']:g} A, "
                 f"seed {result['seed']}.</p>")
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>drivecal calibration report</title><style>{CSS}</style></head><body>"
        "<h1>drivecal calibration report</h1>"
        f'<p class="stamp">generated <time id="generated">{_e(stamp)}</time></p>'
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
