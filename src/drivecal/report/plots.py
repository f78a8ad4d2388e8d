"""Figures, each returned as a matplotlib Figure (save it, or show it in a notebook).

Each ``*_figure`` function has a ``*_job`` twin giving ``(name, inputs)``: the
figure's plain inputs (numbers, arrays, strings), which ``drivecal._figures``
draws in this process or in a worker (``FigureRenderer``). The figures
themselves are defined once, in ``drivecal._figure_kinds``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from .. import _figure_kinds
from .._figure_kinds import plt  # noqa: F401  (pyplot on the Agg backend, as drivecal's figures draw with it)
from ..physics import UNITS

if TYPE_CHECKING:
    from ..data import BenchData
    from ..identify import Identifiability
    from ..results import Calibration

Job = tuple[str, dict[str, Any]]


def _build(job: Job):
    name, kwargs = job
    return _figure_kinds.FIGURES[name](**kwargs)


def _segments(data: "BenchData") -> list[dict[str, Any]]:
    return [{"name": s.name, "locked": bool(s.locked), "t": np.asarray(s.t), "voltages": np.asarray(s.voltages),
             "currents": np.asarray(s.currents)} for s in data.segments]


def excitation_job(clean: "BenchData", noisy: "BenchData", title: str = "") -> Job:
    """The inputs of :func:`excitation_figure`."""
    return "excitation", {"clean": _segments(clean), "noisy": _segments(noisy), "title": title}


def excitation_figure(clean: "BenchData", noisy: "BenchData", title: str = ""):
    """Applied voltages (top) and currents (bottom) per segment: noise-free lines, measured dots."""
    return _build(excitation_job(clean, noisy, title))


def convergence_job(calibration: "Calibration", truth: np.ndarray | None = None) -> Job:
    """The inputs of :func:`convergence_figure`."""
    history = calibration.history
    if history is None:
        raise ValueError("convergence_figure needs a single fit (a batch records no history)")
    names = tuple(calibration.fit_names)
    idx = [calibration.names.index(n) for n in names]
    ref = np.asarray(truth)[idx] if truth is not None else np.asarray(calibration.estimate)[idx]
    return "convergence", {"history": np.asarray(history), "names": names, "ref": ref,
                           "against_truth": truth is not None}


def convergence_figure(calibration: "Calibration", truth: np.ndarray | None = None):
    """Each fitted parameter per accepted LM step, divided by the truth (or the final estimate)."""
    return _build(convergence_job(calibration, truth))


def estimates_job(calibration: "Calibration", truth: np.ndarray | None = None) -> Job:
    """The inputs of :func:`estimates_figure`: against the truth when given, else against the prior (the
    motor file's datasheet values, which a real fit has; a parameter with no prior value is shown as is)."""
    names = tuple(calibration.names)
    prior = np.array([float(getattr(calibration.prior, n)) for n in names])
    return "estimates", {
        "names": names, "units": tuple(UNITS[n] for n in names), "estimate": np.asarray(calibration.estimate),
        "ci95": np.asarray(calibration.ci95), "identifiable": tuple(bool(x) for x in calibration.identifiable),
        "ref": np.asarray(truth) if truth is not None else prior,
        "reference": "truth" if truth is not None else "prior"}


def estimates_figure(calibration: "Calibration", truth: np.ndarray | None = None):
    """Each estimate with its 95 % interval, as a deviation (%) from the truth or the prior."""
    return _build(estimates_job(calibration, truth))


def identifiability_job(reports: Mapping[str, "Identifiability"]) -> Job:
    """The inputs of :func:`identifiability_figure`."""
    return "identifiability", {"reports": [
        {"label": label, "names": tuple(rep.names), "rank": int(rep.rank),
         "singular_values": np.asarray(rep.singular_values), "sensitivity": np.asarray(rep.sensitivity),
         "dead": tuple(rep.dead_params)} for label, rep in reports.items()]}


def identifiability_figure(reports: Mapping[str, "Identifiability"]):
    """Singular-value spectra (left) and per-parameter sensitivity (right) of several designs."""
    return _build(identifiability_job(reports))


def currents_job(segments: Sequence[Mapping], title: str = "") -> Job:
    """The inputs of :func:`currents_figure`."""
    return "currents", {"segments": list(segments), "title": title}


def currents_figure(segments: Sequence[Mapping], title: str = ""):
    """Per segment: applied voltages (top), measured currents (dots) and the fit's prediction (lines, bottom).

    Args:
        segments: the result JSON's ``segments`` section (``record.segment_traces``):
            per segment ``name``, ``locked``, ``t`` (s), ``v_d``, ``v_q`` (V),
            ``i_d``, ``i_q`` measured and ``i_d_pred``, ``i_q_pred`` predicted (A).
        title: appended to the figure title.
    """
    return _build(currents_job(segments, title))


def residuals_job(segments: Sequence[Mapping], sigma_hat: float | None = None) -> Job:
    """The inputs of :func:`residuals_figure`."""
    return "residuals", {"segments": list(segments), "sigma_hat": sigma_hat}


def residuals_figure(segments: Sequence[Mapping], sigma_hat: float | None = None):
    """Residuals ``measured - predicted`` (A) per segment and axis, with the +-1.96 sigma_hat band.

    Args:
        segments: the result JSON's ``segments`` section (see :func:`currents_figure`).
        sigma_hat: residual standard deviation of the fit (A), for the band.
    """
    return _build(residuals_job(segments, sigma_hat))


def correlation_job(calibration: "Calibration") -> Job:
    """The inputs of :func:`correlation_figure`."""
    return "correlation", {"names": tuple(calibration.fit_names), "corr": np.asarray(calibration.correlation)}


def correlation_figure(calibration: "Calibration"):
    """Heat-map of the correlation matrix of the fitted parameters, values written in each cell."""
    return _build(correlation_job(calibration))


def flux_maps_job(section: Mapping) -> Job:
    """The inputs of :func:`flux_maps_figure`."""
    return "flux_maps", {"section": section}


def flux_maps_figure(section: Mapping):
    """The flux maps and incremental inductances with their 95 % bands, from a result's ``flux_maps`` section.

    Top: ``psi_d`` (Wb) against ``i_d`` and ``psi_q`` against ``i_q`` (A); bottom: ``L_dd``, ``L_qq``
    (mH). One line per value of the other current (up to four, zero among them), its band shaded;
    solid where the data tested the point, dotted where it is extrapolated.
    """
    return _build(flux_maps_job(section))
