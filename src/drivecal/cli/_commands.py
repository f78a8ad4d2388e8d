"""The ``drivecal`` command.

Bad input never shows a traceback: it is one sentence on stderr and exit status 2.
"""

from __future__ import annotations

import json
import math
import sys

import click
from rich.console import Console
from rich.markup import escape
from rich.table import Table

import drivecal

EXIT_BAD_INPUT = 2


class _Positive(click.ParamType):
    name = "number > 0"

    def convert(self, value, param, ctx):
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not (x > 0 and math.isfinite(x)):
            self.fail(f"{value!r} must be a positive, finite number", param, ctx)
        return x


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(drivecal.__version__, prog_name="drivecal")
def cli():
    """drivecal: calibrate a PMSM's R, Ld, Lq and lambda_m from bench data.

    It checks that the bench experiment can identify each parameter before
    fitting, fits by Levenberg-Marquardt on the measured currents, and reports
    every estimate with a 95 % confidence interval. SI units throughout.

    Start with `drivecal demo`: a full calibration on the built-in synthetic
    bench (the Jaxonomy engine playing the motor).
    """


def _fmt(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.6g}"


def _design_table(run: drivecal.DesignRun, truth: drivecal.MotorParams) -> Table:
    cal = run.calibration
    errors = run.errors(truth)
    table = Table(title=f"{run.label}: {cal.message}, {int(cal.iterations)} LM steps, "
                        f"sigma_hat {float(cal.sigma_hat) * 1e3:.2f} mA", title_justify="left")
    for col in ("parameter", "unit", "true", "initial", "estimate", "error [%]", "error [SE]", "95 % CI"):
        # one row per parameter: never wrap a number
        justify = "left" if col in ("parameter", "unit", "95 % CI") else "right"
        table.add_column(escape(col), justify=justify, no_wrap=True)
    for i, n in enumerate(cal.names):
        e = errors[n]
        if cal.identifiable[i]:
            ci = f"[{_fmt(cal.ci95[i, 0])}, {_fmt(cal.ci95[i, 1])}]"
            est, err_se = _fmt(cal.estimate[i]), f"{e['error_in_se']:+.2f}"
        else:
            ci = "[red]not identifiable[/red]"
            est, err_se = f"[dim]{_fmt(cal.estimate[i])} (prior)[/dim]", "-"
        table.add_row(n, drivecal.UNITS[n], _fmt(e["true"]), _fmt(cal.initial[i]), est,
                      f"{e['error_percent']:+.4f}", err_se, ci)
    return table


def _identifiability_lines(run: drivecal.DesignRun) -> str:
    ident = run.calibration.identifiability
    verdict = "[green]identifiable[/green]" if ident.identifiable else "[red]NOT identifiable[/red]"
    lines = [f"identifiability ({run.label}): rank {ident.rank}/{len(ident.names)}, condition number "
             f"{ident.condition_number:.3g} -> {verdict}"]
    lines += [f"  [red]{name}[/red]: {why}" for name, why in ident.reasons.items()]
    return "\n".join(lines)


def _print_demo(result: drivecal.DemoResult, console: Console) -> None:
    console.print(f"[bold]drivecal demo[/bold]: synthetic bench on the Jaxonomy engine, sensor noise "
                  f"{result.noise * 1e3:g} mA, seed {result.seed}; prior = datasheet guess 30-50 % off, "
                  "search started from an equation-error estimate of the data (column 'initial')\n")
    for run in (result.default, result.poor):
        console.print(_identifiability_lines(run))
        console.print(_design_table(run, result.truth))
        console.print()
    poor = result.poor.calibration
    dead = [n for n, ok in zip(poor.names, poor.identifiable) if not ok]
    if dead:
        console.print(f"The locked q-step alone cannot calibrate {', '.join(dead)}: they are held at the "
                      "datasheet values and not reported as calibrated.")


@cli.command()
@click.option("--out", "out_dir", type=click.Path(file_okay=False, writable=True), default=None,
              help="Directory for report.json and the PNG figures (created if missing).")
@click.option("--noise", type=_Positive(), default=0.02, show_default=True,
              help="Current-sensor noise standard deviation [A] added to the synthetic bench.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True,
              help="Seed of the sensor noise (the poor design uses seed + 1).")
