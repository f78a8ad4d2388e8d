"""Every figure drivecal draws, built from plain data: numbers, arrays, strings and dicts of them.

The builders take only what a result JSON holds, never drivecal's own types: a
figure can then be drawn in another process that loads numpy and matplotlib and
nothing of JAX (``drivecal._figures`` renders them to PNG, in worker processes).
``drivecal.report.plots`` turns drivecal's objects into these inputs (one place)
and returns the figures to a user. Each builder lays its figure out
(``tight_layout``) and returns it. Units: times in the inputs are seconds,
currents amperes, voltages volts (the figures show ms and mA where they say so).
"""

from __future__ import annotations

from typing import Any, Callable, Mapping, Sequence

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg", force=False)
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def excitation(clean: Sequence[Mapping], noisy: Sequence[Mapping], title: str = ""):
    """Applied voltages (top) and currents (bottom) per segment: noise-free lines, measured dots.

    Args:
        clean, noisy: per segment ``name``, ``locked``, ``t`` (s, shape (N,)), ``voltages`` and
            ``currents`` (V, A; shape (N, 2), columns d and q); the noise-free run and the measured one.
        title: appended to the figure title.
    """
    n = len(clean)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 5.2), squeeze=False, sharex="col")
    for j, (c, m) in enumerate(zip(clean, noisy)):
        t_ms = np.asarray(c["t"]) * 1e3
        volts, amps, measured = (np.asarray(x) for x in (c["voltages"], c["currents"], m["currents"]))
        ax_v, ax_i = axes[0, j], axes[1, j]
        _voltages(ax_v, t_ms, volts[:, 0], volts[:, 1], c)
        ax_i.plot(t_ms, measured[:, 0], ".", ms=1.5, color="0.6", alpha=0.6)
        ax_i.plot(t_ms, measured[:, 1], ".", ms=1.5, color="0.6", alpha=0.6, label="measured")
        ax_i.plot(t_ms, amps[:, 0], color="C0", lw=1.6, label="i_d (noise-free)")
        ax_i.plot(t_ms, amps[:, 1], color="C3", lw=1.6, label="i_q (noise-free)")
        _grid(ax_v, ax_i)
    return _finish(fig, axes, 5, f"Excitation and response{': ' + title if title else ''}")


def _voltages(ax, t_ms: np.ndarray, v_d: np.ndarray, v_q: np.ndarray, segment: Mapping) -> None:
    """A segment's applied v_d, v_q (V) against time (ms), titled with its name and rotor condition."""
    ax.plot(t_ms, v_d, color="C0", label="v_d")
    ax.plot(t_ms, v_q, color="C3", label="v_q")
    ax.set_title(f"{segment['name']} ({'locked' if segment['locked'] else 'free'})", fontsize=10)


def _grid(ax_v, ax_i) -> None:
    ax_i.set_xlabel("time [ms]")
    for ax in (ax_v, ax_i):
        ax.grid(alpha=0.3)


def _finish(fig, axes, markerscale: float, title: str):
    """Axis labels and legends of a voltages-over-currents grid, its title, and the layout."""
    axes[0, 0].set_ylabel("voltage [V]")
    axes[1, 0].set_ylabel("current [A]")
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=8, markerscale=markerscale)
    fig.suptitle(title, wrap=True)
    fig.tight_layout()
    return fig


def convergence(history: np.ndarray, names: Sequence[str], ref: np.ndarray, against_truth: bool):
    """Each fitted parameter per accepted LM step, divided by ``ref`` (the truth or the final estimate).

    Args:
        history: the fitted parameters after each accepted step, shape (steps, len(names)), SI.
        names: the fitted parameters.
        ref: what each is divided by, shape (len(names),), SI.
        against_truth: ``ref`` is the truth (else the final estimate); sets the axis label.
    """
    history, ref = np.asarray(history), np.asarray(ref)
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    steps = np.arange(history.shape[0])
    for k, n in enumerate(names):
        ax.plot(steps, history[:, k] / ref[k], "o-", ms=4, label=n)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("accepted Levenberg-Marquardt step")
    ax.set_ylabel("estimate / " + ("truth" if against_truth else "final estimate") + " [-]")
    ax.set_title("Convergence")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    fig.tight_layout()
    return fig


