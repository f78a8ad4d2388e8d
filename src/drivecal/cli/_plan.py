"""``drivecal plan``: design a feasible, identifiable bench plan for a motor and the bench's real limits."""

from __future__ import annotations

import json
import math
from typing import TYPE_CHECKING

import click

from ._common import _check_out, _console, _load_motor, _motor_option, _predicted_cells, _Positive, _Quantity

if TYPE_CHECKING:
    from rich.console import Console

#: rad/s -> rpm.
RPM = 60.0 / (2.0 * math.pi)


@click.command("plan")
@_motor_option
@click.option("--vdc", type=_Positive(), required=True, help="The bench's DC-link voltage [V]; segments stay inside "
              "the voltage circle v_dc/sqrt(3).")
@click.option("--imax", type=_Positive(), required=True, help="The bench's current limit [A] (peak |i_dq|).")
@click.option("--max-speed", type=_Positive(), default=None,
              help="Highest mechanical speed allowed in the free spin-up [rad/s] (rated speed, say). Default: the "
                   "no-load speed the voltage allows.")
@click.option("--max-torque", type=_Quantity("torque", "N*m", positive=True), default=None, metavar="N*m",
              help="The rotor clamp's torque limit [N*m] (a number, or e.g. \"300 N*m\"): locked steps stay under "
                   "80 % of it. Default: not checked (the predicted clamp torque is shown).")
@click.option("--budget", type=_Positive(), default=None, help="Longest total plan duration [s].")
@click.option("--sample-rate", type=_Positive(), default=None,
              help="The inverter's sample (PWM) rate [Hz]. Default: 10 kHz, a typical inverter's, raised up to "
                   "40 kHz only where the motor's electrical time constant or the spin-up's speed needs it.")
@click.option("--dead-time", "dead_time", type=_Quantity("time", "s"), default=None, metavar="SECONDS",
              help="The inverter's dead time per switching edge [s] (a number, or e.g. \"1 us\"), for the expected "
                   "dead-time voltage v_dc x dead time x sample rate; 0 for an inverter that compensates it. "
                   "Default: 1 us (the motor file's v_dead where it gives one).")
@click.option("--noise", type=_Positive(), default=None,
              help="Expected current-sensor noise standard deviation [A], for the predicted intervals (and "
                   "the length of the mechanical test); the plan file records it as current_noise, which `drivecal "
                   "design` and `simulate` then use. Default: 0.2 % of --imax.")
@click.option("--estimate", "estimate", default=None, metavar="NAMES",
              help="Comma-separated parameters the plan must identify, replacing the motor file's 'estimate' "
                   "(default: R,Ld,Lq,lambda_m); any of J, B, T_coulomb, T_load adds the mechanical test.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan and its assessment as JSON on stdout.")
@click.option("--out", "out_path", required=True, type=click.Path(),
              help="Plan file to write (TOML, the format `drivecal design` and `simulate` read).")
