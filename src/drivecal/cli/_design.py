"""``drivecal design``: judge a plan before bench time; ``--optimize`` improves it (D-optimal)."""

from __future__ import annotations

import dataclasses
import json
from typing import TYPE_CHECKING

import click

from ..errors import PlanError
from ._common import _check_out, _console, _load_motor, _motor_option, _plan_noise, _predicted_cells, _Positive

if TYPE_CHECKING:
    from rich.console import Console


@click.command("design")
@click.argument("plan_path", metavar="PLAN.toml", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--noise", type=_Positive(), default=None,
              help="Expected current-sensor noise standard deviation [A], for the predicted intervals. Default: "
                   "the plan's current_noise (the noise it was designed for), else 0.02.")
@click.option("--json", "as_json", is_flag=True, help="Print the assessment JSON on stdout instead of tables.")
@click.option("--optimize", is_flag=True,
              help="Improve the plan's amplitudes, durations and bands for the smallest predicted confidence "
                   "volume (D-optimal) within the margins `drivecal plan` keeps (90 % of the voltage circle, 80 % "
                   "of the current limit, of the speed limit and of max_torque; segments of 200 samples and "
                   "locked ones of 3 L/R at least) and the time budget; needs --out.")
@click.option("--budget", type=_Positive(), default=None,
              help="With --optimize: total duration of the improved plan [s] (default: the plan's own, "
                   "lengthened where its segments are shorter than the margins' least durations).")
@click.option("--out", "out_path", type=click.Path(), default=None,
              help="With --optimize: the improved plan file to write (TOML).")
def design(plan_path, motor_path, noise, as_json, optimize, budget, out_path):
    """Judge PLAN.toml before bench time: feasibility, identifiability, predicted intervals.

    \b
    On the nominal motor of --motor it checks
      - the voltage circle |v_dq| <= v_dc/sqrt(3) of every sample,
      - the predicted peak current against the plan's current_limit,
      - that a free spin-up stays stable and under max_speed, and that an
        inverter-off coast-down's back-EMF stays inside v_dc/sqrt(3),
    then the rank and condition number of the sensitivity Jacobian, dead and
    weak parameters (with the reason), and the 95 % CI half-width each
    parameter would get at the sensor noise: --noise, else the plan's
    current_noise (the noise it was designed for), else 20 mA; the output
    says which. Exit status 2 when the plan is infeasible or cannot identify
    every parameter.

    A motor file with a saturating magnetic law (sat_d, sat_q, sat_dq) has
    its peak currents predicted with that law.

    With --optimize --out OPT.toml the plan is improved first (D-optimal: the
    smallest predicted confidence volume, same segments, within the margins of
    `drivecal plan` and --budget) and written to OPT.toml, with the noise it
    was judged at as its current_noise; the predicted intervals before and
    after and the volume ratio are printed. A multisine, chirp or PRBS whose
    amplitude the optimum removes is written as the constant it is (its
    segment named "step" instead). An input that breaks the margins is not
    written back: the best plan that holds them is, even at a larger volume. Saturation coefficients to
    estimate that the plan cannot show (one current level on an axis, no d
    and q current together) first get the locked steps `drivecal plan` lays
    out for them, before the first free segment.
    """
    if optimize:
        _design_optimize(plan_path, motor_path, noise, as_json, budget, out_path)
        return
    if budget is not None or out_path is not None:
        raise click.UsageError("--budget and --out go with --optimize")

    from ..design import assess_design
    from ..identify import check_requested
    from ..model import Experiment
    from ..plan import load_plan

    plan = load_plan(plan_path)
    noise, noise_source = _plan_noise(plan, noise)
    motor_file = _load_motor(motor_path)
    if motor_file.estimate is not None:
        check_requested(motor_file.names, Experiment.from_plan(plan), plan_path)
    report = assess_design(plan, motor_file.motor, noise_sigma=noise, names=motor_file.names,
                           delay_samples=motor_file.delay_samples)
    if as_json:
        click.echo(json.dumps({**report.to_dict(), "noise_source": noise_source}, indent=2))
    else:
        _print_design(report, plan_path, _console(False), noise_source)
    if not report.ok:
        what = []
        if report.problems:
            what.append(f"{len(report.problems)} feasibility problem(s)")
        ident = report.identifiability
        dead = ident.dead_params + ident.confounded_params
        if dead:
            what.append("cannot identify " + ", ".join(dead))
        elif ident.weak_params:
            what.append("identifies " + ", ".join(ident.weak_params) + " only weakly")
        elif not ident.identifiable:
            what.append("is ill-conditioned")
        raise PlanError(f"{plan_path}: the plan {' and '.join(what)}; see the assessment above.")