@click.option("--json", "as_json", is_flag=True, help="Print the result JSON on stdout instead of tables.")
def demo(out_dir, noise, seed, as_json):
    """Calibrate the default motor on the synthetic bench, then show a failed design.

    \b
    1. The default plan runs on the Jaxonomy engine (locked d-step, locked
       q-step, free spin-up at 20 kHz) and sensor noise is added.
    2. Identifiability is checked, then R, Ld, Lq, lambda_m are fitted from a
       datasheet guess 30-50 % off; each gets a 95 % interval.
    3. A locked q-step alone is tried: Ld and lambda_m are dead (rank 2 of 4),
       named, and not reported as calibrated.

    With --out DIR it also writes DIR/report.json and PNG figures.
    """
    # A pipe or a log file gets a fixed width wide enough for the table.
    console = Console(stderr=as_json, width=None if sys.stdout.isatty() else 120)
    with console.status("running the synthetic bench and fitting...") as status:
        result = drivecal.run_demo(noise=noise, seed=seed, progress=lambda m: status.update(m) if not as_json else None)
        if out_dir is not None:
            status.update("writing figures and report.json")
            written = drivecal.write_demo_outputs(result, out_dir)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
    else:
        _print_demo(result, console)
        if out_dir is not None:
            console.print(f"wrote {len(written)} files to {out_dir}/: " + ", ".join(p.name for p in written))


_MOTOR_HELP = ("Motor file (TOML): nominal R, Ld, Lq, lambda_m (the prior) and fixed pole_pairs, J, B. "
               "Default: the 48 V demo motor.")


def _motor_option(f):
    return click.option("--motor", "motor_path", type=click.Path(dir_okay=False), default=None, help=_MOTOR_HELP)(f)


def _console(as_json: bool) -> Console:
    # A pipe or a log file gets a fixed width wide enough for the tables.
    return Console(stderr=as_json, width=None if sys.stdout.isatty() else 120)


