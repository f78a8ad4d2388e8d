"""The fleet report: one self-contained HTML page of a ``drivecal batch`` results table, for a production engineer.

First the verdicts: pass/fail against the specification when the batch judged
one (its ``spec`` column), then the calibration status. Then each check's rule,
what it flagged and how often it flags a healthy motor (computed from the
threshold it runs at), the parameters against their nominal and limits in
engineering units and % of nominal, the motors out of specification, the
outliers, the failures and the model-mismatch alarms. Last, one figure per
parameter: its trend along the line (serial in natural order, or a test-time
column) with a rolling median and band, and its histogram, both on a robust
axis range with the values beyond it drawn at its edge and listed
(``_report_stats`` says how each is computed). The numbers the figures are drawn
from are embedded as JSON (``<script id="fleet-data">``). The page fetches nothing.
"""

from __future__ import annotations

import datetime as _dt
import html as _html
import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..errors import DrivecalError
from .._io import atomic_path
from .._page import CSS, figure_data_uri
from .._parameters import ESTIMABLE, ESTIMATED
from .._status import Spec, Status
from ._report_stats import (BAND_K, DRIFT_FRACTION, DRIFT_NOISE_SD, USABLE, ParameterView, drift_noise, drift_threshold,
                            false_alarm_rates, line_positions, natural_order, outlier_z_of, parameter_view,
                            time_columns)

#: The table's status words counted in the summary, in its order.
_SUMMARY = (Status.CALIBRATED, Status.PARTIAL, Status.NOT_CONVERGED, Status.INVALID)
#: Statuses of the motors listed as failed.
_FAILED = [Status.INVALID.label, Status.NOT_CONVERGED.label]
#: Rows listed per table of motors (the rest are counted).
MAX_ROWS = 200
#: Points of each rolling band kept in the embedded JSON.
_JSON_POINTS = 300
_EXTRA_CSS = """
.counts td:first-child{font-weight:600} tr.fail td{color:#c62828} tr.pass td{color:#2a7d3f}
td.drift{background:#fff3cd} ul.beyond{font-size:.85em;color:#8b1a1a;margin:.2em 0 1em}
section.param{margin-top:1.2em} .note{color:#555;font-size:.9em}
"""


def load_results(path: str | os.PathLike) -> pd.DataFrame:
    """Read a ``drivecal batch`` results table, refusing anything else in one sentence."""
    path = Path(path)
    if not path.is_file():
        raise DrivecalError(f"{path}: no such file; give the .parquet table written by `drivecal batch`.")
    try:
        table = pd.read_parquet(path)
    except Exception as exc:
        raise DrivecalError(f"{path}: not a Parquet table ({exc}); "
                            "give the file written by `drivecal batch`.") from None
    missing = [c for c in ("serial", "file", "status") if c not in table]
    if missing:
        raise DrivecalError(f"{path}: not a drivecal batch table (no column {', '.join(missing)}).")
    return table


def _e(x) -> str:
    return _html.escape(str(x))


def _num(x) -> float | None:
    """A float for JSON (None for NaN or infinity)."""
    try:
        x = float(x)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _flag(table: pd.DataFrame, column: str) -> pd.Series:
    return (table[column].fillna(False).astype(bool) if column in table
            else pd.Series(False, index=table.index))


def _pct(x: float, digits: int = 1) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{digits}f} %"


def _rate(x: float) -> str:
    return f"{100 * x:.2g} %" if x >= 1e-4 else f"{x:.2g}"


def _value(view: ParameterView | None, x) -> str:
    """A value (SI) in the view's unit."""
    x = _num(x)
    if x is None:
        return "–"
    return f"{x * view.factor:.5g}" if view is not None else f"{x:.6g}"


def _counts_table(table_id: str, heading: str, counts: dict[str, int], total: int) -> str:
    rows = "".join(f"<tr class='{_e(k.split()[0])}'><td class='l'>{_e(k)}</td><td>{v}</td>"
                   f"<td>{_pct(100 * v / total if total else math.nan)}</td></tr>" for k, v in counts.items())
    return (f"<table class='counts' id='{table_id}'><tr><th class='l'>{_e(heading)}</th><th>motors</th>"
            f"<th>share</th></tr>{rows}</table>")


