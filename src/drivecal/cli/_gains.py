"""``drivecal gains``: current-loop PI gains from a saved calibration, with their uncertainty, for firmware."""

from __future__ import annotations

import json
import math
import re
from typing import TYPE_CHECKING

import click

from ._common import _check_out, _console, _Positive

if TYPE_CHECKING:
    from rich.console import Console


class _QFormat(click.ParamType):
    name = "Qn"

    def convert(self, value, param, ctx):
        if isinstance(value, int):
            return value
        match = re.fullmatch(r"[Qq]?(\d{1,2})", str(value).strip())
        if not match:
            self.fail(f"{value!r} is not a Q format; write e.g. Q15", param, ctx)
        return int(match.group(1))


class _OperatingPoint(click.ParamType):
    name = "ID,IQ"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        parts = str(value).split(",")
        try:
            point = tuple(float(p) for p in parts)
        except ValueError:
            point = ()
        if len(point) != 2 or not all(math.isfinite(x) for x in point):
            self.fail(f"{value!r} is not two currents ID,IQ in A, comma-separated; write e.g. -5,20", param, ctx)
        return point


def _plan_number(fit_doc, key: str) -> float | None:
    """A positive number of the result's ``plan`` section (the bench's sample rate, its DC voltage), or None."""
    plan = fit_doc.get("plan")
    value = plan.get(key) if isinstance(plan, dict) else None
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value > 0 and math.isfinite(value):
        return float(value)
    return None


@click.command("gains")
@click.argument("result_json", type=click.Path(dir_okay=False))
@click.option("--bandwidth", type=_Positive(), default=None,
              help="Closed-loop -3 dB current bandwidth [Hz] of the sampled loop with its delay (without "
                   "--sample-rate: of the continuous loop, where it equals the crossover).")
@click.option("--crossover", type=_Positive(), default=None, help="Open-loop crossover frequency [Hz] instead.")
@click.option("--phase-margin", type=_Positive(), default=None,
              help="Phase margin [deg] instead (30 to 90; needs --sample-rate).")
@click.option("--sample-rate", type=_Positive(), default=None,
              help="Controller sample rate [Hz]: design the discrete PI for the sampled loop with its delay. "
                   "Without it the loop is designed and judged in continuous time without delay.")
@click.option("--delay", type=click.FloatRange(min=0), default=None,
              help="Command delay [controller samples] (computation + PWM). Default: the result's fitted delay, "
                   "else 1.")
@click.option("--operating-point", type=_OperatingPoint(), default=None,
              help="Design at the operating point i_d,i_q [A] (e.g. -5,20): the plant's inductances are the "
                   "calibrated flux law's incremental L_dd and L_qq there (equal to Ld, Lq for a linear "
                   "calibration). Default: Ld and Lq at zero current.")
@click.option("--vdc", type=_Positive(), default=None,
              help="DC-link voltage [V] for the voltage limit V_dc/sqrt(3) (default: the result's plan v_dc).")
@click.option("--base-current", type=_Positive(), default=None, help="Per-unit base current [A].")
@click.option("--base-voltage", type=_Positive(), default=None, help="Per-unit base voltage [V].")
@click.option("--base-frequency", type=_Positive(), default=None,
              help="Per-unit base electrical frequency [Hz] for the feed-forward constants.")
@click.option("--q-format", type=_QFormat(), default=None,
              help="Fixed-point format of the per-unit constants, e.g. Q15 (the default with a base).")
@click.option("--header", "header_path", default=None, help="Write the constants as a C header FILE.h.")
@click.option("--out", "out_path", default=None, help="Write the gains JSON to FILE.json.")
@click.option("--design", default=None, help="Which fit of a demo result (default: the first, 'default').")
@click.option("--samples", type=click.IntRange(min=100), default=4000, show_default=True,
              help="Monte Carlo draws from the parameter covariance.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Monte Carlo seed.")
