"""The fleet report: one self-contained HTML page of a ``drivecal batch`` results table.

Summary counts, the outliers (with their robust z-scores), the motors that
failed with their reasons, the motors whose residuals suggest model mismatch,
a histogram of each parameter with the outlier band, and each parameter
against the serial order (trends along the line). Figures are embedded PNGs;
the page fetches nothing.
"""

from __future__ import annotations

import datetime as _dt
import html as _html
import os
from pathlib import Path

import pandas as pd

import numpy as np
from ..errors import DrivecalError
from ..report import CSS, figure_data_uri
from ..physics import ESTIMATED, UNITS
from ..results import Status
from .._io import atomic_path
from .._stats import robust_centre_scale
from ._checks import outlier_z_of

#: The table's status words counted in the summary, in its order.
_SUMMARY = (Status.CALIBRATED, Status.PARTIAL, Status.NOT_CONVERGED, Status.INVALID)
#: Statuses whose estimates are usable (drawn and summarised).
_USABLE = [Status.CALIBRATED.label, Status.PARTIAL.label]
#: Statuses of the motors listed as failed.
_FAILED = [Status.INVALID.label, Status.NOT_CONVERGED.label]


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


def _rows(table: pd.DataFrame, columns: list[str]) -> str:
    head = "".join(f"<th class='l'>{_e(c)}</th>" for c in columns)
    body = "".join(
        "<tr>" + "".join(f"<td class='l'>{_e(_fmt(row[c]))}</td>" for c in columns) + "</tr>"
        for _, row in table.iterrows()
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _fmt(x) -> str:
    if isinstance(x, float):
        return f"{x:.6g}"
    return str(x)


def render_fleet_html(table: pd.DataFrame, source: str, *, generated: str | None = None) -> str:
    """The fleet report page as a string."""
    stamp = generated or _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    status = table["status"]
    counts = {s.label: int((status == s.label).sum()) for s in _SUMMARY}
    names = [n for n in ESTIMATED if n in table]
    summary = "".join(f"<tr><td class='l'>{_e(k)}</td><td>{v}</td></tr>" for k, v in counts.items())
    stats = []
    for n in names:
        v = table.loc[status.isin(_USABLE), n].astype(float)
        if len(v):
            centre, robust_sd = robust_centre_scale(v)
            stats.append(f"<tr><td class='l'>{n} [{UNITS[n]}]</td><td>{centre:.6g}</td>"
                         f"<td>{robust_sd:.3g}</td><td>{v.min():.6g}</td>"
                         f"<td>{v.max():.6g}</td></tr>")
    outliers = table[table.get("outlier", False) == True]  # noqa: E712 (a pandas mask)
    failed = table[status.isin(_FAILED)]
    mismatch = table[table.get("mismatch", pd.Series(False, index=table.index)).fillna(False).astype(bool)]
    parts = [
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>",
        f"<title>drivecal fleet report</title><style>{CSS}</style></head><body>",
        "<h1>drivecal fleet report</h1>",
        f'<p class="stamp">{_e(source)}: {len(table)} motors; generated <time id="generated">{_e(stamp)}</time></p>',
        f"<h2>Summary</h2><table><tr><th class='l'>status</th><th>motors</th></tr>{summary}</table>",
        "<table><tr><th class='l'>parameter</th><th>median</th><th>robust SD</th><th>min</th><th>max</th></tr>"
        + "".join(stats) + "</table>",
        f"<h2>Outliers ({len(outliers)})</h2>",
        _rows(outliers, ["serial", "outlier_params"] + [f"z_{n}" for n in names] + names) if len(outliers)
        else "<p>none at this threshold</p>",
        f"<h2>Failed ({len(failed)})</h2>",
        _rows(failed, ["serial", "status", "reason", "file"]) if len(failed) else "<p>none</p>",
        f"<h2>Model mismatch suspected ({len(mismatch)})</h2>",
        _rows(mismatch, ["serial", "resid_min_p", "sigma_hat"]) if len(mismatch) else "<p>none</p>",
    ]
    calibrated = table[status.isin(_USABLE)]
    if len(calibrated):
        parts += [
            "<h2>Distributions</h2>",
            f'<figure><img alt="histograms" src="{figure_data_uri(fleet_histograms(calibrated, names))}">'
            "<figcaption>Each parameter over the fleet; the band is median ± threshold × 1.4826·MAD, "
            "red lines are outliers.</figcaption></figure>",
            "<h2>Trends along the line</h2>",
            f'<figure><img alt="trends" src="{figure_data_uri(fleet_trends(calibrated, names))}">'
            "<figcaption>Each parameter in serial order; outliers in red.</figcaption></figure>",
        ]
    parts.append("</body></html>\n")
    return "".join(parts)


def write_fleet_report(results: str | os.PathLike, html_out: str | os.PathLike) -> pd.DataFrame:
    """Read the batch table ``results`` and write its HTML report to ``html_out``, atomically."""
    table = load_results(results)
    page = render_fleet_html(table, str(results))
    with atomic_path(html_out) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return table


def fleet_histograms(table, names=None, threshold=None):
    """Histogram of each estimate over a fleet, with the median, the ±z band and the outliers marked.

    Args:
        table: the ``drivecal batch`` results (pandas DataFrame).
        names: parameters to show (default: those present of R, Ld, Lq, lambda_m).
        threshold: the band's half-width in robust SDs (default: the run's ``--outlier-z``, as the
            table records it; ``DEFAULT_OUTLIER_Z`` for a table written before it was recorded).
    """
    from ..report.plots import plt

    from ..physics import ESTIMATED, UNITS

    threshold = outlier_z_of(table) if threshold is None else float(threshold)

    names = [n for n in (names or ESTIMATED) if n in table]
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(3.6 * max(len(names), 1), 3.0), squeeze=False)
    for ax, name in zip(axes[0], names):
        values = table[name].astype(float)
        outlier = table.get("outlier_params", "").astype(str).str.contains(rf"\b{name}\b", regex=True)
        ok = values[~outlier].dropna()
        ax.hist(ok, bins=40, color="C0", alpha=0.8, label="motors")
        if outlier.any():
            for v in values[outlier]:
                ax.axvline(v, color="C3", lw=1.2)
            ax.plot([], [], color="C3", label="outlier")
        z = table.get(f"z_{name}")
        if z is not None and z.notna().sum() >= 3:
            centre, scale = robust_centre_scale(values[z.notna()])
            ax.axvspan(centre - threshold * scale, centre + threshold * scale, color="C2", alpha=0.12,
                       label=f"median ± {threshold:g} robust SD")
        ax.set_xlabel(f"{name} [{UNITS[name]}]")
        ax.set_ylabel("motors")
        ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def fleet_trends(table, names=None):
    """Each estimate against the production order (serial), outliers in red."""
    from ..report.plots import plt

    from ..physics import ESTIMATED, UNITS

    names = [n for n in (names or ESTIMATED) if n in table]
    fig, axes = plt.subplots(len(names), 1, figsize=(10, 1.9 * len(names)), sharex=True, squeeze=False)
    order = np.arange(len(table))
    for ax, name in zip(axes[:, 0], names):
        values = table[name].astype(float).to_numpy()
        outlier = table.get("outlier_params", "").astype(str).str.contains(rf"\b{name}\b", regex=True).to_numpy()
        ax.plot(order[~outlier], values[~outlier], ".", ms=2, color="C0")
        ax.plot(order[outlier], values[outlier], "o", ms=4, color="C3")
        ax.set_ylabel(f"{name}\n[{UNITS[name]}]")
    axes[-1, 0].set_xlabel("motor, in serial order")
    fig.tight_layout()
    return fig