def _design_optimize(plan_path, motor_path, noise, as_json, budget, out_path) -> None:
    if out_path is None:
        raise click.UsageError("--optimize needs --out OPT.toml, the improved plan file to write")
    out = _check_out(out_path, "--out", example="out/optimal_plan.toml")
    from ..design import load_plan_waveforms, optimize_plan, with_saturation_steps
    from ..identify import check_requested
    from ..model import Experiment
    from ..plan import write_plan

    plan, specs = load_plan_waveforms(plan_path)
    noise, noise_source = _plan_noise(plan, noise)
    motor_file = _load_motor(motor_path)
    if motor_file.estimate is not None:
        check_requested(motor_file.names, Experiment.from_plan(plan), plan_path)
    plan, added = with_saturation_steps(plan, motor_file.motor, motor_file.names)
    for seg in plan.segments:
        if seg.name in added:
            specs.update({(seg.name, "v_d"): float(seg.v_d), (seg.name, "v_q"): float(seg.v_q)})
    console = _console(as_json)
    if added:
        console.print(f"added {len(added)} locked step(s) that show the magnetic saturation: {', '.join(added)}")
    with console.status("optimizing the plan (D-optimal: BFGS through the sensitivity Jacobian)..."):
        result = optimize_plan(plan, motor_file.motor, waveforms_spec=specs, budget=budget,
                               noise_sigma=noise, names=motor_file.names)
    header = (f"D-optimal plan written by `drivecal design --optimize` from {plan_path}\n"
              f"budget {result.budget:g} s; predicted confidence volume x{result.volume_ratio:.3g} "
              f"(det of the covariance x{result.det_ratio:.3g}) on the nominal motor, noise {noise:g} A")
    tables = {key: spec for key, spec in result.waveforms_after.items() if isinstance(spec, dict)}
    # The improved plan records the noise it was optimised and judged at.
    write_plan(out, dataclasses.replace(result.plan_after, current_noise=noise), tables, header=header)
    if as_json:
        click.echo(json.dumps({"plan": str(plan_path), "out": str(out), "added_segments": list(added),
                               **result.to_dict(), "noise_source": noise_source}, indent=2))
        return
    _print_optimal(result, plan_path, out, console, noise_source)


def _print_optimal(result, plan_path, out, console: Console, noise_source: str) -> None:
    from rich.markup import escape
    from rich.table import Table

    from .._units import display_unit, format_value
    from ..physics import UNITS

    before, after = result.plan_before, result.plan_after
    console.print(f"[bold]{plan_path}[/bold]: D-optimal improvement on the nominal motor, budget "
                  f"{result.budget:g} s, {result.iterations} BFGS steps ({escape(result.message)})")
    seg_table = Table(title="segments before -> after", title_justify="left")
    for col in ("segment", "rotor", "duration [ms]", "v_d [V]", "v_q [V]", "peak |i_dq| [A]", "peak w_m [rad/s]"):
        seg_table.add_column(escape(col), justify="left" if col in ("segment", "rotor") else "right",
                             no_wrap=not col.startswith("v_"))  # waveform texts may wrap

    def level(spec):
        if not isinstance(spec, dict):
            return f"{float(spec):.3g}"
        if spec["kind"] in ("step", "ramp"):
            return f"{spec['kind']} {spec['level']:.3g}"
        if spec["kind"] == "samples":
            return "samples"
        return f"{spec['kind']} {spec['offset']:+.3g}±{spec['amplitude']:.2g}"  # bands: in the written file

    for sb, sa, pb, pa in zip(before.segments, after.segments, result.report_before.segments,
                              result.report_after.segments):
        row = [sa.name, "locked" if sa.locked else "free", f"{sb.duration * 1e3:.4g} -> {sa.duration * 1e3:.4g}"]
        for axis in ("v_d", "v_q"):
            row.append(escape(f"{level(result.waveforms_before[(sb.name, axis)])} -> "
                              f"{level(result.waveforms_after[(sa.name, axis)])}"))
        row.append(f"{pb.peak_current:.3g} -> {pa.peak_current:.3g}")
        row.append("-" if sa.locked else f"{pb.peak_speed:.4g} -> {pa.peak_speed:.4g}")
        seg_table.add_row(*row)
    console.print(seg_table)
    console.print(f"sensor noise {result.noise_sigma * 1e3:.4g} mA ({noise_source}); {out} records it as current_noise")
    table = Table(title=f"predicted 95 % CI half-widths at noise {result.noise_sigma * 1e3:g} mA",
                  title_justify="left")
    table.add_column("plan", justify="left", no_wrap=True)
    # one engineering unit per column (the nominal value's prefix), two significant digits per half-width
    scales = [display_unit(float(getattr(result.report_before.motor, n)) or float(result.ci95_before[i]), UNITS[n])
              for i, n in enumerate(result.names)]
    for n, (_, unit) in zip(result.names, scales):
        table.add_column(escape(f"{n} [{unit or '-'}]"), justify="right", no_wrap=True)
    table.add_column("log det Cov", justify="right", no_wrap=True)
    for label, halves, logdet in (("before", result.ci95_before, result.logdet_before),
                                  ("after", result.ci95_after, result.logdet_after)):
        table.add_row(label, *(f"±{format_value(x, scale, x)}" for x, (scale, _) in zip(halves, scales)),
                      f"{logdet:.2f}")
    table.add_row("after / before", *(f"{a / b:.3f}" for a, b in zip(result.ci95_after, result.ci95_before)),
                  f"{result.logdet_after - result.logdet_before:+.2f}")
    console.print(table)
    console.print(f"confidence volume ratio (after / before) {result.volume_ratio:.3g}; det(Cov) ratio "
                  f"{result.det_ratio:.3g}; improved plan feasible, identifiability "
                  f"{result.report_after.identifiability.summary()}")
    if result.plan_after is result.plan_before:
        console.print("[yellow]no better feasible plan was found: the input plan is written unchanged[/yellow]")
    elif not result.improved:
        console.print("[yellow]the input plan breaks the margins of `drivecal plan`: the written plan holds them, at "
                      "a larger predicted confidence volume[/yellow]")
    console.print(f"wrote {out}")