def _motor_rows(table: pd.DataFrame, columns: list[str], views: dict[str, ParameterView]) -> str:
    """Motors (natural serial order, at most :data:`MAX_ROWS`) with ``columns``; parameters in engineering units."""
    shown = table.iloc[natural_order(table["serial"].astype(str).to_numpy())[:MAX_ROWS]]
    columns = [c for c in columns if c in table]
    head = "".join(f"<th class='l'>{_e(views[c].label if c in views else c)}</th>" for c in columns)
    cells = {c: [_value(views[c], v) for v in shown[c]] if c in views else
             [f"{v:.3g}" if isinstance(v, float) else str(v) for v in shown[c]] for c in columns}
    body = "".join("<tr>" + "".join(f"<td class='l'>{_e(cells[c][i])}</td>" for c in columns) + "</tr>"
                   for i in range(len(shown)))
    more = f"<p class='note'>and {len(table) - MAX_ROWS} more (see the table)</p>" if len(table) > MAX_ROWS else ""
    return f"<table><tr>{head}</tr>{body}</table>{more}"


def _listing(title: str, table: pd.DataFrame, columns: list[str], views: dict[str, ParameterView],
             empty: str = "none") -> str:
    return (f"<h2>{_e(title)} ({len(table)})</h2>"
            + (_motor_rows(table, columns, views) if len(table) else f"<p>{_e(empty)}</p>"))


def _checks_table(table: pd.DataFrame, views: dict[str, ParameterView], threshold: float,
                  toleranced: int) -> tuple[str, dict[str, Any]]:
    """Each check: its rule, what it flagged here, and its false-alarm rate on healthy motors (and the count
    expected here)."""
    usable = int(table["status"].isin(USABLE).sum())
    z_columns = [c for c in table if c.startswith("z_") and table[c].notna().any()]
    rates = false_alarm_rates(threshold, len(z_columns) or len(views), toleranced)
    flagged = {"outlier": int(_flag(table, "outlier").sum()), "mismatch": int(_flag(table, "mismatch").sum())}
    if "spec" in rates:
        flagged["spec"] = int((table["spec"] == Spec.FAIL.label).sum()) if "spec" in table else 0
    names = {"spec": "specification (fail)", "outlier": "fleet outlier", "mismatch": "model mismatch"}
    rows, data = [], {}
    for key in ("spec", "outlier", "mismatch"):
        if key not in rates:
            continue
        rate, basis = rates[key]["rate"], rates[key]["basis"]
        bound = "≤ " if key != "outlier" else "≈ "
        expected = "–" if key == "spec" else f"{bound}{usable * rate:.2g}"
        rows.append(f"<tr data-check='{key}'><td class='l'>{_e(names[key])}</td><td class='l'>{_e(basis)}</td>"
                    f"<td>{flagged[key]}</td><td>{bound}{_rate(rate)}</td><td>{expected}</td></tr>")
        data[key] = {"rate": rate, "flagged": flagged[key], "expected": None if key == "spec" else usable * rate}
    drift = ("Drift is shown, not alarmed: the rolling median's largest distance from the fleet median, in "
             "half-widths of the rolling band. A drift-free line's rolling median wanders by about the 'drift "
             f"noise' column (1 SD, from the window's length); a drift is called visible from {DRIFT_FRACTION:.0%} "
             f"or {DRIFT_NOISE_SD:g} such SDs, whichever is more.")
    return ("<table id='checks'><tr><th class='l'>check</th><th class='l'>rule</th><th>flagged here</th>"
            f"<th>false alarms per healthy motor</th><th>expected here ({usable} usable)</th></tr>{''.join(rows)}"
            f"</table><p class='note'>{_e(drift)}</p>", data)


def _limits_text(view: ParameterView) -> str:
    lo, hi = view.tolerance
    if lo is None and hi is None:
        return "–"
    parts = [f"{'≥' if hi is None else ''}{_value(view, lo)}" if lo is not None else "",
             f"{'≤' if lo is None else ''}{_value(view, hi)}" if hi is not None else ""]
    text = " .. ".join(p for p in parts if p)
    if view.nominal:
        pct = [f"{view.percent(x):.1f}" for x in (lo, hi) if x is not None]
        text += f" ({' .. '.join(pct)} %)"
    return text