@cli.command()
@click.argument("plan_path", metavar="PLAN.toml", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--noise", type=_Positive(), default=0.02, show_default=True,
              help="Current-sensor noise standard deviation [A] added to i_d and i_q.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True, help="Seed of the sensor noise.")
@click.option("--speed/--no-speed", "record_speed", default=True, show_default=True,
              help="Also write the measured mechanical speed w_m [rad/s] (an encoder; noise-free).")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Bench file to write: .csv, .parquet or .mat (format from the suffix).")
def simulate(plan_path, motor_path, noise, seed, record_speed, out_path):
    """Run PLAN.toml on the synthetic bench and write a bench file.

    The plan runs on the Jaxonomy engine (its PMSM block and adaptive solver)
    with the motor of --motor, currents are sampled at the plan's sample rate
    and seeded Gaussian noise is added. The file has the bench-file columns
    (segment, locked, t, v_d, v_q, i_d, i_q, w_m; temperature when the plan
    sets one) and can be fitted with `drivecal fit`. Bench effects set in the
    motor file (v_dead, offsets, delay_samples, alpha_R with segment
    temperatures) are part of the simulated truth.
    """
    from pathlib import Path

    out = Path(out_path)
    if out.suffix.lower() not in (".csv", ".parquet", ".mat"):
        raise drivecal.DrivecalError(f"--out {out}: unknown format '{out.suffix}'; use a .csv, .parquet or .mat name.")
    plan = drivecal.load_plan(plan_path)
    motor_file = drivecal.load_motor(motor_path)
    console = _console(False)
    with console.status(f"running {len(plan.segments)} segment(s) on the Jaxonomy engine..."):
        bench = drivecal.engine_bench(plan, motor_file.motor, record_speed=record_speed,
                                      delay_samples=motor_file.delay_samples).add_noise(noise, seed)
        bench.save(out)
    console.print(f"wrote {out}: {bench.num_samples} samples in {len(bench.segments)} segment(s) at "
                  f"{bench.sample_rate:g} Hz, noise {noise * 1e3:g} mA (seed {seed})")


def _fit_table(cal: drivecal.Calibration) -> Table:
    table = Table(title=f"{cal.source}: {cal.message}, {int(cal.iterations)} LM steps, "
                        f"sigma_hat {float(cal.sigma_hat) * 1e3:.3f} mA", title_justify="left")
    for col in ("parameter", "unit", "prior", "estimate", "std err", "95 % CI", "rel. CI [%]"):
        justify = "left" if col in ("parameter", "unit", "95 % CI") else "right"
        table.add_column(escape(col), justify=justify, no_wrap=True)
    for i, n in enumerate(cal.names):
        prior = _fmt(float(getattr(cal.prior, n)))
        if cal.identifiable[i]:
            half = 0.5 * (cal.ci95[i, 1] - cal.ci95[i, 0])
            table.add_row(n, drivecal.UNITS[n], prior, _fmt(cal.estimate[i]), f"{cal.se[i]:.3g}",
                          f"[{_fmt(cal.ci95[i, 0])}, {_fmt(cal.ci95[i, 1])}]", f"±{100 * half / abs(cal.estimate[i]):.3f}")
        else:
            table.add_row(n, drivecal.UNITS[n], prior, f"[dim]{_fmt(cal.estimate[i])} (prior)[/dim]", "-",
                          "[red]not identifiable[/red]", "-")
    return table


@cli.command("fit")
@click.argument("bench_path", metavar="BENCH", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--measured-speed/--simulated-speed", default=True, show_default=True,
              help="On free segments with a w_m column, use the measured speed as an input (J and B not needed); "
                   "--simulated-speed integrates the speed from J and B of the motor file instead.")
@click.option("--noise", type=_Positive(), default=None,
              help="The current sensor's noise standard deviation [A], if known: a sigma_hat well above it "
                   "is reported as model mismatch. Without it only the whiteness of the residuals is judged.")
@click.option("--estimate", "estimate", default=None, metavar="NAMES",
              help="Comma-separated parameters to estimate, replacing the motor file's 'estimate', e.g. "
                   "R,Ld,Lq,lambda_m,v_dead,offset_d,offset_q (bench effects: v_dead, offset_d, offset_q, "
                   "offset_a, offset_b, alpha_R).")
@click.option("--delay", "delay_samples", type=click.IntRange(0, 100), default=None,
              help="The inverter's PWM/computation delay [samples], replacing the motor file's 'delay_samples'.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default=None,
              help="Directory for report.json, report.html and the PNG figures (created if missing).")
@click.option("--json", "as_json", is_flag=True, help="Print the result JSON on stdout instead of the table.")
def fit_command(bench_path, motor_path, measured_speed, noise, estimate, delay_samples, out_dir, as_json):
    """Calibrate R, Ld, Lq, lambda_m from a bench file (.csv, .parquet or .mat).

    \b
    The file holds one row per sample: segment, locked (0/1), t [s],
    v_d, v_q [V], i_d, i_q [A], optional w_m [rad/s] and temperature [degC];
    or phase columns i_a, i_b, (i_c), v_a, v_b, (v_c) with theta_e or
    theta_m [rad].
    The motor file's values are the starting point and the prior; a parameter
    the recording cannot identify is held there and reported as such. Bench
    effects (dead time, sensor offsets, temperature coefficient) are fitted
    jointly when named in --estimate or the motor file's 'estimate'.
    """
    motor_file = drivecal.load_motor(motor_path)
    if estimate is not None:
        motor_file = motor_file.model_copy(update={"estimate": _estimate_names(estimate)})
    if delay_samples is not None:
        motor_file = motor_file.model_copy(update={"delay_samples": delay_samples})
    prior = motor_file.motor
    bench = drivecal.load_bench(bench_path, pole_pairs=float(prior.pole_pairs), nominal_R=float(prior.R))
    experiment = bench.experiment(measured_speed=measured_speed, delay_samples=motor_file.delay_samples)
    if motor_file.estimate is not None:
        drivecal.check_requested(motor_file.names, experiment, bench_path)
    console = _console(as_json)
    with console.status("checking identifiability and fitting..."):
        cal = drivecal.fit(bench, prior, names=motor_file.names, measured_speed=measured_speed,
                           delay_samples=motor_file.delay_samples)
        payload = drivecal.build_result(cal, bench, experiment=experiment, noise_sigma=noise, input_path=bench_path,
                                        motor_file=motor_path)
        payload["measured_speed"] = bool(measured_speed and bench.has_measured_speed)
        payload["drivecal_version"] = drivecal.__version__
        saturation = drivecal.check_saturation(bench, prior)
        payload["saturation"] = saturation.to_dict() if saturation.tested else None
        if out_dir is not None:
            written = _write_fit_outputs(cal, payload, out_dir)
    if as_json:
        click.echo(json.dumps(payload, indent=2))
        return
    ident = cal.identifiability
    verdict = "[green]identifiable[/green]" if ident.identifiable else "[red]NOT fully identifiable[/red]"
    speed = "measured speed as input" if payload["measured_speed"] else "speed simulated from J and B"
    console.print(f"identifiability: rank {ident.rank}/{len(ident.names)}, condition number "
                  f"{ident.condition_number:.3g} -> {verdict}; {speed}")
    for name, why in ident.reasons.items():
        console.print(f"  [red]{name}[/red]: {why}")
    console.print(_fit_table(cal))
    verdict = payload["verdict"]
    colour = {"calibrated": "green"}.get(verdict["status"], "red")
    console.print(f"verdict: [{colour}]{escape(verdict['headline'])}[/{colour}]")
    for line in verdict.get("details", []):
        console.print(f"  {escape(line)}")
    for line in (payload["saturation"] or {}).get("findings", []):
        colour = "red" if "saturates" in line else "green"
        console.print(f"saturation check: [{colour}]{escape(line)}[/{colour}]")
    if out_dir is not None:
        console.print(f"wrote {len(written)} files to {out_dir}/: " + ", ".join(p.name for p in written))


def _estimate_names(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in drivecal.ESTIMABLE]
    if unknown or not names:
        raise drivecal.DrivecalError(f"--estimate: unknown parameter(s) {', '.join(unknown) or '(none given)'}; "
                                     f"choose from {', '.join(drivecal.ESTIMABLE)}.")
    return names


def _write_fit_outputs(cal, payload, out_dir):
    from drivecal.report import plots
    from drivecal._io import prepare_output_dir, save_figure, write_json

    out = prepare_output_dir(out_dir)
    written = []
    figures = {
        "convergence.png": plots.convergence_figure(cal),
        "estimates.png": plots.estimates_figure(cal),
        "identifiability.png": plots.identifiability_figure({cal.source: cal.identifiability}),
    }
    for name, fig in figures.items():
        save_figure(fig, out / name)
        written.append(out / name)
    write_json(out / "report.json", payload)
    drivecal.write_html_report(payload, out / "report.html")
    return written + [out / "report.json", out / "report.html"]


@cli.command()
@click.argument("plan_path", metavar="PLAN.toml", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--noise", type=_Positive(), default=0.02, show_default=True,
              help="Expected current-sensor noise standard deviation [A], for the predicted intervals.")
@click.option("--json", "as_json", is_flag=True, help="Print the assessment JSON on stdout instead of tables.")
@click.option("--optimize", is_flag=True,
              help="Improve the plan's amplitudes, durations and bands for the smallest predicted confidence "
                   "volume (D-optimal) within the voltage circle, the current limit and the time budget; "
                   "needs --out.")
@click.option("--budget", type=_Positive(), default=None,
              help="With --optimize: total duration of the improved plan [s] (default: the plan's own).")
@click.option("--out", "out_path", type=click.Path(dir_okay=False), default=None,
              help="With --optimize: the improved plan file to write (TOML).")
def design(plan_path, motor_path, noise, as_json, optimize, budget, out_path):
    """Judge PLAN.toml before bench time: feasibility, identifiability, predicted intervals.

    \b
    On the nominal motor of --motor it checks
      - the voltage circle |v_dq| <= v_dc/sqrt(3) of every sample,
      - the predicted peak current against the plan's current_limit,
      - that a free spin-up stays stable and under max_speed,
    then the rank and condition number of the sensitivity Jacobian, dead and
    weak parameters (with the reason), and the 95 % CI half-width each
    parameter would get at the given noise. Exit status 2 when the plan is
    infeasible or cannot identify every parameter.

    With --optimize --out OPT.toml the plan is improved first (D-optimal: the
    smallest predicted confidence volume, same segments, within the limits and
    --budget) and written to OPT.toml; the predicted intervals before and
    after and the volume ratio are printed.
    """
    if optimize:
        _design_optimize(plan_path, motor_path, noise, as_json, budget, out_path)
        return
    if budget is not None or out_path is not None:
        raise click.UsageError("--budget and --out go with --optimize")
    plan = drivecal.load_plan(plan_path)
    motor_file = drivecal.load_motor(motor_path)
    if motor_file.estimate is not None:
        drivecal.check_requested(motor_file.names, drivecal.Experiment.from_plan(plan), plan_path)
    report = drivecal.assess_design(plan, motor_file.motor, noise_sigma=noise, names=motor_file.names,
                                    delay_samples=motor_file.delay_samples)
    if as_json:
        click.echo(json.dumps(report.to_dict(), indent=2))
    else:
        _print_design(report, plan_path, _console(False))
    if not report.ok:
        what = []
        if report.problems:
            what.append(f"{len(report.problems)} feasibility problem(s)")
        dead = report.identifiability.dead_params + report.identifiability.confounded_params
        if dead:
            what.append("cannot identify " + ", ".join(dead))
        elif not report.identifiability.identifiable:
            what.append("is ill-conditioned")
        raise drivecal.PlanError(f"{plan_path}: the plan {' and '.join(what)}; see the assessment above.")


def _design_optimize(plan_path, motor_path, noise, as_json, budget, out_path) -> None:
    from pathlib import Path

    from drivecal.plan import write_plan
    from drivecal.design import load_plan_waveforms

    if out_path is None:
        raise click.UsageError("--optimize needs --out OPT.toml, the improved plan file to write")
    out = Path(out_path)
    if out.is_dir() or not out.parent.is_dir():
        raise drivecal.DrivecalError(f"--out {out}: not a file in an existing directory; give a path like "
                                     "out/optimal_plan.toml.")
    plan, specs = load_plan_waveforms(plan_path)
    motor_file = drivecal.load_motor(motor_path)
    if motor_file.estimate is not None:
        drivecal.check_requested(motor_file.names, drivecal.Experiment.from_plan(plan), plan_path)
    console = _console(as_json)
    with console.status("optimizing the plan (D-optimal: BFGS through the sensitivity Jacobian)..."):
        result = drivecal.optimize_plan(plan, motor_file.motor, waveforms_spec=specs, budget=budget,
                                        noise_sigma=noise, names=motor_file.names)
    header = (f"D-optimal plan written by `drivecal design --optimize` from {plan_path}\n"
              f"budget {result.budget:g} s; predicted confidence volume x{result.volume_ratio:.3g} "
              f"(det of the covariance x{result.det_ratio:.3g}) on the nominal motor, noise {noise:g} A")
    tables = {key: spec for key, spec in result.waveforms_after.items() if isinstance(spec, dict)}
    write_plan(out, result.plan_after, tables, header=header)
    if as_json:
        click.echo(json.dumps({"plan": str(plan_path), "out": str(out), **result.to_dict()}, indent=2))
        return
    _print_optimal(result, plan_path, out, console)


def _print_optimal(result, plan_path, out, console: Console) -> None:
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
        if spec["kind"] == "step":
            return f"step {spec['level']:.3g}"
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
    table = Table(title=f"predicted 95 % CI half-widths at noise {result.noise_sigma * 1e3:g} mA",
                  title_justify="left")
    table.add_column("plan", justify="left", no_wrap=True)
    for n in result.names:
        table.add_column(escape(f"{n} [{drivecal.UNITS[n]}]"), justify="right", no_wrap=True)
    table.add_column("log det Cov", justify="right", no_wrap=True)
    table.add_row("before", *(f"±{x:.3g}" for x in result.ci95_before), f"{result.logdet_before:.2f}")
    table.add_row("after", *(f"±{x:.3g}" for x in result.ci95_after), f"{result.logdet_after:.2f}")
    table.add_row("after / before", *(f"{a / b:.3f}" for a, b in zip(result.ci95_after, result.ci95_before)),
                  f"{result.logdet_after - result.logdet_before:+.2f}")
    console.print(table)
    verdict = "identifiable" if result.report_after.identifiability.identifiable else "NOT identifiable"
    console.print(f"confidence volume ratio (after / before) {result.volume_ratio:.3g}; det(Cov) ratio "
                  f"{result.det_ratio:.3g}; improved plan feasible, {verdict}, condition number "
                  f"{result.report_after.identifiability.condition_number:.3g}")
    if not result.improved:
        console.print("[yellow]no better feasible plan was found: the input plan is written unchanged[/yellow]")
    console.print(f"wrote {out}")


def _print_design(report, plan_path, console: Console) -> None:
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
    verdict = "[green]identifiable[/green]" if ident.identifiable else "[red]NOT identifiable[/red]"
    console.print(f"identifiability: rank {ident.rank}/{len(ident.names)}, condition number "
                  f"{ident.condition_number:.3g} -> {verdict}")
    table = Table(title=f"predicted 95 % intervals at noise {ident.noise_sigma * 1e3:g} mA", title_justify="left")
    for col in ("parameter", "unit", "nominal", "± 95 % CI", "rel. [%]", "identifiable"):
        justify = "left" if col in ("parameter", "unit", "identifiable") else "right"
        table.add_column(escape(col), justify=justify, no_wrap=True)
    for i, n in enumerate(ident.names):
        nominal = float(getattr(report.motor, n))
        half = ident.predicted_ci95[i]
        relative = f"{100 * half / abs(nominal):.3g}" if nominal != 0 else "-"
        if n not in ident.fit_names:
            table.add_row(n, drivecal.UNITS[n], _fmt(nominal), "-", "-", "[red]no[/red]")
        elif n in ident.weak_params:
            table.add_row(n, drivecal.UNITS[n], _fmt(nominal), f"{half:.3g}", relative, "[yellow]weak[/yellow]")
        else:
            table.add_row(n, drivecal.UNITS[n], _fmt(nominal), f"{half:.3g}", relative, "yes")
    console.print(table)
    for n in ident.names:
        if n in ident.reasons:
            colour = "yellow" if n in ident.fit_names else "red"
            console.print(f"  [{colour}]{n}[/{colour}]: {escape(ident.reasons[n])}")


@cli.command("plan")
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
              help="Expected current-sensor noise standard deviation [A], for the predicted intervals. "
                   "Default: 0.2 % of --imax.")