def plan_command(motor_path, vdc, imax, max_speed, max_torque, budget, sample_rate, dead_time, noise, estimate,
                 as_json, out_path):
    """Design a bench plan for the motor: feasible, identifiable, scaled to it and to the bench's limits.

    \b
    From the nominal motor of --motor and the bench's limits:
      - sample rate: --sample-rate, else 10 kHz (a real inverter's PWM
        rate), raised along 16, 20, 25, 32, 40 kHz only where the fastest
        electrical time constant would get < 10 samples or the spin-up
        > 0.1 electrical rad per sample; durations come from time
        constants, so the plan keeps its shape at another rate;
      - locked d-step and q-step: steady current half of --imax (v = i*R,
        inside 90 % of the voltage circle), 6 electrical time constants
        L/R long; the q-step's clamp torque 1.5 p (lambda_m i_q +
        (Ld-Lq) i_d i_q) under 80 % of --max-torque;
      - dead time: a step under 10 x the expected dead-time voltage
        v_dc x --dead-time x sample rate is raised to it where 80 % of
        --imax allows; where not, v_dead must be fitted (the output says
        so): a second d-step at half the current joins, and every step
        adds the dead time's drop to reach its current;
      - free spin-up: a ramp on v_q to 60 % of the speed limit
        (--max-speed, and the no-load speed), as fast as keeps its
        current near a locked step's, peak under 80 % of the limit.
    The table shows per segment the duration, voltages, predicted peak
    current, peak speed (rpm and rad/s) and clamp torque, with the limits.
    With sat_d, sat_q or sat_dq to estimate (magnetic saturation) the
    locked steps show it: on each saturating axis three steps with steady
    currents of 1/3, 2/3 and all of 0.8 x --imax (v = i*R), and for sat_dq
    two combined steps with both axes energised, (+d,+q) and (+d,-q), each
    axis at 0.8/sqrt(2) x --imax; a motor without a magnet (lambda_m = 0, a
    synchronous reluctance motor) gets locked steps only. Peak currents are
    predicted with the motor's saturating law where it has one (sat_d,
    sat_q, sat_dq in the motor file); where it has none, the free segments
    are sized so that a motor whose Ld and Lq fall to 50 % still stays
    under --imax (the margin is printed).
    With J, B, T_coulomb or T_load to estimate (--estimate or the motor
    file's 'estimate') the spin-up is a voltage step that runs on at a
    steady speed and the mechanical test continues it (continue = true): a
    low-speed run at a quarter of the spin-up voltage (and a reversed one
    for T_load), whose steady q currents carry the friction torque at two
    speeds, then a short-circuit braking (0 V), whose deceleration shows
    J; the steady runs are long enough for B and T_coulomb to reach a
    standard error of 10 % at --noise.
    The plan is judged like `drivecal design` (predicted peaks, rank,
    predicted 95 % CI half-widths) and scaled down until it is feasible.
    Exit status 2 when no feasible, identifiable plan exists.
    """
    out = _check_out(out_path, "--out", example="plans/motor.toml")
    from ..design import DEFAULT_DEAD_TIME, auto_design
    from ..plan import plan_to_dict, write_plan
    from ._fit import _estimate_names

    names = _estimate_names(estimate) if estimate is not None else None
    motor_file = _load_motor(motor_path)
    if names is not None:
        motor_file = motor_file.replace(estimate=names)
    dead = DEFAULT_DEAD_TIME if dead_time is None else dead_time
    report = auto_design(motor_file.motor, v_dc=vdc, current_limit=imax, max_speed=max_speed,
                         budget=budget, sample_rate=sample_rate, noise_sigma=noise, names=motor_file.names,
                         max_torque=max_torque, dead_time=dead)
    plan, limits = report.plan, report.limits
    header = (f"drivecal plan: auto-plan for {motor_file.source}\n"
              f"v_dc {vdc:g} V, current limit {imax:g} A, max speed "
              f"{'-' if max_speed is None else f'{max_speed:g} rad/s'}, clamp torque limit "
              f"{'-' if max_torque is None else f'{max_torque:g} N*m'}, budget "
              f"{'-' if budget is None else f'{budget:g} s'}\n"
              f"sample rate {plan.sample_rate:g} Hz ({limits.sample_rate_source}); dead time "
              f"{dead * 1e6:g} us, expected dead-time voltage {limits.v_dead:.3g} V\n"
              f"identifies {', '.join(limits.names)}"
              + ("\nv_dead must be fitted: add it to the motor file's estimate" if limits.v_dead_fitted else ""))
    write_plan(out, plan, report.waveforms, header=header)
    if as_json:
        segments = plan_to_dict(plan)["segments"]
        for entry in segments:  # a waveform the plan was built from, as its table, not its samples
            for axis in ("v_d", "v_q"):
                if (entry["name"], axis) in report.waveforms:
                    entry[axis] = dict(report.waveforms[(entry["name"], axis)])
        click.echo(json.dumps({"plan": str(out), "sample_rate": plan.sample_rate, "num_samples": plan.num_samples,
                               "duration": sum(s.duration for s in plan.segments),
                               "segments": segments, "assessment": report.to_dict()}, indent=2))
    else:
        _print_plan(report, out, _console(False))


def _voltage(seg, axis: str, spec) -> str:
    """A segment's voltage on one axis, as shown: a constant, or its waveform table in words."""
    if spec is not None and spec.get("kind") == "ramp":
        return f"ramp to {spec['level']:.4g} in {spec['rise'] * 1e3:.3g} ms"
    value = getattr(seg, axis)
    try:
        return f"{float(value):.4g}"
    except TypeError:
        return f"{min(value):.3g} to {max(value):.3g}"