def _parameter_table(views: dict[str, ParameterView]) -> str:
    rows = []
    for view in views.values():
        nominal = _value(view, view.nominal) if view.nominal is not None else "–"
        median = f"{_value(view, view.centre)} ({_pct(view.percent(view.centre))})"
        spread = f"{_value(view, view.scale)} ({_pct(view.percent(view.scale), 2)})"
        beyond = int(view.above.sum() + view.below.sum())
        drift_cls = " drift" if view.drift >= drift_threshold(view.window) else ""
        rows.append(f"<tr data-param='{_e(view.name)}'><td class='l'>{_e(view.label)}</td><td>{nominal}</td>"
                    f"<td>{_e(_limits_text(view))}</td><td>{median}</td><td>{spread}</td>"
                    f"<td>{_value(view, view.values.min())}</td><td>{_value(view, view.values.max())}</td>"
                    f"<td>{beyond}</td><td class='r{drift_cls}'>{_pct(100 * view.drift, 0)}</td>"
                    f"<td>±{_pct(100 * drift_noise(view.window), 0)}</td></tr>")
    return ("<table id='parameters'><tr><th class='l'>parameter</th><th>nominal</th><th>limits (% of nominal)</th>"
            "<th>median (% of nominal)</th><th>robust SD (% of nominal)</th><th>min</th><th>max</th>"
            "<th>beyond the axes</th><th>drift (% of band)</th><th>drift noise (1 SD)</th></tr>"
            + "".join(rows) + "</table>")


def _beyond_list(view: ParameterView) -> str:
    items = []
    for mask, where in ((view.above, "above"), (view.below, "below")):
        for i in np.flatnonzero(mask)[:MAX_ROWS]:
            pct, value = view.percent(view.values[i]), float(view.values[i])
            items.append(f"<li class='beyond' data-serial='{_e(view.serial[i])}' data-value='{value!r}' "
                         f"data-side='{where}'>{_e(view.serial[i])}: {view.name} = {_value(view, view.values[i])} "
                         f"{_e(view.unit)}{f' ({pct:.1f} % of nominal)' if math.isfinite(pct) else ''}, "
                         f"{where} the axis</li>")
    if not items:
        return ""
    return f"<ul class='beyond' data-param='{_e(view.name)}'>{''.join(items)}</ul>"


