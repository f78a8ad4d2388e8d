"""The ``drivecal`` command.

Bad input never shows a traceback: it is one sentence on stderr and exit status 2.
"""

from __future__ import annotations

import json
import math
import sys

import click
from rich.console import Console
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
        table.add_column(col, justify="left" if col in ("parameter", "unit", "95 % CI") else "right", no_wrap=True)
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
                  f"{result.noise * 1e3:g} mA, seed {result.seed}; start = prior = datasheet guess 30-50 % off\n")
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

    from drivecal.html import write_html_report
    from drivecal.record import load_result, result_fits

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
    from drivecal.gains import design_current_loop
    from drivecal.record import load_result, select_fit

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
