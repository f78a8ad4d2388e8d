"""``drivecal gains``: current-loop PI gains from a saved calibration, with their uncertainty."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import click

from ._common import _console, _fmt, _Positive

if TYPE_CHECKING:
    from rich.console import Console


@click.command("gains")
@click.argument("result_json", type=click.Path(dir_okay=False))
@click.option("--bandwidth", type=_Positive(), required=True,
              help="Requested closed-loop current bandwidth [Hz] (the crossover w_c = 2*pi*bandwidth).")
@click.option("--sample-rate", type=_Positive(), default=None,
              help="Controller sample rate [Hz]: also give the discrete-time gains and judge the loop with "
                   "its one-sample computation delay. Without it the loop is judged in continuous time.")
@click.option("--design", default=None, help="Which fit of a demo result (default: the first, 'default').")
@click.option("--samples", type=click.IntRange(min=100), default=4000, show_default=True,
              help="Monte Carlo draws from the parameter covariance.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Monte Carlo seed.")
@click.option("--json", "as_json", is_flag=True, help="Print the gains JSON on stdout instead of tables.")
def gains(result_json, bandwidth, sample_rate, design, samples, seed, as_json):
    """Current-loop PI gains per axis from a saved calibration, with their uncertainty.

    \b
    Pole-zero cancellation per axis: Kp = L*w_c [V/A], Ki = R*w_c [V/(A*s)],
    w_c = 2*pi*bandwidth (L = Ld for d, Lq for q). The uncertainty of Kp and Ki
    is propagated from the parameter covariance to first order and by Monte
    Carlo; the achieved closed-loop bandwidth and phase margin are reported
    over true motors drawn from the confidence region.
    """
    from ..fitting import Calibration
    from ..report import design_current_loop
    from ..results import load_result, select_fit

    doc = load_result(result_json)
    label, fit_doc = select_fit(doc, design, source=str(result_json))
    source = str(result_json) if label == "fit" else f"{result_json} (design {label})"
    cal = Calibration.from_dict(fit_doc, source)
    result = design_current_loop(cal, bandwidth, sample_rate_hz=sample_rate, num_samples=samples, seed=seed,
                                 source=source)
    if as_json:
        click.echo(json.dumps({"result": str(result_json), "design": label, **result.to_dict()}, indent=2))
        return
    console = _console(False)
    _print_gains(result, console, f"{result_json} ({label})")


def _print_gains(result, console: Console, source: str) -> None:
    from rich.markup import escape
    from rich.table import Table

    console.print(escape(f"current-loop PI gains for {source}: bandwidth {result.bandwidth_hz:g} Hz "
                         f"(w_c = {result.omega_c:.6g} rad/s); {result.discretisation}"))
    table = Table(title="gains by pole-zero cancellation: Kp = L*w_c, Ki = R*w_c", title_justify="left")
    for col in ("axis", "gain [unit]", "value", "SE first-order", "SD Monte Carlo", "MC / first-order [-]",
                "from"):
        table.add_column(col, justify="left" if col in ("axis", "gain [unit]", "from") else "right", no_wrap=True)
    for ax in result.axes:
        rows = [("Kp [V/A]", ax.kp, ax.kp_se, ax.kp_sd_mc, f"{ax.inductance_name} = {_fmt(ax.inductance)} H"),
                ("Ki [V/(A*s)]", ax.ki, ax.ki_se, ax.ki_sd_mc, f"R = {_fmt(ax.resistance)} ohm")]
        if ax.ki_ts is not None:
            ts = 1.0 / result.sample_rate_hz
            rows.append(("Ki*Ts [V/A]", ax.ki_ts, ax.ki_se * ts, ax.ki_sd_mc * ts, "discrete integrator step"))
        for name, value, se, sd, origin in rows:
            ratio = sd / se if math.isfinite(se) and se > 0 else math.nan
            label = ax.axis if ax.calibrated else f"{ax.axis} (not calibrated)"
            table.add_row(label, name, _fmt(value), _fmt(se), _fmt(sd), "-" if not math.isfinite(ratio)
                          else f"{ratio:.3f}", origin)
    console.print(table)
    loop = Table(title=f"closed loop of these gains on true motors drawn from the covariance ({result.num_samples} "
                       "draws): at the estimate, MC mean [2.5 %, 97.5 %]", title_justify="left")
    for col in ("axis", "-3 dB bandwidth [Hz]", "bandwidth MC [Hz]", "phase margin [deg]", "phase margin MC [deg]"):
        # escape: rich would read a lower-case "[deg]" as a style tag
        loop.add_column(escape(col), justify="left" if col == "axis" else "right", no_wrap=True)
    for ax in result.axes:
        bw, pm = ax.bandwidth, ax.phase_margin
        loop.add_row(ax.axis, f"{bw.nominal:.6g}", f"{bw.mean:.6g} [{bw.p025:.6g}, {bw.p975:.6g}]",
                     f"{pm.nominal:.4g}", f"{pm.mean:.4g} [{pm.p025:.4g}, {pm.p975:.4g}]")
    console.print(loop)
    for w in result.warnings:
        console.print(f"[yellow]warning[/yellow]: {escape(w)}")