def estimates(names: Sequence[str], units: Sequence[str], estimate: np.ndarray, ci95: np.ndarray,
              identifiable: Sequence[bool], ref: np.ndarray, reference: str):
    """Each estimate with its 95 % interval against a reference value: the truth, the prior or the estimate.
    A parameter whose reference is not zero is shown as a deviation in % of it; one whose reference is zero
    (a bench effect such as ``v_dead`` or an offset, whose prior is none) as its value in its engineering unit.
    Args:
        names, units: the parameters and their SI units.
        estimate: shape (n,), SI; ci95: shape (n, 2), SI; identifiable: shape (n,).
        ref: shape (n,), SI: the reference values.
        reference: what ``ref`` is, in words for the legend and axis (``"truth"``, ``"prior"``, ``"estimate"``).
    """
    from ._units import display_unit

    estimate, ci95, ref = np.asarray(estimate), np.asarray(ci95), np.asarray(ref)
    fig, axes = plt.subplots(1, len(names), figsize=(3.0 * len(names), 3.4), squeeze=False)
    for i, (ax, n) in enumerate(zip(axes[0], names)):
        relative = bool(ref[i] != 0.0 and np.isfinite(ref[i]))
        scale, shown = display_unit(max(abs(estimate[i]), *np.abs(ci95[i])) if not relative else ref[i], units[i])
        f = (lambda x, r=ref[i]: 100.0 * (x - r) / abs(r)) if relative else (lambda x, s=scale: x / s)
        est = f(estimate[i])
        ax.axhline(f(ref[i]), color="C0", lw=2, label=reference)
        if identifiable[i]:
            lo, hi = f(ci95[i][0]), f(ci95[i][1])
            ax.errorbar([0], [est], yerr=[[est - lo], [hi - est]], fmt="o", color="C3", capsize=6,
                        label="estimate, 95 % CI")
            ax.set_title(f"{n} [{shown or '-'}]\n{estimate[i] / scale:.5g}", fontsize=10)
        else:
            ax.plot([0], [est], "x", color="0.4", ms=10, label="held at prior")
            ax.set_title(f"{n} [{shown or '-'}]\nnot identifiable", fontsize=10, color="C3")
        ax.set_ylabel(f"deviation from the {reference} [%]" if relative else f"{n} [{shown or '-'}]", fontsize=8)
        ax.set(xticks=[], xlim=(-1, 1))
        ax.grid(alpha=0.3, axis="y")
    axes[0, 0].legend(fontsize=8, loc="best")
    fig.suptitle(f"Estimates with 95 % confidence intervals, against the {reference}", wrap=True)
    fig.tight_layout()
    return fig


def identifiability(reports: Sequence[Mapping]):
    """Singular-value spectra (left) and per-parameter sensitivity (right) of several designs.

    Args:
        reports: per design ``label``, ``names``, ``rank``, ``singular_values`` (column-normalised J,
            descending), ``sensitivity`` (A per unit of ln theta) and ``dead`` (the dead parameters).
    """
    fig, (ax_s, ax_p) = plt.subplots(1, 2, figsize=(11, 4))
    floor = 1e-17
    width = 0.8 / max(len(reports), 1)
    for k, rep in enumerate(reports):
        sv = np.asarray(rep["singular_values"])
        rel = np.maximum(sv / sv[0], floor)
        ax_s.semilogy(np.arange(1, len(sv) + 1), rel, "o-", ms=7,
                      label=f"{rep['label']}: rank {rep['rank']}/{len(rep['names'])}")
        sens = np.asarray(rep["sensitivity"])
        x = np.arange(len(rep["names"])) + (k - (len(reports) - 1) / 2) * width
        ax_p.bar(x, np.maximum(sens, floor), width, label=rep["label"], color=f"C{k}")
        for xi, name in zip(x, rep["names"]):
            if name in rep["dead"]:
                ax_p.text(xi, floor * 10, "dead", ha="center", va="bottom", fontsize=8, rotation=90, color="C3")
    names = reports[0]["names"]
    ax_s.set_xlabel("singular-value index")
    ax_s.set_ylabel("sigma_i / sigma_1 (column-normalised J) [-]")
    ax_s.set_title("Singular-value spectrum")
    ax_s.set_xticks(np.arange(1, len(names) + 1))
    ax_s.grid(alpha=0.3, which="both")
    ax_s.legend(fontsize=8)
    ax_p.set_yscale("log")
    ax_p.set_xticks(np.arange(len(names)))
    ax_p.set_xticklabels(names)
    ax_p.set_ylabel("||dI / d ln(theta)|| [A]")
    ax_p.set_title("Per-parameter sensitivity")
    ax_p.grid(alpha=0.3, axis="y", which="both")
    ax_p.legend(fontsize=8)
    for axis in (ax_s.yaxis, ax_p.yaxis):
        axis.set_major_formatter(_LogLabels())
        axis.set_minor_formatter(_LogLabels())
    fig.suptitle("Identifiability before fitting", wrap=True)
    fig.tight_layout()
    return fig