@click.option("--json", "as_json", is_flag=True, help="Print the plan and its assessment as JSON on stdout.")
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Plan file to write (TOML, the format `drivecal design` and `simulate` read).")
def plan_command(motor_path, vdc, imax, max_speed, budget, sample_rate, noise, as_json, out_path):
    """Design a bench plan for the motor: feasible, identifiable, scaled to it.

    \b
    Three segments, from the nominal motor of --motor and the bench limits:
      - locked d-step and q-step: steady current half of --imax (v = i*R,
        inside the voltage circle), 6 electrical time constants L/R long;
      - free spin-up on v_q: peak speed under 80 % of --max-speed (and of
        the no-load speed), a few mechanical time constants long;
      - sample rate: >= 10 samples per electrical time constant and
        <= 0.1 electrical rad per sample.
    The plan is judged like `drivecal design` (predicted peaks, rank,
    predicted 95 % CI half-widths) and scaled down until it is feasible.
    Exit status 2 when no feasible, identifiable plan exists.
    """
    from pathlib import Path

    out = Path(out_path)
    if out.is_dir() or not out.parent.is_dir():
        raise drivecal.DrivecalError(f"--out {out}: not a file in an existing directory; give a path like "
                                     "plans/motor.toml.")
    motor_file = drivecal.load_motor(motor_path)
    report = drivecal.auto_design(motor_file.motor, v_dc=vdc, current_limit=imax, max_speed=max_speed,
                                  budget=budget, sample_rate=sample_rate, noise_sigma=noise)
    plan = report.plan
    header = (f"drivecal plan: auto-plan for {motor_file.source}\n"
              f"v_dc {vdc:g} V, current limit {imax:g} A, max speed "
              f"{'-' if max_speed is None else f'{max_speed:g} rad/s'}, budget "
              f"{'-' if budget is None else f'{budget:g} s'}")
    drivecal.write_plan(out, plan, header=header)
    if as_json:
        click.echo(json.dumps({"plan": str(out), "sample_rate": plan.sample_rate, "num_samples": plan.num_samples,
                               "duration": sum(s.duration for s in plan.segments),
                               "segments": [{"name": s.name, "locked": s.locked, "duration": s.duration,
                                             "v_d": float(s.v_d), "v_q": float(s.v_q)} for s in plan.segments],
                               "assessment": report.to_dict()}, indent=2))
    else:
        _print_plan(report, out, _console(False))


