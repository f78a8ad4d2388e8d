"""The fleet report's figures, drawn from :class:`ParameterView` (``_report_stats``): one figure per parameter.

Each figure is the parameter along the line (serial in natural order, or test
time) with its rolling median and band, and beside it the parameter's
histogram on the same value axis. Both share the robust axis range: values
beyond it are drawn at its edge as red triangles with their serial and value;
the nominal and the tolerance limits are lines (or named at the edge when far
off); the values are in engineering units, with % of nominal on the right.
Everything is drawn with whole-array calls: a figure costs the same for 100 or
10 000 motors, bar the few edge labels.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib import ticker

from ._report_stats import BAND_K, ParameterView

#: Values beyond the axis labelled with their serial and value, per edge (the most extreme first).
MAX_EDGE_LABELS = 5
_LINE_STYLE = {"nominal": dict(color="0.25", ls="--", lw=1.0),
               "lower limit": dict(color="C3", ls="-", lw=1.3), "upper limit": dict(color="C3", ls="-", lw=1.3)}


class EngineeringFormatter(ticker.Formatter):
    """Tick labels of an SI axis in an engineering unit: the value times ``factor``, as many decimals as the ticks'
    spacing needs."""

    def __init__(self, factor: float):
        self.factor = float(factor)

    def __call__(self, x, pos=None):
        return f"{x * self.factor:.6g}"

    def format_ticks(self, values):
        v = np.asarray(values, dtype=float) * self.factor
        step = np.min(np.abs(np.diff(v))) if v.size > 1 else 0.0
        decimals = int(min(max(-math.floor(math.log10(step) + 1e-9), 0), 9)) if step > 0 else 3
        return [f"{x:.{decimals}f}" for x in v]


def _value_axis(ax, view: ParameterView, vertical: bool):
    """Range, engineering tick labels and label of the value axis (x when ``vertical``, y otherwise)."""
    axis = ax.xaxis if vertical else ax.yaxis
    (ax.set_xlim if vertical else ax.set_ylim)(*view.view)
    axis.set_major_formatter(EngineeringFormatter(view.factor))
    (ax.set_xlabel if vertical else ax.set_ylabel)(view.label)


def _percent_axis(ax, view: ParameterView, vertical: bool) -> None:
    if not view.nominal:
        return
    nominal = float(view.nominal)
    functions = (lambda v: 100.0 * v / nominal, lambda p: p * nominal / 100.0)
    secondary = ax.secondary_xaxis("top", functions=functions) if vertical else \
        ax.secondary_yaxis("right", functions=functions)
    (secondary.set_xlabel if vertical else secondary.set_ylabel)("% of nominal", fontsize=8)
    secondary.tick_params(labelsize=7)


def _mark_lines(ax, view: ParameterView, vertical: bool, legend: bool) -> None:
    """Nominal and limits as lines; those off the axis as a note at its edge."""
    line = ax.axvline if vertical else ax.axhline
    drawn = set()
    for label, value in view.marks().items():
        if label in view.off_scale:
            continue
        style = _LINE_STYLE[label]
        key = "tolerance" if "limit" in label else label
        line(value, label=key if legend and key not in drawn else None, **style)
        drawn.add(key)
    for k, (label, value) in enumerate(view.off_scale.items()):
        high = value > view.view[1]
        text = f"{label} {value * view.factor:.4g} {view.unit} {'↑' if high else '↓'} (off scale)"
        if vertical:
            ax.text(1.0 if high else 0.0, 0.98 - 0.08 * k, text, transform=ax.transAxes, fontsize=7, color="C3",
                    ha="right" if high else "left", va="top")
        else:
            ax.text(0.01, 0.98 - 0.08 * k if high else 0.02 + 0.08 * k, text, transform=ax.transAxes, fontsize=7,
                    color="C3", va="top" if high else "bottom")


def draw_histogram(ax, view: ParameterView, threshold: float, *, vertical: bool = True, legend: bool = True) -> None:
    """The parameter's histogram over the axis range, the outlier band (median ± ``threshold`` robust SDs), the
    flagged motors inside the range as red ticks, and the counts beyond it at its edges."""
    lo, hi = view.view
    inside = view.values[(view.values >= lo) & (view.values <= hi)]
    ax.hist(inside, bins=np.linspace(lo, hi, 41), color="C0", alpha=0.8, label="motors",
            orientation="vertical" if vertical else "horizontal")
    if view.scale > 0:
        span = ax.axvspan if vertical else ax.axhspan
        span(view.centre - threshold * view.scale, view.centre + threshold * view.scale, color="C2", alpha=0.12,
             label=f"median ± {threshold:g} robust SD")
    shown = view.flagged & (view.values >= lo) & (view.values <= hi)
    if shown.any():
        rug = np.column_stack([view.values[shown], np.zeros(shown.sum())])
        ax.plot(*(rug.T if vertical else rug[:, ::-1].T), "|" if vertical else "_", ms=14, mew=2, color="C3",
                transform=ax.get_xaxis_transform() if vertical else ax.get_yaxis_transform(), clip_on=False,
                label="outlier")
    arrows = ("▶", "◀") if vertical else ("▲", "▼")
    for mask, edge, arrow in ((view.above, 1.0, arrows[0]), (view.below, 0.0, arrows[1])):
        if mask.any():
            extreme = view.values[mask].max() if edge else view.values[mask].min()
            text = f"{arrow} {int(mask.sum())} beyond\n(to {extreme * view.factor:.4g})"
            if vertical:
                ax.text(edge, 0.5, text, transform=ax.transAxes, fontsize=7, color="C3", rotation=90,
                        ha="right" if edge else "left", va="center")
            else:
                ax.text(0.98, edge, text, transform=ax.transAxes, fontsize=7, color="C3", ha="right",
                        va="top" if edge else "bottom")
    _mark_lines(ax, view, vertical, legend=False)
    _value_axis(ax, view, vertical)
    (ax.set_ylabel if vertical else ax.set_xlabel)("motors")
    if legend:
        ax.legend(fontsize=7)


def _edge_labels(ax, view: ParameterView, x: np.ndarray) -> None:
    """The values beyond the axis at its edges: red triangles, the most extreme labelled with serial and value."""
    lo, hi = view.view
    label = "beyond the axis (drawn at its edge)"
    for mask, edge, marker, sign in ((view.above, hi, "^", -1), (view.below, lo, "v", 1)):
        if not mask.any():
            continue
        ax.plot(x[mask], np.full(int(mask.sum()), edge), marker, ms=6, color="C3", clip_on=False, zorder=5,
                label=label)
        label = None
        idx = np.flatnonzero(mask)
        idx = idx[np.argsort(-np.abs(view.values[idx] - view.centre), kind="stable")][:MAX_EDGE_LABELS]
        for k, i in enumerate(sorted(idx, key=lambda j: x[j])):
            ax.annotate(f"{view.serial[i]}: {view.values[i] * view.factor:.4g}", (x[i], edge),
                        xytext=(4, sign * (9 + 9 * k)), textcoords="offset points", fontsize=7, color="C3",
                        va="center", arrowprops=dict(arrowstyle="-", color="C3", lw=0.5))
        extra = int(mask.sum()) - len(idx)
        if extra > 0:
            ax.text(0.99, 0.97 if edge == hi else 0.03, f"+{extra} more beyond", transform=ax.transAxes,
                    fontsize=7, color="C3", ha="right", va="top" if edge == hi else "bottom")


def draw_trend(ax, view: ParameterView, *, serial_ticks: tuple[np.ndarray, np.ndarray] | None = None,
               legend: bool = True) -> None:
    """The parameter along the line: the motors, the flagged ones red, the rolling median and band, the nominal
    and the limits, the values beyond the axis at its edge with their values."""
    x, v = view.x, view.values
    lo, hi = view.view
    inside = (v >= lo) & (v <= hi)
    ax.plot(x[inside & ~view.flagged], v[inside & ~view.flagged], ".", ms=3, color="C0", alpha=0.6, label="motors")
    if (inside & view.flagged).any():
        ax.plot(x[inside & view.flagged], v[inside & view.flagged], "o", ms=4, color="C3", label="outlier")
    if len(view.band):
        ax.fill_between(x, view.band["low"], view.band["high"], color="C1", alpha=0.18, lw=0,
                        label=f"rolling band (± {BAND_K:g} robust SD)")
        ax.plot(x, view.band["median"], color="C1", lw=1.8, label=f"rolling median ({view.window} motors)")
    ax.axhline(view.centre, color="C1", lw=0.8, ls=":", label="fleet median")
    _edge_labels(ax, view, x)
    _mark_lines(ax, view, vertical=False, legend=True)
    _value_axis(ax, view, vertical=False)
    if serial_ticks is not None:
        positions, labels = serial_ticks
        ax.xaxis.set_major_locator(ticker.FixedLocator(positions))
        ax.xaxis.set_major_formatter(ticker.FixedFormatter(labels))
        ax.tick_params(axis="x", labelsize=7)
    if legend:
        ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, fontsize=7, frameon=False)


def serial_ticks(table_serials: np.ndarray, rank: np.ndarray, count: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``count`` evenly spaced positions along the natural serial order, labelled with their serials."""
    n = len(rank)
    if not n:
        return np.array([]), np.array([])
    positions = np.unique(np.linspace(0, n - 1, min(count, n)).round().astype(int))
    by_rank = np.empty(n, dtype=object)
    by_rank[rank.astype(int)] = table_serials
    return positions.astype(float), by_rank[positions]


def parameter_figure(view: ParameterView, threshold: float, *, x_label: str,
                     serial_tick_marks: tuple[np.ndarray, np.ndarray] | None = None):
    """One parameter: its trend along the line (left) and its histogram on the same value axis (right)."""
    from .._figure_kinds import plt

    fig, (ax_t, ax_h) = plt.subplots(1, 2, figsize=(14.0, 3.4), sharey=True,
                                     gridspec_kw={"width_ratios": [4.2, 1.0], "wspace": 0.04})
    draw_trend(ax_t, view, serial_ticks=serial_tick_marks)
    ax_t.set_xlabel(x_label)
    draw_histogram(ax_h, view, threshold, vertical=False, legend=False)
    ax_h.set_ylabel("")
    ax_h.tick_params(axis="y", labelleft=False)
    _percent_axis(ax_h, view, vertical=False)
    for ax in (ax_t, ax_h):
        ax.grid(alpha=0.25)
    return fig