class _LogLabels(matplotlib.ticker.LogFormatterSciNotation):
    """A log axis's labels (``10⁻⁵``, ``2×10⁻⁵``) in plain text with superscripts, not mathtext: the same labels,
    without a parse by mathtext's grammar (tens of ms per label)."""

    def __call__(self, x, pos=None):
        text = super().__call__(x, pos)
        if not (text.startswith("$\\mathdefault{") and text.endswith("}$")):
            return text
        base, _, power = text[len("$\\mathdefault{"):-2].replace("\\times", "×").partition("^{")
        return base + power.rstrip("}").translate(_SUPERSCRIPTS)


_SUPERSCRIPTS = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _segment_arrays(seg: Mapping) -> dict[str, np.ndarray]:
    return {k: np.asarray(seg[k], dtype=float) for k in ("t", "v_d", "v_q", "i_d", "i_q", "i_d_pred", "i_q_pred")}


def currents(segments: Sequence[Mapping], title: str = ""):
    """Per segment: applied voltages (top), measured currents (dots) and the fit's prediction (lines, bottom).

    Args:
        segments: a result JSON's ``segments`` section: per segment ``name``, ``locked``, ``t`` (s),
            ``v_d``, ``v_q`` (V), ``i_d``, ``i_q`` measured and ``i_d_pred``, ``i_q_pred`` predicted (A).
        title: appended to the figure title.
    """
    n = len(segments)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 5.2), squeeze=False, sharex="col")
    for j, seg in enumerate(segments):
        a = _segment_arrays(seg)
        t_ms = a["t"] * 1e3
        ax_v, ax_i = axes[0, j], axes[1, j]
        _voltages(ax_v, t_ms, a["v_d"], a["v_q"], seg)
        ax_i.plot(t_ms, a["i_d"], ".", ms=1.5, color="C0", alpha=0.35)
        ax_i.plot(t_ms, a["i_q"], ".", ms=1.5, color="C3", alpha=0.35)
        ax_i.plot(t_ms, a["i_d_pred"], color="k", lw=1.2, label="predicted (fit)")
        ax_i.plot(t_ms, a["i_q_pred"], color="k", lw=1.2)
        ax_i.plot([], [], ".", color="C0", label="i_d measured")
        ax_i.plot([], [], ".", color="C3", label="i_q measured")
        _grid(ax_v, ax_i)
    return _finish(fig, axes, 4, f"Excitation, measured and predicted currents{': ' + title if title else ''}")


def residuals(segments: Sequence[Mapping], sigma_hat: float | None = None):
    """Residuals ``measured - predicted`` (mA) per segment and axis, with the +-1.96 sigma_hat band.

    Args:
        segments: a result JSON's ``segments`` section (see :func:`currents`).
        sigma_hat: residual standard deviation of the fit (A), for the band.
    """
    n = len(segments)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 4.6), squeeze=False, sharex="col", sharey="row")
    for j, seg in enumerate(segments):
        a = _segment_arrays(seg)
        t_ms = a["t"] * 1e3
        for k, (axis, color) in enumerate((("i_d", "C0"), ("i_q", "C3"))):
            r = a[axis] - a[axis + "_pred"]
            ax = axes[k, j]
            ax.plot(t_ms, r * 1e3, ".", ms=1.5, color=color, alpha=0.6)
            if sigma_hat is not None:
                for sgn in (-1, 1):
                    ax.axhline(sgn * 1.96 * sigma_hat * 1e3, color="k", lw=0.8, ls="--")
            ax.axhline(0.0, color="k", lw=0.6)
            ax.set_title(f"{seg['name']}: {axis}, RMS {np.sqrt(np.mean(r**2)) * 1e3:.3g} mA", fontsize=9)
            ax.grid(alpha=0.3)
        axes[1, j].set_xlabel("time [ms]")
    axes[0, 0].set_ylabel("i_d residual [mA]")
    axes[1, 0].set_ylabel("i_q residual [mA]")
    fig.suptitle("Residuals (measured - predicted)" + (", dashed: +-1.96 sigma_hat" if sigma_hat else ""),
                 wrap=True)
    fig.tight_layout()
    return fig