def _print_plan(report, out, console: Console) -> None:
    plan, ident = report.plan, report.identifiability
    duration = sum(s.duration for s in plan.segments)
    console.print(f"[bold]wrote {out}[/bold]: {len(plan.segments)} segments, {duration:.4g} s, {plan.num_samples} "
                  f"samples at {plan.sample_rate:g} Hz; voltage limit {plan.voltage_limit:.4g} V, current limit "
                  f"{plan.current_limit:g} A")
    seg_table = Table(title="segments, predicted on the nominal motor", title_justify="left")
    for col in ("segment", "rotor", "duration [s]", "v_d [V]", "v_q [V]", "peak |i_dq| [A]", "peak w_m [rad/s]"):
        seg_table.add_column(escape(col), justify="left" if col in ("segment", "rotor") else "right", no_wrap=True)
    for seg, pred in zip(plan.segments, report.segments):
        seg_table.add_row(seg.name, "locked" if seg.locked else "free", f"{seg.duration:.4g}", f"{float(seg.v_d):.4g}",
                          f"{float(seg.v_q):.4g}", f"{pred.peak_current:.3g}",
                          "-" if pred.locked else f"{pred.peak_speed:.4g}")
    console.print(seg_table)
    console.print(f"identifiability: rank {ident.rank}/{len(ident.names)}, condition number "
                  f"{ident.condition_number:.3g} -> [green]identifiable[/green]")
    table = Table(title=f"predicted 95 % intervals at noise {ident.noise_sigma * 1e3:.4g} mA", title_justify="left")
    for col in ("parameter", "unit", "nominal", "± 95 % CI", "rel. [%]"):
        table.add_column(escape(col), justify="left" if col in ("parameter", "unit") else "right", no_wrap=True)
    for i, n in enumerate(ident.names):
        nominal = float(getattr(report.motor, n))
        half = ident.predicted_ci95[i]
        table.add_row(n, drivecal.UNITS[n], _fmt(nominal), f"{half:.3g}", f"{100 * half / nominal:.3g}")
    console.print(table)