def _print_plan(report, out, console: Console) -> None:
    from rich.markup import escape
    from rich.table import Table

    from ..design import CURRENT_MARGIN, DEAD_TIME_MARGIN, SPEED_FRACTION, TORQUE_MARGIN
    from ..physics import UNITS

    plan, ident, limits = report.plan, report.identifiability, report.limits
    duration = sum(s.duration for s in plan.segments)
    console.print(f"[bold]wrote {out}[/bold]: {len(plan.segments)} segments, {duration:.4g} s, {plan.num_samples} "
                  f"samples at {plan.sample_rate:g} Hz; voltage limit {plan.voltage_limit:.4g} V, current limit "
                  f"{plan.current_limit:g} A")
    console.print(f"sample rate {plan.sample_rate / 1e3:g} kHz ({escape(limits.sample_rate_source)}; --sample-rate "
                  "gives the bench's)")
    ratio = limits.dead_time_ratio(plan)
    if limits.v_dead > 0 and math.isfinite(ratio):
        origin = (f"{plan.v_dc:g} V x {limits.dead_time * 1e6:g} µs x {plan.sample_rate / 1e3:g} kHz"
                  if limits.dead_time else "the motor file's v_dead")
        head = (f"dead time: expected dead-time voltage {limits.v_dead:.3g} V ({origin}); the smallest locked step is "
                f"{ratio:.2g} x it")
        if ratio >= DEAD_TIME_MARGIN:
            console.print(f"{head}, above the margin {DEAD_TIME_MARGIN:g} x")
        elif limits.v_dead_fitted:
            console.print(f"{head}, under the margin {DEAD_TIME_MARGIN:g} x: [yellow]v_dead must be fitted[/yellow]: "
                          f"add v_dead to the motor file's estimate, with v_dead = \"{limits.v_dead:.3g} V\" and "
                          f"i_dead = \"{limits.i_dead:.3g} A\" (its transition's width); the plan holds a second "
                          "d-step current and its steps add the dead time's drop")
        else:
            console.print(f"{head}, under the margin {DEAD_TIME_MARGIN:g} x: [yellow]R reads the dead time too[/yellow]"
                          " (this plan does not lay out what tells them apart)")
    else:
        console.print("dead time: none assumed (--dead-time 0: the inverter compensates it)")
    console.print(f"sensor noise {ident.noise_sigma * 1e3:.4g} mA, recorded as the plan's current_noise: `drivecal "
                  "design` and `simulate` use it")
    console.print(_segment_table(report, limits, escape))
    clamp = ("[yellow]not checked[/yellow] (give --max-torque)" if limits.max_torque is None
             else f"{limits.max_torque:.4g} N·m (locked steps under {TORQUE_MARGIN * 100:g} % of it)")
    given = plan.max_speed is not None and plan.max_speed <= limits.speed_limit
    console.print(f"limits: current {plan.current_limit:g} A (peaks under {CURRENT_MARGIN * 100:g} %), speed "
                  f"{limits.speed_limit:.4g} rad/s = {limits.speed_limit * RPM:.4g} rpm "
                  f"({'--max-speed' if given else 'the no-load speed'}; free segments under "
                  f"{SPEED_FRACTION * 100:g} %), clamp torque {clamp}")
    console.print(f"identifiability: {ident.summary(markup=True)}")
    for note in report.notes:
        if note not in limits.dead_time_notes(plan):  # said above
            console.print(f"  note: {escape(note)}")
    table = Table(title=f"predicted 95 % intervals at noise {ident.noise_sigma * 1e3:.4g} mA", title_justify="left")
    for col in ("parameter", "unit", "nominal", "± 95 % CI", "rel. [%]"):
        table.add_column(escape(col), justify="left" if col in ("parameter", "unit") else "right", no_wrap=True)
    for i, n in enumerate(ident.names):
        table.add_row(n, *_predicted_cells(float(getattr(report.motor, n)), float(ident.predicted_ci95[i]), UNITS[n]))
    console.print(table)


def _segment_table(report, limits, escape):
    from rich.table import Table

    plan = report.plan
    table = Table(title="segments: peak current, peak speed and clamp torque predicted on the nominal motor",
                  title_justify="left")
    columns = ("segment", "rotor", "duration [s]", "v_d [V]", "v_q [V]", "|i| [A]", "speed [rpm]", "[rad/s]",
               "clamp [N·m]")
    for col in columns:  # names and waveforms wrap; numbers do not
        wraps = col in ("segment", "rotor") or col.startswith("v_")
        table.add_column(escape(col), justify="left" if col in ("segment", "rotor") else "right", no_wrap=not wraps,
                         min_width=13 if col == "segment" else 6 if wraps else None)
    for seg, pred in zip(plan.segments, report.segments):
        rotor = ("locked" if seg.locked else "free") + (", continues" if seg.continues else "")
        table.add_row(escape(seg.name), rotor, f"{seg.duration:.4g}",
                      *(escape(_voltage(seg, axis, report.waveforms.get((seg.name, axis)))) for axis in ("v_d", "v_q")),
                      f"{pred.peak_current:.3g}",
                      "-" if pred.locked else f"{pred.peak_speed * RPM:.4g}",
                      "-" if pred.locked else f"{pred.peak_speed:.4g}",
                      f"{pred.peak_torque:.3g}" if pred.locked else "-")
    table.add_section()
    table.add_row("limit", "", "", "", "", f"{plan.current_limit:.3g}", f"{limits.speed_limit * RPM:.4g}",
                  f"{limits.speed_limit:.4g}",
                  "-" if limits.max_torque is None else f"{limits.max_torque:.3g}")
    return table