@click.option("--json", "as_json", is_flag=True, help="Print the gains JSON on stdout instead of tables.")
def gains(result_json, bandwidth, crossover, phase_margin, sample_rate, delay, operating_point, vdc, base_current,
          base_voltage, base_frequency, q_format, header_path, out_path, design, samples, seed, as_json):
    """Current-loop PI gains per axis from a saved calibration, with their uncertainty.

    \b
    Exactly one specification: --bandwidth (closed-loop -3 dB), --crossover or
    --phase-margin, met by the discrete PI on the sampled loop with its command
    delay (--sample-rate). Gains by discrete pole-zero cancellation per axis
    (L = Ld for d, Lq for q; with --operating-point the incremental L_dd and
    L_qq at those currents, with a warning where they lie beyond the
    calibration's data); their uncertainty is propagated from the
    parameter covariance to first order and by Monte Carlo, and the achieved
    crossover, bandwidth and phase margin are reported over true motors drawn
    from the confidence region. With --sample-rate also the firmware
    constants: decoupling feed-forward, the voltage limit V_dc/sqrt(3),
    per-unit and Q-format values (--base-current, --base-voltage), as a C
    header (--header) and JSON (--out, --json). Nothing is written when the
    input is refused.
    """
    from ..errors import DrivecalError

    for path, option, example in ((header_path, "--header", "gains.h"), (out_path, "--out", "gains.json")):
        if path is not None:
            _check_out(path, option, example=example)
    firmware_options = {"--header": header_path, "--vdc": vdc, "--base-current": base_current,
                        "--base-voltage": base_voltage, "--base-frequency": base_frequency, "--q-format": q_format,
                        "--delay": delay}
    if sample_rate is None and any(v is not None for v in firmware_options.values()):
        first = next(k for k, v in firmware_options.items() if v is not None)
        raise DrivecalError(f"{first} needs --sample-rate: it is about the sampled controller.")
    if header_path is not None and out_path is not None and header_path == out_path:
        raise DrivecalError(f"--header and --out are the same file {header_path}; give two paths.")

    from .._io import atomic_path, write_json
    from ..fitting import Calibration
    from ..report import c_header, design_current_loop, firmware_gains
    from ..results import load_result, select_fit

    doc = load_result(result_json)
    label, fit_doc = select_fit(doc, design, source=str(result_json))
    source = str(result_json) if label == "fit" else f"{result_json} (design {label})"
    cal = Calibration.from_dict(fit_doc, source)
    result = design_current_loop(cal, bandwidth, crossover_hz=crossover, phase_margin_deg=phase_margin,
                                 sample_rate_hz=sample_rate, delay_samples=delay,
                                 delay_sample_rate_hz=_plan_number(fit_doc, "sample_rate"), num_samples=samples,
                                 seed=seed, source=source, operating_point=operating_point)
    fw = None
    if sample_rate is not None:
        v_dc, v_dc_source = vdc, "--vdc"
        if v_dc is None and _plan_number(fit_doc, "v_dc") is not None:
            v_dc, v_dc_source = _plan_number(fit_doc, "v_dc"), "the result's plan v_dc"
        fw = firmware_gains(result, cal, v_dc=v_dc, v_dc_source=v_dc_source, base_current=base_current,
                            base_voltage=base_voltage, base_frequency_hz=base_frequency, q_bits=q_format)
    payload = {"result": str(result_json), "design": label, **result.to_dict(),
               "firmware": None if fw is None else fw.to_dict()}
    header = None if header_path is None else c_header(fw, source=source)
    if out_path is not None:
        write_json(out_path, payload)
    if header is not None:
        with atomic_path(header_path) as tmp:
            tmp.write_text(header)
    if as_json:
        click.echo(json.dumps(payload, indent=2))
        return
    console = _console(False)
    _print_gains(result, console, f"{result_json} ({label})")
    if fw is not None:
        _print_firmware(fw, console)
    for path in (out_path, header_path):
        if path is not None:
            console.print(f"wrote {path}", markup=False, highlight=False)