EXIT_COMPLETED_WITH_FAILURES = 1


@cli.command()
@click.argument("inputs", metavar="INPUT...", nargs=-1, required=True)
@click.option("--out", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Results table (.parquet): one row per motor.")
@_motor_option
@click.option("--chunk", type=click.IntRange(min=1), default=256, show_default=True,
              help="Motors per compiled call and per saved part of the table.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local helper processes, one per core (default: this machine's cores, at most one per "
                   "chunk; 1: everything in this process).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Send chunks to a running dask.distributed scheduler, e.g. tcp://10.0.0.5:8786.")
@click.option("--resume", is_flag=True, help="Continue an interrupted run of the same --out: skip motors already done.")
@click.option("--measured-speed/--simulated-speed", default=True, show_default=True,
              help="Use a measured w_m as an input on free segments (see `drivecal fit --help`).")
@click.option("--outlier-z", type=_Positive(), default=5.0, show_default=True,
              help="Robust z-score (median/MAD of the batch) beyond which a parameter flags a motor.")
@click.option("--json", "as_json", is_flag=True, help="Print the run summary as JSON on stdout; no progress bar.")
def batch(inputs, out_path, motor_path, chunk, workers, scheduler, resume, measured_speed, outlier_z, as_json):
    """Calibrate many motors: one bench file per motor, one results table.

    \b
    INPUT is bench files, directories (searched recursively) or glob patterns.
    The serial number is the file name, or the file's `serial` column.
    Motors that share a plan shape are fitted together in one compiled call
    per chunk. Every file gets a row: a file that fails validation or a fit
    that does not converge is recorded with its reason and the run goes on.
    Each chunk's rows are saved as they finish, so a killed run continues
    with --resume and loses nothing. At the end every parameter is compared
    with the batch (robust z-score) and outliers are flagged.

    Exit status: 0 all calibrated, 1 completed with failures, 2 bad input.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if workers is not None and scheduler is not None:
        raise click.UsageError("give --workers (local processes) or --scheduler (a dask cluster), not both")
    drivecal.fleet.tune_for_batch()  # this process is the batch: before JAX starts its threads
    motor_file = drivecal.load_motor(motor_path)
    console = _console(as_json)
    show = not as_json and console.is_terminal
    columns = (TextColumn("calibrating"), BarColumn(), MofNCompleteColumn(),
               TextColumn("{task.fields[rate]:.0f} motors/s"), TimeRemainingColumn())
    with Progress(*columns, console=console, disable=not show, transient=True) as bar:
        task = bar.add_task("batch", total=None, rate=0.0)
        started = {}

        def progress(done, total):
            import time

            now = time.perf_counter()
            started.setdefault("t", now)
            started.setdefault("done", done)
            elapsed = now - started["t"]
            rate = (done - started["done"]) / elapsed if elapsed > 0 else 0.0
            bar.update(task, completed=done, total=total, rate=rate)

        summary = drivecal.fleet.run_batch(inputs, out_path, motor_file, chunk=chunk, workers=workers,
                                           scheduler=scheduler, resume=resume, measured_speed=measured_speed,
                                           outlier_z=outlier_z, progress=progress)
    if as_json:
        click.echo(json.dumps(summary.to_dict(), indent=2))
    else:
        _print_batch_summary(summary, console)
    if summary.completed_with_failures:
        raise SystemExit(EXIT_COMPLETED_WITH_FAILURES)


def _print_batch_summary(summary, console: Console) -> None:
    rate = (summary.total - summary.done_before) / summary.seconds if summary.seconds > 0 else 0.0
    state = "[red]completed with failures[/red]" if summary.completed_with_failures else "[green]completed[/green]"
    console.print(f"{state}: {summary.total} motors in {summary.out} ({summary.done_before} from an earlier run); "
                  f"{summary.calibrated} calibrated, {summary.partial} partially, {summary.failed} failed "
                  f"(see the status and reason columns); {summary.seconds:.1f} s, {rate:.0f} motors/s")
    if summary.outliers:
        console.print(f"fleet outliers ({len(summary.outliers)}): " + ", ".join(summary.outliers))
    if summary.mismatch:
        console.print(f"model mismatch suspected ({len(summary.mismatch)}): " + ", ".join(summary.mismatch))


# --- report and hand-off commands (issue 5) -------------------------------------------------------


@cli.command()
@click.argument("result_json", type=click.Path(dir_okay=False))
@click.option("--html", "html_out", type=click.Path(dir_okay=False, writable=True), default=None,
              help="Write the self-contained HTML report (figures embedded) to this file.")
@click.option("--json", "as_json", is_flag=True, help="Print the verdict of each fit as JSON on stdout.")
def report(result_json, html_out, as_json):
    """Print the calibration report of a saved result JSON; optionally write the HTML report.

    RESULT_JSON is a file written by `drivecal fit` or `drivecal demo --out DIR`
    (DIR/report.json). The HTML equals the one the run wrote, apart from its
    time stamp.
    """
    from pathlib import Path

    from drivecal.report import write_html_report
    from drivecal.report import load_result, result_fits

    doc = load_result(result_json)
    if html_out is not None:
        target = Path(html_out)
        if target.is_dir() or not target.parent.is_dir():
            raise drivecal.DrivecalError(f"--html {target}: not a file in an existing directory; "
                                         "give a path like out/report.html.")
    fits = result_fits(doc)
    if as_json:
        click.echo(json.dumps({k: f.get("verdict") for k, f in fits.items()}, indent=2))
    else:
        for label, fit_doc in fits.items():
            verdict = fit_doc.get("verdict") or {}
            click.echo(f"== {label}: {verdict.get('headline', '')}")
            click.echo(str(drivecal.Calibration.from_dict(fit_doc)))
            click.echo()
    if html_out is not None:
        write_html_report(doc, html_out)
        click.echo(f"wrote {html_out}", err=as_json)


@cli.command()
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
    from drivecal.report import design_current_loop
    from drivecal.report import load_result, select_fit

    doc = load_result(result_json)
    label, fit_doc = select_fit(doc, design, source=str(result_json))
    cal = drivecal.Calibration.from_dict(fit_doc)
    result = design_current_loop(cal, bandwidth, sample_rate_hz=sample_rate, num_samples=samples, seed=seed)
    if as_json:
        click.echo(json.dumps({"result": str(result_json), "design": label, **result.to_dict()}, indent=2))
        return
    console = Console(width=None if sys.stdout.isatty() else 120)
    _print_gains(result, console, f"{result_json} ({label})")


def _print_gains(result, console: Console, source: str) -> None:
    from rich.markup import escape

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

@cli.command("fleet-report")
@click.argument("results", metavar="RESULTS.parquet", type=click.Path(dir_okay=False))
@click.option("--html", "html_out", required=True, type=click.Path(dir_okay=False),
              help="Write the self-contained HTML fleet report (histograms, outliers, trends) here.")
def fleet_report(results, html_out):
    """Summarise a `drivecal batch` table: counts, outliers, failures, histograms and trends.

    The page lists the outliers with their robust z-scores (median/MAD of the
    batch), the motors that failed with their reasons, and plots each
    parameter's distribution and its trend along the serial order.
    """
    from pathlib import Path

    from drivecal.fleet import write_fleet_report

    target = Path(html_out)
    if target.is_dir() or not target.parent.is_dir():
        raise drivecal.DrivecalError(f"--html {target}: not a file in an existing directory; "
                                     "give a path like out/fleet.html.")
    table = write_fleet_report(results, target)
    outliers = table.loc[table["outlier"].fillna(False).astype(bool), "serial"].astype(str).tolist()
    click.echo(f"wrote {target}: {len(table)} motors, {len(outliers)} outlier(s)"
               + (": " + ", ".join(outliers) if outliers else ""))


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning bad input into one line and exit status 2."""
    try:
        rv = cli.main(args=argv, prog_name="drivecal", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click.UsageError as exc:
        command = exc.ctx.command_path if exc.ctx else "drivecal"
        click.echo(f"drivecal: error: {exc.format_message()} (see '{command} --help')", err=True)
        raise SystemExit(EXIT_BAD_INPUT)
    except click.Abort:
        click.echo("drivecal: aborted", err=True)
        raise SystemExit(1)
    except drivecal.DrivecalError as exc:
        click.echo(f"drivecal: error: {exc}", err=True)
        raise SystemExit(EXIT_BAD_INPUT)
    except click.exceptions.Exit as exc:
        raise SystemExit(exc.exit_code)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main(sys.argv[1:]))
