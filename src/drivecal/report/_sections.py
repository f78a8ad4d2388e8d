"""The parts of a fit's report a drive engineer reads first, from one fit's result JSON (a dict) alone.

- :func:`plain_words_html`: each parameter in a sentence: value, 95 % interval, change against the prior.
- :func:`setup_html`: the test as run: files, samples and sample rate, the computation delay, what the
  measured speed was used as, the current noise, the bench effects and the magnetic model.
- :func:`plan_html`: the plan as recorded, or (a bench file without one) the segments as the file holds them.
- :func:`checks_html`: every check drivecal makes, done or skipped, each with its outcome or the reason.

Numbers are shown in engineering units (:mod:`drivecal._units`); the JSON stays SI.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from ..physics import UNITS
from ..results import escape as _e
from .._units import format_quantity

#: The rows a check's outcome may take, with the CSS class of its cell.
DONE, SKIPPED, FAILED = "done", "skipped", "failed"

#: What each result "speed" mode means, in words.
SPEED_MODES = {"input": "an exact input of the model (the rotor's speed as measured)",
               "output": "a second measured output (the speed simulated from J and B, weighed by its noise)",
               "ignore": "not used (the speed simulated from J and B)"}


def quantity(value: Any, unit: str, uncertainty: float | None = None) -> str:
    """A value of the result JSON for a person (engineering units), '-' where there is none."""
    if not isinstance(value, (int, float)) or not np.isfinite(value):
        return "-"
    return format_quantity(value, unit, uncertainty)


def kv_table(rows: list[tuple[str, Any]], cls: str = "kv") -> str:
    """A two-column table: a header cell and a value per row (both escaped)."""
    body = "".join(f'<tr><th class="l">{_e(k)}</th><td class="l">{_e(v)}</td></tr>' for k, v in rows)
    return f'<table class="{cls}">{body}</table>'


def sample_rate(fit: Mapping[str, Any]) -> float | None:
    """The sample rate [Hz]: the plan's, else the median spacing of the recorded segments' times."""
    plan = fit.get("plan")
    if plan and plan.get("sample_rate"):
        return float(plan["sample_rate"])
    steps = [np.diff(np.asarray(s["t"], dtype=float)) for s in fit.get("segments") or () if len(s["t"]) > 1]
    steps = np.concatenate(steps) if steps else np.array([])
    return float(1.0 / np.median(steps)) if steps.size and np.median(steps) > 0 else None


# --- the result in plain words --------------------------------------------------------------------

def _sentence(name: str, p: Mapping[str, Any]) -> str:
    unit = p.get("unit") or UNITS.get(name, "-")
    prior = p.get("prior")
    has_prior = isinstance(prior, (int, float)) and np.isfinite(prior)
    if not p.get("identifiable") or not p.get("ci95"):
        held = f"; held at the prior {quantity(prior, unit)}" if has_prior else ""
        return f"{name}: not determined by this test ({p.get('reason', 'not identifiable')}){held}."
    low, high = p["ci95"]
    est, half = float(p["estimate"]), 0.5 * (high - low)
    text = f"{name} = {quantity(est, unit, half)} (95 % interval)"
    if not has_prior:
        return text + "."
    if prior == 0.0:
        inside = low <= 0.0 <= high
        return text + (": none, as assumed (zero is inside the interval)." if inside else
                       ": present (zero is outside the interval).")
    change, change_half = 100.0 * (est - prior) / abs(prior), 100.0 * half / abs(prior)
    digits = max(0, min(6, 1 - int(np.floor(np.log10(change_half))))) if change_half > 0 else 2
    where = "above" if change > 0 else "below"
    inside = low <= prior <= high
    return (text + f": {abs(change):.{digits}f} ± {change_half:.{digits}f} % {where} the prior "
            f"{quantity(prior, unit)}" + (" (inside the interval)." if inside else
                                          ": this unit differs from it by more than the interval."))


def plain_words_html(fit: Mapping[str, Any]) -> str:
    """Each parameter in a sentence (value and 95 % interval, change against the prior), one list."""
    items = "".join(f"<li>{_e(_sentence(n, p))}</li>" for n, p in fit["parameters"].items())
    return f'<ul class="plain">{items}</ul>'


# --- the test as run ------------------------------------------------------------------------------

def _delay_row(fit: Mapping[str, Any]) -> str:
    assumed = float(fit.get("delay_samples") or 0.0)
    params = fit.get("parameters") or {}
    if "delay" in params and params["delay"].get("identifiable") and params["delay"].get("ci95"):
        low, high = params["delay"]["ci95"]
        return (f"fitted: {quantity(params['delay']['estimate'], 'samples', 0.5 * (high - low))} "
                f"(95 %; started from {assumed:g})")
    text = f"{assumed:g} samples, as assumed (the motor file's delay_samples or --delay), not fitted"
    test = _effect(fit, "delay")
    if test and test.get("p_value") is not None:
        text += f"; the data tested for another delay: {test['how']} (p = {test['p_value']:.2g})"
    return text


def _speed_row(fit: Mapping[str, Any]) -> str:
    speed = fit.get("speed") or {}
    if not fit.get("measured_speed") and not speed.get("resolution"):
        return "none in the file: simulated from the motor file's J and B"
    mode = speed.get("mode") or ("input" if fit.get("measured_speed") else "ignore")
    how = "as asked" if speed.get("requested") else "chosen by default"
    text = f"{SPEED_MODES.get(mode, mode)}, {how}"
    resolution = speed.get("resolution") or {}
    if resolution.get("summary"):
        text += f"; its resolution: {resolution['summary']}"
    return text + (f" ({speed['reason']})" if speed.get("reason") else "")


def noise_row(fit: Mapping[str, Any]) -> str:
    """The noise sigma_hat was checked against and where it came from, or why the check was off."""
    res = fit.get("residuals") or {}
    if not res:
        return "-"
    if res.get("sigma_stated") is None:
        return f"none: the noise check is off ({res.get('noise_check_off') or 'no sensor noise was stated'})"
    how = "estimated from the samples" if res.get("sigma_estimated") else "stated"
    source = f", {res['sigma_source']}" if res.get("sigma_source") else ""
    return f"{quantity(res['sigma_stated'], 'A')} ({how}{source})"


def _effect(fit: Mapping[str, Any], name: str) -> Mapping[str, Any] | None:
    return next((e for e in (fit.get("effects") or {}).get("effects", ()) if e["effect"] == name), None)


def setup_html(fit: Mapping[str, Any]) -> str:
    """The test as run: files, samples and rate, delay, speed, noise, bench effects, magnetics."""
    segments = fit.get("segments") or []
    rate = sample_rate(fit)
    samples = sum(len(s["t"]) for s in segments)
    inp = fit.get("input") or {}
    effects = fit.get("effects") or {}
    included = effects.get("included") or []
    rows = [
        ("bench file", inp.get("path") or fit.get("source") or "-"),
        ("motor file (the prior)", fit.get("motor_file") or "none (the built-in demo motor)"),
        ("samples", f"{samples} per current axis in {len(segments)} segment(s)" if segments else "-"),
        ("sample rate", quantity(rate, "Hz") if rate else "-"),
        ("computation delay", _delay_row(fit)),
        ("measured speed used as", _speed_row(fit)),
        ("current-sensor noise", noise_row(fit)),
        ("bench effects", (f"{effects.get('mode', 'auto')}: " + (", ".join(included) if included else
                                                                "none needed by the data")) if effects else
         "none modelled (--effects none)"),
        ("magnetic model", effects.get("magnetic_model") or effects.get("magnetics") or "linear"),
    ]
    return kv_table(rows, "setup")


# --- the plan -------------------------------------------------------------------------------------

def _volts(v: Any) -> str:
    if isinstance(v, list):
        return f"{len(v)} values in [{min(v):.4g}, {max(v):.4g}]"
    if isinstance(v, dict):  # a waveform (ramp, chirp, ...): its kind and level
        return ", ".join(f"{k} {x:.4g}" if isinstance(x, (int, float)) else f"{k} {x}" for k, x in v.items())
    return f"{v:.4g}"


def _span(x: np.ndarray) -> str:
    low, high = float(np.min(x)), float(np.max(x))
    return f"{low:.4g}" if abs(high - low) <= 1e-9 * max(1.0, abs(high)) else f"{low:.4g} .. {high:.4g}"


def plan_html(fit: Mapping[str, Any]) -> str:
    """The plan as recorded (segments, sample rate, voltages, durations), else the segments as the bench file
    holds them (duration, samples, voltage range, peak current)."""
    plan = fit.get("plan")
    head = ("<tr><th class='l'>segment</th><th class='l'>rotor</th><th>duration [ms]</th><th>samples</th>"
            "<th class='l'>v_d [V]</th><th class='l'>v_q [V]</th>{extra}</tr>")
    if plan:
        rate = float(plan["sample_rate"])
        rows = "".join(
            f'<tr><td class="l">{_e(s["name"])}</td><td class="l">{"locked" if s["locked"] else "free"}</td>'
            f'<td>{1e3 * s["duration"]:.4g}</td><td>{round(s["duration"] * rate)}</td>'
            f'<td class="l">{_e(_volts(s["v_d"]))}</td><td class="l">{_e(_volts(s["v_q"]))}</td></tr>'
            for s in plan["segments"])
        limits = (f"sample rate {quantity(rate, 'Hz')}, DC link {quantity(plan['v_dc'], 'V')}, current limit "
                  f"{quantity(plan['current_limit'], 'A')}")
        for key, unit, what in (("max_speed", "rad/s", "speed limit"), ("max_torque", "N*m", "clamp torque limit"),
                                ("current_noise", "A", "designed for a sensor noise of")):
            if isinstance(plan.get(key), (int, float)):
                limits += f", {what} {quantity(plan[key], unit)}"
        return (f"<p>The plan as recorded: {_e(limits)}.</p>"
                f"<table class='plan'>{head.format(extra='')}{rows}</table>")
    segments = fit.get("segments") or []
    if not segments:
        return "<p>No plan recorded, and the result holds no segments.</p>"
    rows = []
    for s in segments:
        t = np.asarray(s["t"], dtype=float)
        step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
        peak = float(np.max(np.hypot(np.asarray(s["i_d"], dtype=float), np.asarray(s["i_q"], dtype=float))))
        rows.append(f'<tr><td class="l">{_e(s["name"])}</td><td class="l">{"locked" if s["locked"] else "free"}</td>'
                    f'<td>{1e3 * (t[-1] - t[0] + step):.4g}</td><td>{t.size}</td>'
                    f'<td class="l">{_span(np.asarray(s["v_d"]))}</td><td class="l">{_span(np.asarray(s["v_q"]))}</td>'
                    f"<td>{peak:.4g}</td></tr>")
    return ("<p>No plan file was given: the segments as the bench file recorded them.</p>"
            f"<table class='plan'>{head.format(extra='<th>peak |i| [A]</th>')}{''.join(rows)}</table>")


# --- the checks -----------------------------------------------------------------------------------

def _checks(fit: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """(check, done/skipped/failed, outcome or reason) of every check, in the order drivecal makes them."""
    out = []
    ident = fit.get("identifiability") or {}
    if ident:
        weak = [n for n in ident.get("names", ()) if n not in ident.get("fit_names", ident.get("names", ()))]
        text = (f"rank {ident['rank']}/{ident['num_params']}, condition number {ident['condition_number']:.3g}: "
                + ("every parameter is determined by the test" if ident.get("identifiable") else
                   "not every parameter is determined by the test"))
        if weak:
            text += f"; held at the prior: {', '.join(weak)}"
        out.append(("identifiability (before fitting)", DONE if ident.get("identifiable") else FAILED, text))
    out.append(("convergence of the fit", DONE if fit.get("converged") else FAILED,
                f"{fit.get('message', '')} after {fit.get('iterations', '?')} Levenberg-Marquardt steps"))
    res = fit.get("residuals") or {}
    if not res:
        out.append(("noise level of the residuals", SKIPPED, "the result holds no residuals"))
        out.append(("no pattern left in the residuals", SKIPPED, "the result holds no residuals"))
    else:
        if res.get("sigma_stated") is None:
            out.append(("noise level of the residuals", SKIPPED,
                        res.get("noise_check_off") or "no sensor noise was stated or could be estimated"))
        else:
            ok = res.get("noise_consistent")
            out.append(("noise level of the residuals", DONE if ok else FAILED,
                        f"the residuals' level {quantity(res['sigma_hat'], 'A')} is {res['sigma_ratio']:.3g} times "
                        f"the sensor noise {noise_row(fit)} (at most {res['sigma_ratio_max']:g} allowed)"))
        white = res.get("white")
        out.append(("no pattern left in the residuals", DONE if white else FAILED,
                    "none: they look like sensor noise (Ljung-Box test of each segment and axis)" if white else
                    "a pattern remains: the model misses something (see the verdict)"))
    for e in (fit.get("effects") or {}).get("effects", ()):
        name = f"bench effect: {e['effect'].replace('_', ' ')}"
        if e.get("p_value") is None and not e.get("included"):
            out.append((name, SKIPPED, e.get("note") or e.get("how", "not tested")))
        else:
            p = ""
            if e.get("p_value") is not None:
                p = f" (p = {e['p_value']:.2g}" + (f"; fitted where p < {e['p_threshold']:.2g})"
                                                   if e.get("p_threshold") is not None else ")")
            out.append((name, DONE, (e.get("note") or f"{'fitted' if e.get('included') else 'not fitted'}: "
                                                     f"{e.get('how', '')}") + p))
    speed = fit.get("speed") or {}
    if speed.get("input_error_ratio") is not None:
        ratio = float(speed["input_error_ratio"])
        out.append(("resolution of the measured speed", DONE,
                    f"as an exact input its errors could add {ratio:.2g} times the current noise's variance "
                    f"(limit {speed['input_error_ratio_max']:g}): "
                    + ("too coarse to be exact" if speed.get("flagged") else "fine enough to be exact")))
    else:
        out.append(("resolution of the measured speed", SKIPPED,
                    "no measured speed in the file" if not speed.get("resolution") else
                    "the currents are too clean to weigh the speed's noise against"))
    spec = fit.get("spec")
    if spec:
        out.append(("specification (the motor file's tolerances)", DONE if spec["status"] == "pass" else FAILED,
                    spec["headline"]))
    else:
        out.append(("specification (the motor file's tolerances)", SKIPPED,
                    "the motor file gives no tolerances ([tolerance] table)"))
    return out


def checks_html(fit: Mapping[str, Any]) -> str:
    """Every check, done or skipped, with its outcome or the reason it was skipped."""
    rows = "".join(f'<tr class="{state}"><td class="l">{_e(name)}</td><td class="l">{state}</td>'
                   f'<td class="l">{_e(text)}</td></tr>' for name, state, text in _checks(fit))
    head = "<tr><th class='l'>check</th><th class='l'>state</th><th class='l'>outcome, or why it was skipped</th></tr>"
    return f'<table class="checks">{head}{rows}</table>'
