"""The one-line verdict of a calibration, and the residual checks behind it.

The criterion, kept simple on purpose so a reader can check it by hand:

1. **not calibrated: the fit did not converge** when the LM solve failed. Where a saturation term's score
   test flagged the data and no fit with the term converged to take it up, the iron saturates beyond
   drivecal's law (the iron bridges of a PM-assisted motor saturate asymmetrically in i_d): the headline
   names that as the most likely cause and the first detail gives its fix.
2. **model mismatch suspected** when either
   * the residual standard deviation is well above the stated sensor noise:
     ``sigma_hat > SIGMA_RATIO_MAX * sigma_stated`` (1.5: with thousands of
     samples, sigma_hat of a correct model lies within a few percent of the
     noise; 50 % more is a systematic error, not bad luck), or
   * the residuals are not white: a Ljung-Box test with ``WHITENESS_LAGS``
     lags on each segment and current axis rejects at family-wise level
     ``WHITENESS_ALPHA`` (Bonferroni over the tests). A correct model leaves
     sensor noise, which is white; an unmodelled effect (a wrong R, saturation,
     dead time) leaves a smooth, autocorrelated trace.
   * a score test finds the signature of a bench effect the model left out
     (delay, dead time, sensor offsets; on a phase file with its rotor angle an
     encoder offset; ``diagnose/_mismatch.py``) at family-wise
     level 1e-3: the most significant one is named first, in the headline
     and the first detail, with its fix.
   A sigma_hat well *below* the stated noise is reported as a note only.
   Where no noise is stated, the check runs against the sensor noise estimated
   from the samples (:func:`estimated_noise`: the robust second-difference
   level, which the slow currents of a step or a spin-up barely touch), and the
   details say so; where it cannot be estimated the details say that the check
   is off, and why.
   Where a measured speed too coarse or noisy to be exact (``drivecal.data.choose_speed``: flagged) was
   used as an exact input, the mismatch is put down to it first, its fix ``--simulated-speed`` or
   ``--speed output``, and the effect tests' findings as signatures it can leave too (their fixes, such
   as a delay to raise, are not advised); without mismatch it is a note.
3. **partially calibrated: <names> not identifiable by this plan** when the
   identifiability check held some parameters at their prior.
4. **calibrated** otherwise.

Everything here reads plain arrays or the result JSON: the same verdict comes
out of a fresh fit and out of a saved file.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

import numpy as np

from ..data import BenchData
from ..results import Status
from ._whiteness import WHITENESS_ALPHA, WHITENESS_LAGS, ljung_box, whiteness_rule
from ._mismatch import BRIDGE_EFFECTS, MAGNETIC_EFFECTS

#: sigma_hat above this multiple of the stated sensor noise means mismatch.
SIGMA_RATIO_MAX = 1.5
#: Segments shorter than this are left out of the noise estimated from the samples: the robust level of one
#: series of n white samples scatters by ~1.42/sqrt(n) of itself (measured over 20 000 series), 10 % at 200,
#: so a correct model's sigma_hat stays under SIGMA_RATIO_MAX times it by more than three SDs.
NOISE_MIN_SAMPLES = 200
#: An estimated noise below this fraction of the largest current is no noise at all (noise-free synthetic
#: data, or currents quantised coarser than their noise): the check is then off rather than set on zero.
NOISE_FLOOR = 1e-6


def estimated_noise(bench: BenchData) -> tuple[float | None, str]:
    """The current sensor's noise estimated from the samples, for the noise check where none is stated.

    It is ``BenchData.noise_levels``' current level (the median over segments, i_d and i_q, of the robust
    second-difference estimate) over the segments of at least :data:`NOISE_MIN_SAMPLES` samples.

    Returns:
        ``(sigma [A], how it was estimated)``, or ``(None, why it cannot be)``.
    """
    long = tuple(s for s in bench.segments if s.num_samples >= NOISE_MIN_SAMPLES)
    if not long:
        return None, (f"no segment has the {NOISE_MIN_SAMPLES} samples an estimate of the sensor noise from the "
                      f"data needs (the longest has {max(s.num_samples for s in bench.segments)})")
    sigma = dataclasses.replace(bench, segments=long).noise_levels()[0]
    peak = float(np.max(np.abs(bench.currents), initial=0.0))
    if not sigma > NOISE_FLOOR * peak:
        return None, (f"the currents show no measurable noise (second-difference level {sigma:.3g} A against a "
                      f"peak of {peak:.3g} A): noise-free or coarsely quantised samples")
    return float(sigma), f"the robust second-difference level of i_d and i_q, median over {len(long)} segment(s)"


def residual_checks(
    segments: Sequence[tuple[str, np.ndarray]], sigma_hat: float, sigma_stated: float | None, *,
    sigma_source: str | None = "stated", estimated: bool = False, noise_check_off: str | None = None,
) -> dict[str, Any]:
    """Residual diagnostics of one fit.

    Args:
        segments: per segment, its name and residuals ``measured - predicted``
            (A), shape (N, 2) for i_d, i_q.
        sigma_hat: residual standard deviation of the fit (A).
        sigma_stated: the sensor noise the residuals are judged against (A), or None: no noise check.
        sigma_source: where ``sigma_stated`` comes from, in words (e.g. ``"--noise"``).
        estimated: ``sigma_stated`` is an estimate from the samples (:func:`estimated_noise`), not stated.
        noise_check_off: without ``sigma_stated``, why the noise check is off.

    Returns:
        The JSON ``residuals`` block: per segment and axis RMS (A), lag-1
        autocorrelation and Ljung-Box p-value; the Bonferroni threshold; the
        sigma ratio; where the noise came from (``sigma_source``, ``sigma_estimated``) or why the check is
        off (``noise_check_off``); and the two booleans ``white`` and ``noise_consistent``.
    """
    tests = []
    per_segment = []
    for name, res in segments:
        res = np.asarray(res, dtype=float)
        entry: dict[str, Any] = {"name": name, "num_samples": int(res.shape[0])}
        for k, axis in enumerate(("i_d", "i_q")):
            r = res[:, k]
            _, p = ljung_box(r)
            d = r - r.mean()
            lag1 = float(d[:-1] @ d[1:] / (d @ d)) if r.shape[0] > 2 and d @ d > 0 else None
            entry[axis] = {
                "rms": float(np.sqrt(np.mean(r**2))),
                # A segment the model misses stands out here even when the overall sigma_hat looks fine.
                "rms_over_sigma_hat": float(np.sqrt(np.mean(r**2)) / sigma_hat) if sigma_hat > 0 else None,
                "mean": float(r.mean()),
                "lag1_autocorrelation": lag1,
                "ljung_box_p": None if not np.isfinite(p) else p,
            }
            if np.isfinite(p):
                tests.append(p)
        per_segment.append(entry)
    threshold, white = whiteness_rule(tests)
    ratio = float(sigma_hat / sigma_stated) if sigma_stated else None
    return {
        "sigma_hat": float(sigma_hat),
        "sigma_stated": None if sigma_stated is None else float(sigma_stated),
        "sigma_source": None if sigma_stated is None else sigma_source,
        "sigma_estimated": sigma_stated is not None and bool(estimated),
        "noise_check_off": None if sigma_stated is not None else (noise_check_off or "no sensor noise was stated"),
        "sigma_ratio": ratio,
        "sigma_ratio_max": SIGMA_RATIO_MAX,
        "noise_consistent": ratio is None or ratio <= SIGMA_RATIO_MAX,
        "whiteness_lags": WHITENESS_LAGS,
        "whiteness_alpha": WHITENESS_ALPHA,
        "whiteness_p_threshold": threshold,
        "white": bool(white),
        "per_segment": per_segment,
    }


def verdict(result: dict[str, Any]) -> dict[str, Any]:
    """The verdict of one fit's result JSON (see the module docstring for the rule).

    Returns:
        ``{"status", "headline", "details"}``: status a :class:`drivecal.results.Status`
        key (``calibrated``, ``partial``, ``mismatch``, ``failed``); the headline is the sentence a
        report leads with; details list every finding, most serious first.
    """
    not_ident = [n for n, p in result["parameters"].items() if not p["identifiable"]]
    res = result.get("residuals") or {}
    details = []
    mismatch = False
    # The one most likely unmodelled cause first (the score tests come most significant first), with its fix.
    causes = [e for e in res.get("unmodelled_effects") or [] if e["suspected"]]
    speed = _speed_finding(result.get("speed") or {})
    beyond = "" if result["converged"] else _beyond_the_law(result)
    if causes:
        mismatch = True
        details += [e["message"] if not speed[1] else
                    f"the residuals carry a signature like that of {e['effect'].replace('_', ' ')} (score test p = "
                    f"{e['p_value']:.2g}), which the speed input's errors leave too: correct the speed first"
                    for e in causes]
    if beyond:
        mismatch = True
        details.append(beyond)
    noise = ("the sensor noise estimated from the samples" if res.get("sigma_estimated")
             else "the stated sensor noise")
    if res and not res.get("noise_consistent", True):
        mismatch = True
        details.append(
            f"sigma_hat {res['sigma_hat'] * 1e3:.4g} mA is {res['sigma_ratio']:.2f} times {noise} "
            f"{res['sigma_stated'] * 1e3:.4g} mA (limit {res['sigma_ratio_max']:g}x): the model does not explain "
            "the data to the noise level" + (f" (no noise was stated; the estimate is {res['sigma_source']})"
                                             if res.get("sigma_estimated") else "")
        )
    elif res.get("sigma_estimated"):
        details.append(f"noise check against {noise} ({res['sigma_stated'] * 1e3:.4g} mA: {res['sigma_source']}): "
                       f"sigma_hat is {res['sigma_ratio']:.2f} times it; no noise was stated (give --noise or the "
                       "motor file's current_noise to check against the sensor's own)")
    if res and res.get("sigma_stated") is None:
        details.append(f"noise check off: {res.get('noise_check_off') or 'no sensor noise was stated'}; sigma_hat "
                       "is not judged, only the residuals' whiteness and the bench-effect tests (give --noise or the "
                       "motor file's current_noise)")
    if res and not res.get("white", True):
        mismatch = True
        bad = [f"{s['name']} {ax}" for s in res["per_segment"] for ax in ("i_d", "i_q")
               if s[ax]["ljung_box_p"] is not None and s[ax]["ljung_box_p"] < res["whiteness_p_threshold"]]
        details.append("residuals are not white (Ljung-Box, " + ", ".join(bad) + "): a systematic, unmodelled effect")
    if res.get("sigma_ratio") is not None and res["sigma_ratio"] < 1.0 / SIGMA_RATIO_MAX:
        details.append(f"note: sigma_hat is only {res['sigma_ratio']:.2f} times {noise}; "
                       + ("fast signal content in the currents has inflated that estimate" if res.get("sigma_estimated")
                          else "the stated noise may be too pessimistic"))
    for choice in (result.get("effects") or {}).get("effects", []):
        if choice["included"] and choice["how"] == "selected":
            shown = ", ".join(f"{n} = {v['value']:.4g} ± {1.96 * v['se']:.2g} (95 %)" for n, v in choice["estimate"].items()
                              if v["value"] is not None and v["se"] is not None)
            magnetic = choice["effect"] in MAGNETIC_EFFECTS or choice["effect"] in BRIDGE_EFFECTS
            kind = "magnetic saturation" if magnetic else "bench effect"
            evidence = (f"likelihood-ratio p = {choice['p_value']:.2g}" if choice["p_value"] is not None else
                        "the law without the iron bridge did not converge")
            details.append(f"{kind} fitted because the data support it: {choice['effect'].replace('_', ' ')}"
                           f" ({shown}; {evidence})"
                           + ("; the speed input's errors can leave its signature too" if speed[1] else ""))
    if not_ident:
        details.append(f"{', '.join(not_ident)} not identifiable by this plan: held at the prior, not calibrated")
    if speed[0]:
        details.insert(0 if speed[1] and mismatch else len(details), speed[0])
    if not result["converged"]:
        status, headline = Status.NOT_CONVERGED, f"not calibrated: the fit did not converge ({result.get('message', '')})"
        if beyond and not causes and not speed[1]:
            headline += f"; most likely {_BEYOND} (see the first detail for the fix)"
    elif mismatch:
        status, headline = Status.MISMATCH, "model mismatch suspected"
        if speed[1]:
            headline += ": most likely the measured speed input (see the first detail for the fix)"
        elif causes:
            headline += f": most likely {causes[0]['effect'].replace('_', ' ')} (see the first detail for the fix)"
    elif not_ident:
        status, headline = Status.PARTIAL, f"partially calibrated: {', '.join(not_ident)} not identifiable by this plan"
    else:
        status, headline = Status.CALIBRATED, "calibrated"
        if (result.get("effects") or {}).get("magnetic_model") == "saturating":
            headline += ", with magnetic saturation (the saturating law: Ld, Lq, lambda_m at zero current)"
    return {"status": status.key, "headline": headline, "details": details}


#: The headline's words for iron that saturates beyond drivecal's law.
_BEYOND = "magnetic saturation beyond drivecal's saturating law"


def _beyond_the_law(result: dict[str, Any]) -> str:
    """The finding (a detail, with its fix) where the iron saturates beyond drivecal's law, else ``""``.

    Read where the fit did not converge: a term of the law left out as ``not supported`` although its score
    test was below its level. The data show saturation, and no fit with the term took it up.
    """
    flagged = [c for c in (result.get("effects") or {}).get("effects", [])
               if c["effect"] in MAGNETIC_EFFECTS and not c["included"] and c["how"] == "not supported"
               and c["test"] == "score" and c["p_value"] is not None and c["p_threshold"] is not None
               and c["p_value"] < c["p_threshold"]]
    if not flagged:
        return ""
    tried = next((c for c in (result.get("effects") or {}).get("effects", []) if c["effect"] in BRIDGE_EFFECTS), None)
    tests = ", ".join(f"{c['effect'].replace('_', ' ')} p = {c['p_value']:.2g}" for c in flagged)
    return (f"the score tests find magnetic saturation ({tests}) that no fit with drivecal's saturating law took "
            "up: the iron saturates beyond the law the model choice tries (self- and cross-saturation symmetric "
            "about the magnet's flux; the iron bridges of a PM-assisted motor saturate asymmetrically in i_d). "
            "Calibrate the small-signal values on a plan that stays where the iron is linear (a lower current "
            "limit: drivecal plan --imax), or fit each current level on its own; for a PM-assisted motor, state "
            "the law with its iron bridge in the motor file (a [lelli] table, or sat_at_zero = 1 with sat_b, "
            "sat_bp, k_q, psi_n and the saturation terms listed in estimate: docs/bench-effects.md)"
            + (f". Tried: {tried['note']}" if tried else ""))


def _speed_finding(speed: dict[str, Any]) -> tuple[str, bool]:
    """``(detail, the speed is a flagged exact input)`` from the result's ``speed`` section (empty: nothing to say)."""
    if not speed.get("flagged"):
        return "", False
    summary = (speed.get("resolution") or {}).get("summary")
    words = (f"the measured speed w_m{f' ({summary})' if summary else ''} could add up to "
             f"{speed['input_error_ratio']:.3g} times the current noise's variance to the estimates as an exact "
             f"input (limit {speed['input_error_ratio_max']:g})")
    if speed.get("mode") == "input":
        return (words + "; it was one: fit with --simulated-speed (the speed simulated from J and B) or --speed "
                "output (the speed a second measurement)"), True
    how = "a second measured output" if speed.get("mode") == "output" else "left out (simulated from J and B)"
    return f"{words}; it was {how}, so a wrong J or B would show as mismatch", False
