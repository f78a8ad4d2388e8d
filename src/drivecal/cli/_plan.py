"""``drivecal plan``: design a feasible, identifiable bench plan for a motor."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import click

from ._common import _check_out, _console, _load_motor, _motor_option, _predicted_cells, _Positive

if TYPE_CHECKING:
    from rich.console import Console


@click.command("plan")
@_motor_option
@click.option("--vdc", type=_Positive(), required=True, help="The bench's DC-link voltage [V]; segments stay inside "
              "the voltage circle v_dc/sqrt(3).")
@click.option("--imax", type=_Positive(), required=True, help="The bench's current limit [A] (peak |i_dq|).")
@click.option("--max-speed", type=_Positive(), default=None,
              help="Highest mechanical speed allowed in the free spin-up [rad/s]. Default: the no-load speed "
                   "the voltage allows.")
@click.option("--budget", type=_Positive(), default=None, help="Longest total plan duration [s].")
@click.option("--sample-rate", type=_Positive(), default=None,
              help="The bench's sample rate [Hz]. Default: chosen from the motor's time constants.")
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
def plan_command(motor_path, vdc, imax, max_speed, budget, sample_rate, noise, estimate, as_json, out_path):
    """Design a bench plan for the motor: feasible, identifiable, scaled to it.

    \b
    Three segments, from the nominal motor of --motor and the bench limits:
      - locked d-step and q-step: steady current half of --imax (v = i*R,
        inside the voltage circle), 6 electrical time constants L/R long;
      - free spin-up on v_q: peak speed under 80 % of --max-speed (and of
        the no-load speed), a few mechanical time constants long;
      - sample rate: >= 10 samples per electrical time constant and
        <= 0.1 electrical rad per sample.
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
    file's 'estimate') the spin-up runs on at a steady speed and the
    mechanical test continues it (continue = true): a low-speed run at a
    quarter of the spin-up voltage (and a reversed one for T_load), whose
    steady q currents carry the friction torque at two speeds, then a
    short-circuit braking (0 V), whose deceleration shows J; the steady
    runs are long enough for B and T_coulomb to reach a standard error of
    10 % at --noise.
    The plan is judged like `drivecal design` (predicted peaks, rank,
    predicted 95 % CI half-widths) and scaled down until it is feasible.
    Exit status 2 when no feasible, identifiable plan exists.
    """
    out = _check_out(out_path, "--out", example="plans/motor.toml")
    from ..design import auto_design
    from ..plan import plan_to_dict, write_plan
    from ._fit import _estimate_names

    names = _estimate_names(estimate) if estimate is not None else None
    motor_file = _load_motor(motor_path)
    if names is not None:
        motor_file = motor_file.model_copy(update={"estimate": names})
    report = auto_design(motor_file.motor, v_dc=vdc, current_limit=imax, max_speed=max_speed,
                         budget=budget, sample_rate=sample_rate, noise_sigma=noise, names=motor_file.names)
    plan = report.plan
    header = (f"drivecal plan: auto-plan for {motor_file.source}\n"
              f"v_dc {vdc:g} V, current limit {imax:g} A, max speed "
              f"{'-' if max_speed is None else f'{max_speed:g} rad/s'}, budget "
              f"{'-' if budget is None else f'{budget:g} s'}\n"
              f"identifies {', '.join(motor_file.names)}")
    write_plan(out, plan, header=header)
    if as_json:
        click.echo(json.dumps({"plan": str(out), "sample_rate": plan.sample_rate, "num_samples": plan.num_samples,
                               "duration": sum(s.duration for s in plan.segments),
                               "segments": plan_to_dict(plan)["segments"],
                               "assessment": report.to_dict()}, indent=2))
    else:
        _print_plan(report, out, _console(False))


def _print_plan(report, out, console: Console) -> None:
    from rich.markup import escape
    from rich.table import Table

    from ..physics import UNITS

    plan, ident = report.plan, report.identifiability
    duration = sum(s.duration for s in plan.segments)
    console.print(f"[bold]wrote {out}[/bold]: {len(plan.segments)} segments, {duration:.4g} s, {plan.num_samples} "
                  f"samples at {plan.sample_rate:g} Hz; voltage limit {plan.voltage_limit:.4g} V, current limit "
                  f"{plan.current_limit:g} A")
    console.print(f"sensor noise {ident.noise_sigma * 1e3:.4g} mA, recorded as the plan's current_noise: `drivecal "
                  "design` and `simulate` use it")
    seg_table = Table(title="segments, predicted on the nominal motor", title_justify="left")
    for col in ("segment", "rotor", "duration [s]", "v_d [V]", "v_q [V]", "peak |i_dq| [A]", "peak w_m [rad/s]"):
        seg_table.add_column(escape(col), justify="left" if col in ("segment", "rotor") else "right", no_wrap=True)
    for seg, pred in zip(plan.segments, report.segments):
        rotor = ("locked" if seg.locked else "free") + (", continues" if seg.continues else "")
        seg_table.add_row(seg.name, rotor, f"{seg.duration:.4g}", f"{float(seg.v_d):.4g}",
                          f"{float(seg.v_q):.4g}", f"{pred.peak_current:.3g}",
                          "-" if pred.locked else f"{pred.peak_speed:.4g}")
    console.print(seg_table)
    console.print(f"identifiability: {ident.summary(markup=True)}")
    for note in report.notes:
        console.print(f"  note: {escape(note)}")
    table = Table(title=f"predicted 95 % intervals at noise {ident.noise_sigma * 1e3:.4g} mA", title_justify="left")
    for col in ("parameter", "unit", "nominal", "± 95 % CI", "rel. [%]"):
        table.add_column(escape(col), justify="left" if col in ("parameter", "unit") else "right", no_wrap=True)
    for i, n in enumerate(ident.names):
        table.add_row(n, *_predicted_cells(float(getattr(report.motor, n)), float(ident.predicted_ci95[i]), UNITS[n]))
    console.print(table)