def _print_design(report, plan_path, console: Console, noise_source: str) -> None:
    from rich.markup import escape
    from rich.table import Table

    from ..physics import UNITS

    plan, ident = report.plan, report.identifiability
    console.print(f"[bold]{plan_path}[/bold]: {len(plan.segments)} segment(s), {plan.num_samples} samples at "
                  f"{plan.sample_rate:g} Hz; voltage limit {plan.voltage_limit:.2f} V, current limit "
                  f"{plan.current_limit:g} A")
    seg_table = Table(title="feasibility on the nominal motor", title_justify="left")
    for col in ("segment", "rotor", "peak |i_dq| [A]", "at t [s]", "peak w_m [rad/s]"):
        seg_table.add_column(escape(col), justify="left" if col in ("segment", "rotor") else "right", no_wrap=True)
    for s in report.segments:
        seg_table.add_row(s.name, "locked" if s.locked else "free", f"{s.peak_current:.3g}",
                          f"{s.peak_current_time:.4g}", "-" if s.locked else f"{s.peak_speed:.4g}")
    console.print(seg_table)
    for p in report.problems:
        console.print(f"  [red]problem[/red]: {p}")
    console.print(f"identifiability: {ident.summary(markup=True)}")
    console.print(f"sensor noise {ident.noise_sigma * 1e3:.4g} mA ({noise_source})")
    table = Table(title=f"predicted 95 % intervals at noise {ident.noise_sigma * 1e3:g} mA", title_justify="left")
    for col in ("parameter", "unit", "nominal", "± 95 % CI", "rel. [%]", "identifiable"):
        justify = "left" if col in ("parameter", "unit", "identifiable") else "right"
        table.add_column(escape(col), justify=justify, no_wrap=True)
    for i, n in enumerate(ident.names):
        unit, nominal, half, relative = _predicted_cells(float(getattr(report.motor, n)),
                                                         float(ident.predicted_ci95[i]), UNITS[n])
        if n not in ident.fit_names:
            table.add_row(n, unit, nominal, "-", "-", "[red]no[/red]")
        elif n in ident.weak_params:
            table.add_row(n, unit, nominal, half, relative, "[yellow]weak[/yellow]")
        else:
            table.add_row(n, unit, nominal, half, relative, "yes")
    console.print(table)
    for n in ident.names:
        if n in ident.reasons:
            colour = "yellow" if n in ident.fit_names else "red"
            console.print(f"  [{colour}]{n}[/{colour}]: {escape(ident.reasons[n])}")
    for note in report.notes:
        console.print(f"  note: {escape(note)}")