def _view_json(view: ParameterView) -> dict[str, Any]:
    step = max(1, len(view.band) // _JSON_POINTS)
    x = view.x[::step]
    xs = [str(t) for t in np.datetime_as_string(x, unit="s")] if np.issubdtype(x.dtype, np.datetime64) else \
        [_num(t) for t in x]
    band = {k: [_num(v) for v in view.band[k].to_numpy()[::step]] for k in ("median", "low", "high")} \
        if len(view.band) else {"median": [], "low": [], "high": []}
    return {
        "unit": view.unit, "factor": view.factor, "nominal": _num(view.nominal), "tolerance": [
            _num(t) for t in view.tolerance], "median": _num(view.centre), "robust_sd": _num(view.scale),
        "view": [_num(v) for v in view.view], "off_scale": {k: _num(v) for k, v in view.off_scale.items()},
        "window": view.window, "drift": _num(view.drift), "drift_noise": drift_noise(view.window),
        "drift_threshold": drift_threshold(view.window),
        "drift_visible": bool(view.drift >= drift_threshold(view.window)),
        "band": {"x": xs, "serial": [str(v) for v in view.serial[::step]], **band},
        "beyond": [{"serial": str(view.serial[i]), "value": float(view.values[i]),
                    "side": "above" if view.values[i] > view.view[1] else "below"}
                   for i in np.flatnonzero(view.above | view.below)[:MAX_ROWS]],
        "outliers": [str(s) for s in view.serial[view.flagged][:MAX_ROWS]],
    }


def _trend_positions(table: pd.DataFrame, trend_by: str, source: str) -> tuple[np.ndarray, str]:
    if trend_by != "serial" and trend_by not in table:
        offered = ", ".join(["serial", *time_columns(table)])
        raise DrivecalError(f"--trend-by {trend_by}: {source} has no such column; give one of: {offered}.")
    x, label = line_positions(table, trend_by)
    if not pd.notna(x).any():
        raise DrivecalError(f"--trend-by {trend_by}: the column holds no times or numbers; give 'serial' or "
                            "a column of test times.")
    return x, label


def parameter_views(table: pd.DataFrame, *, nominal: dict[str, float] | None = None,
                    tolerances: dict[str, tuple[float | None, float | None]] | None = None,
                    trend_by: str = "serial", source: str = "the table") -> tuple[dict[str, ParameterView], str]:
    """Each reported parameter's :class:`ParameterView` (those with usable values) and the trend axis label.

    The parameters: R, Ld, Lq, lambda_m and any other toleranced one the table holds.
    """
    nominal, tolerances = nominal or {}, tolerances or {}
    names = [n for n in ESTIMABLE if n in table and (n in ESTIMATED or n in tolerances)]
    x, x_label = _trend_positions(table, trend_by, source)
    threshold = outlier_z_of(table)
    views = {}
    for name in names:
        view = parameter_view(table, name, x, threshold, nominal.get(name), tolerances.get(name))
        if view is not None:
            views[name] = view
    return views, x_label


def render_fleet_html(table: pd.DataFrame, source: str, *, generated: str | None = None,
                      nominal: dict[str, float] | None = None,
                      tolerances: dict[str, tuple[float | None, float | None]] | None = None,
                      trend_by: str = "serial") -> str:
    """The fleet report page as a string.

    Args:
        table: the ``drivecal batch`` results.
        source: where it came from (shown on the page).
        generated: the time stamp to show (default: now, UTC).
        nominal: ``{name: value}`` in SI, drawn as the nominal line and the base of the % of nominal.
        tolerances: ``{name: (low, high)}`` absolute limits in SI (either None: one-sided), drawn as lines.
        trend_by: "serial" (natural order) or a column of the table (test times, or numbers) for the trends.
    """
    stamp = generated or _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    views, x_label = parameter_views(table, nominal=nominal, tolerances=tolerances, trend_by=trend_by,
                                     source=source)
    threshold = outlier_z_of(table)
    status = table["status"]
    n = len(table)
    status_counts = {s.label: int((status == s.label).sum()) for s in _SUMMARY}
    spec_counts = ({s.label: int((table["spec"] == s.label).sum()) for s in Spec} if "spec" in table else None)
    # The specification's check is the batch's (its spec column); the limits it used are the motor file's.
    toleranced = (len([k for k in (tolerances or {}) if k in table]) or len(views)) if "spec" in table else 0
    checks_html, checks = _checks_table(table, views, threshold, toleranced)
    parts = [
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>",
        f"<title>drivecal fleet report</title><style>{CSS}{_EXTRA_CSS}</style></head><body>",
        "<h1>drivecal fleet report</h1>",
        f'<p class="stamp">{_e(source)}: {n} motors; generated <time id="generated">{_e(stamp)}</time></p>',
    ]
    if spec_counts is not None:
        parts += ["<h2>Pass/fail against the specification</h2>",
                  _counts_table("spec-counts", "specification", spec_counts, n)]
    parts += ["<h2>Calibration status</h2>", _counts_table("status-counts", "status", status_counts, n),
              "<h2>Checks and their false-alarm rates</h2>", checks_html,
              "<h2>Parameters</h2>", _parameter_table(views)]
    names = list(views)
    if "spec" in table:
        parts.append(_listing("Out of specification", table[table["spec"] == Spec.FAIL.label],
                              ["serial", "spec_failed"] + names, views))
        parts.append(_listing("Inconclusive", table[table["spec"] == Spec.INCONCLUSIVE.label],
                              ["serial", "spec_inconclusive"] + names, views))
    parts += [
        _listing("Outliers", table[_flag(table, "outlier")], ["serial", "outlier_params"]
                 + [f"z_{n}" for n in names] + names, views, "none at this threshold"),
        _listing("Failed", table[status.isin(_FAILED)], ["serial", "status", "reason", "file"], views),
        _listing("Model mismatch suspected", table[_flag(table, "mismatch")], ["serial", "resid_min_p", "sigma_hat"],
                 views),
    ]
    if views:
        parts.append(_figures_html(table, views, threshold, x_label, trend_by))
    data = {"motors": n, "trend_by": trend_by, "outlier_z": threshold, "drift_fraction": DRIFT_FRACTION,
            "status_counts": status_counts, "spec_counts": spec_counts, "checks": checks,
            "parameters": {name: _view_json(v) for name, v in views.items()}}
    text = json.dumps(data, ensure_ascii=False, allow_nan=False).replace("<", "\\u003c")
    parts.append(f'<script type="application/json" id="fleet-data">{text}</script>')
    parts.append("</body></html>\n")
    return "".join(parts)


def _figures_html(table: pd.DataFrame, views: dict[str, ParameterView], threshold: float, x_label: str,
                  trend_by: str) -> str:
    from ._report_figures import parameter_figure, serial_ticks  # matplotlib: loaded when a page is drawn

    ticks = None
    if trend_by == "serial":
        rank, _ = line_positions(table, "serial")
        ticks = serial_ticks(table["serial"].astype(str).to_numpy(), rank)
    others = [c for c in time_columns(table) if c != trend_by]
    offer = (f" The table also has {', '.join(others)}: `drivecal fleet-report --trend-by {others[0]}` draws the "
             "trends against it." if others else "")
    out = ["<h2>Each parameter along the line</h2>",
           f"<p class='note'>Left: each motor against {_e(x_label)}; the rolling median and band (± {BAND_K:g} "
           "robust SD from the rolling interquartile range) show drift. Right: the histogram on the same axis; the "
           f"shaded band is median ± {threshold:g} robust SD (the outlier threshold). The axes cover the population "
           "(robust range), the nominal (dashed) and the tolerance limits (red); values beyond are drawn at the "
           f"edge as red triangles, labelled with their serial and value, and listed under the figure.{_e(offer)}"
           "</p>"]
    for name, view in views.items():
        fig = parameter_figure(view, threshold, x_label=x_label, serial_tick_marks=ticks)
        drift = ""
        if math.isfinite(view.drift):
            visible = " (visible)" if view.drift >= drift_threshold(view.window) else ""
            drift = f"drift {100 * view.drift:.0f} % of the band's half-width{visible}"
        out.append(f"<section class='param' id='param-{_e(name)}' data-param='{_e(name)}'>"
                   f"<h3>{_e(view.label)}{': ' + drift if drift else ''}</h3>"
                   f"<figure><img alt='{_e(name)} along the line and its histogram' src='{figure_data_uri(fig)}'>"
                   f"</figure>{_beyond_list(view)}</section>")
    return "".join(out)


def write_fleet_report(results: str | os.PathLike, html_out: str | os.PathLike, *,
                       nominal: dict[str, float] | None = None,
                       tolerances: dict[str, tuple[float | None, float | None]] | None = None,
                       trend_by: str = "serial") -> pd.DataFrame:
    """Read the batch table ``results`` and write its HTML report to ``html_out``, atomically
    (``nominal``, ``tolerances``, ``trend_by``: as :func:`render_fleet_html`)."""
    table = load_results(results)
    page = render_fleet_html(table, str(results), nominal=nominal, tolerances=tolerances, trend_by=trend_by)
    with atomic_path(html_out) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return table


def fleet_histograms(table, names=None, threshold=None):
    """Histogram of each estimate over a fleet on its robust axis range, with the median ± threshold band, the
    outliers marked and the values beyond the range counted at its edges.

    Args:
        table: the ``drivecal batch`` results (pandas DataFrame).
        names: parameters to show (default: those present of R, Ld, Lq, lambda_m).
        threshold: the band's half-width in robust SDs (default: the run's ``--outlier-z``, as the
            table records it; ``DEFAULT_OUTLIER_Z`` for a table written before it was recorded).
    """
    from .._figure_kinds import plt
    from ._report_figures import draw_histogram

    threshold = outlier_z_of(table) if threshold is None else float(threshold)
    x, _ = line_positions(table, "serial")
    views = [v for v in (parameter_view(table, n, x, threshold) for n in (names or ESTIMATED) if n in table) if v]
    fig, axes = plt.subplots(1, max(len(views), 1), figsize=(3.6 * max(len(views), 1), 3.0), squeeze=False)
    for ax, view in zip(axes[0], views):
        draw_histogram(ax, view, threshold, vertical=True)
    fig.tight_layout()
    return fig


def fleet_trends(table, names=None):
    """Each estimate against the serial (natural order), with its rolling median and band; outliers in red."""
    from .._figure_kinds import plt
    from ._report_figures import draw_trend, serial_ticks

    threshold = outlier_z_of(table)
    x, x_label = line_positions(table, "serial")
    views = [v for v in (parameter_view(table, n, x, threshold) for n in (names or ESTIMATED) if n in table) if v]
    fig, axes = plt.subplots(max(len(views), 1), 1, figsize=(10, 2.2 * max(len(views), 1)), sharex=True,
                             squeeze=False)
    ticks = serial_ticks(table["serial"].astype(str).to_numpy(), x)
    for ax, view in zip(axes[:, 0], views):
        draw_trend(ax, view, serial_ticks=ticks, legend=ax is axes[0, 0])
    axes[-1, 0].set_xlabel(x_label)
    fig.tight_layout()
    return fig