def correlation(names: Sequence[str], corr: np.ndarray):
    """Heat-map of the correlation matrix (shape (n, n)) of the fitted parameters, values written in each cell."""
    corr = np.asarray(corr)
    n = len(names)
    fig, ax = plt.subplots(figsize=(1.2 * n + 2.4, 1.1 * n + 1.4))
    im = ax.imshow(corr, vmin=-1.0, vmax=1.0, cmap="RdBu_r")
    for i in range(n):
        for j in range(n):
            ax.text(j, i, f"{corr[i, j]:+.2f}", ha="center", va="center", fontsize=9,
                    color="white" if abs(corr[i, j]) > 0.6 else "black")
    ax.set_xticks(range(n))
    ax.set_xticklabels(names)
    ax.set_yticks(range(n))
    ax.set_yticklabels(names)
    fig.colorbar(im, ax=ax, label="correlation [-]")
    ax.set_title("Parameter correlation")
    fig.tight_layout()
    return fig


def flux_maps(section: Mapping):
    """The flux maps and incremental inductances with their 95 % bands, from a result's ``flux_maps`` section.

    Top: ``psi_d`` (Wb) against ``i_d`` and ``psi_q`` against ``i_q`` (A); bottom: ``L_dd``, ``L_qq``
    (mH). One line per value of the other current (up to four, zero among them), its band shaded;
    solid where the data tested the point, dotted where it is extrapolated.
    """
    i_d, i_q = np.asarray(section["i_d"], float), np.asarray(section["i_q"], float)
    tested = np.asarray(section["tested"], bool)
    maps = {k: {p: np.asarray(v[p], dtype=float) for p in ("value", "low", "high")}
            for k, v in section["maps"].items()}
    fig, axes = plt.subplots(2, 2, figsize=(9.6, 7.0), sharex="col")
    for col, (axis, grid, other, flux, ind) in enumerate((("d", i_d, i_q, "psi_d", "L_dd"),
                                                          ("q", i_q, i_d, "psi_q", "L_qq"))):
        picks = sorted(set(np.linspace(0, len(other) - 1, 4).round().astype(int)) | {int(np.argmin(np.abs(other)))})
        for n, k in enumerate(picks[:5]):
            def line(name):
                m = maps[name]
                sel = (slice(None), k) if axis == "d" else (k, slice(None))
                return m["value"][sel], m["low"][sel], m["high"][sel], tested[sel]

            label = f"i_{'q' if axis == 'd' else 'd'} = {other[k]:.3g} A"
            for row, name, scale in ((0, flux, 1.0), (1, ind, 1e3)):
                value, low, high, ok = line(name)
                ax = axes[row, col]
                ax.fill_between(grid, low * scale, high * scale, color=f"C{n}", alpha=0.25, lw=0)
                ax.plot(grid, np.where(ok, value, np.nan) * scale, color=f"C{n}", lw=1.4, label=label)
                ax.plot(grid, value * scale, color=f"C{n}", lw=0.8, ls=":")
        axes[0, col].set_ylabel(f"{flux} [Wb]")
        axes[1, col].set_ylabel(f"{ind} [mH]")
        axes[1, col].set_xlabel(f"i_{axis} [A]")
        axes[0, col].legend(fontsize=7)
        for ax in axes[:, col]:
            ax.grid(alpha=0.3)
    fig.suptitle("Flux and incremental inductance with 95 % bands (dotted: extrapolated)", wrap=True)
    fig.tight_layout()
    return fig


#: The figures by name, for jobs sent to another process.
FIGURES: dict[str, Callable[..., Any]] = {f.__name__: f for f in (
    excitation, convergence, estimates, identifiability, currents, residuals, correlation, flux_maps)}