def _print_gains(result, console: Console, source: str) -> None:
    from rich.markup import escape
    from rich.table import Table

    from .._units import format_quantity, format_value
    from ..report import AXES

    spec_unit = "deg" if result.spec_kind == "phase_margin" else "Hz"
    console.print(escape(f"current-loop PI gains for {source}: {result.spec_kind.replace('_', ' ')} "
                         f"{result.spec_value:g} {spec_unit}; {result.discretisation}; delay: {result.delay_source}"))
    if result.limits is not None:
        lim = result.limits
        console.print(escape(f"reachable at {result.sample_rate_hz:g} Hz with this delay and at least "
                             f"{lim['min_phase_margin_deg']:g} deg of margin: crossover up to "
                             f"{lim['max_crossover_hz']:.5g} Hz, -3 dB bandwidth up to {lim['max_bandwidth_hz']:.5g} "
                             f"Hz, phase margin {lim['min_phase_margin_deg']:g} to {lim['max_phase_margin_deg']:g} "
                             "deg"))
    rule = ("Kp = L*w_c, Ki = R*w_c" if result.sample_rate_hz is None
            else "Kp = g*R/(1 - exp(-R*Ts/L)), Ki = g*R/Ts")
    if result.operating_point is None:
        plant = "L = Ld (d), Lq (q) [H], at zero current"
    else:
        i_d, i_q = result.operating_point
        plant = (f"L = incremental L_dd (d), L_qq (q) [H] at the operating point i_d = {i_d:g} A, i_q = {i_q:g} A"
                 + (" (beyond the calibration's data)" if result.extrapolated else ""))
        console.print(escape(f"plant inductances at i_d = {i_d:g} A, i_q = {i_q:g} A: " + ", ".join(
            f"{ax.inductance_name} = {format_quantity(ax.inductance, 'H')} ({dict(AXES)[ax.axis]} = "
            f"{format_quantity(ax.inductance_at_zero_current, 'H')} at 0 A)" for ax in result.axes)))
    table = Table(title=escape(f"gains by pole-zero cancellation: {rule}; {plant}"), title_justify="left")
    for col in ("axis", "gain [unit]", "value", "SE first-order", "SD Monte Carlo", "MC / first-order [-]",
                "from"):
        table.add_column(escape(col), justify="left" if col in ("axis", "gain [unit]", "from") else "right",
                         no_wrap=True)
    for ax in result.axes:
        rows = [("Kp [V/A]", ax.kp, ax.kp_se, ax.kp_sd_mc,
                 f"{ax.inductance_name} = {format_quantity(ax.inductance, 'H')}"),
                ("Ki [V/(A*s)]", ax.ki, ax.ki_se, ax.ki_sd_mc, f"R = {format_quantity(ax.resistance, 'ohm')}")]
        if ax.ki_ts is not None:
            ts = 1.0 / result.sample_rate_hz
            rows.append(("Ki*Ts [V/A]", ax.ki_ts, ax.ki_se * ts, ax.ki_sd_mc * ts, "discrete integrator step"))
        for name, value, se, sd, origin in rows:
            ratio = sd / se if math.isfinite(se) and se > 0 else math.nan
            label = ax.axis if ax.calibrated else f"{ax.axis} (not calibrated)"
            # the gain to its SE's second significant digit, SE and SD to two significant digits
            table.add_row(label, name, format_value(value, 1.0, se), format_value(se, 1.0, se),
                          format_value(sd, 1.0, sd), "-" if not math.isfinite(ratio) else f"{ratio:.3f}", origin)
    console.print(table)
    loop = Table(title=f"closed loop of these gains on true motors drawn from the covariance ({result.num_samples} "
                       "draws): at the estimate, MC mean [2.5 %, 97.5 %]", title_justify="left")
    for col in ("axis", "crossover [Hz]", "-3 dB bandwidth [Hz]", "bandwidth MC [Hz]", "phase margin [deg]",
                "phase margin MC [deg]"):
        # escape: rich would read a lower-case "[deg]" as a style tag
        loop.add_column(escape(col), justify="left" if col == "axis" else "right", no_wrap=True)
    for ax in result.axes:
        bw, pm = ax.bandwidth, ax.phase_margin
        loop.add_row(ax.axis, f"{ax.crossover.nominal:.5g}", f"{bw.nominal:.5g}",
                     f"{bw.mean:.5g} [{bw.p025:.5g}, {bw.p975:.5g}]", f"{pm.nominal:.4g}",
                     f"{pm.mean:.4g} [{pm.p025:.4g}, {pm.p975:.4g}]")
    console.print(loop)
    for w in result.warnings:
        console.print(f"[yellow]warning[/yellow]: {escape(w)}")


def _print_firmware(fw, console: Console) -> None:
    from rich.markup import escape
    from rich.table import Table

    from .._units import display_unit, format_value

    base = ("no per-unit base (give --base-current and --base-voltage)" if fw.base_current is None else
            f"per unit: {fw.base_current:g} A, {fw.base_voltage:g} V"
            + ("" if fw.base_frequency_hz is None else f", {fw.base_frequency_hz:g} Hz electrical")
            + f"; fixed point Q{fw.q_bits}: pu ~= Q / 2^shift")
    table = Table(title=escape(f"firmware constants; feed-forward v_d += -w_e*Lq*i_q, v_q += w_e*(Ld*i_d + "
                               f"lambda_m); V_dc {'-' if fw.v_dc is None else f'{fw.v_dc:g} V'} "
                               f"({fw.v_dc_source}); {base}"), title_justify="left")
    for col in ("name", "value", "unit", "SE", "pu", "Q", "shift"):
        table.add_column(col, justify="left" if col in ("name", "unit") else "right", no_wrap=True)
    for c in fw.constants:
        q, shift = c.fixed if c.fixed is not None else ("-", "-")
        se = c.se if math.isfinite(c.se) and c.se > 0 else None
        scale, unit = display_unit(max(abs(c.value), se or 0.0), c.unit)  # each row in its engineering unit
        table.add_row(c.name, format_value(c.value, scale, se), unit or "-",
                      "-" if se is None else format_value(se, scale, se), "-" if c.pu is None else f"{c.pu:.6g}",
                      str(q), str(shift))
    console.print(table)
