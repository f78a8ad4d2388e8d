"""``drivecal fit``: calibrate one motor from a bench file."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import click

from ..errors import DrivecalError
from ._common import _check_out, _console, _format_option, _load_motor, _motor_option, _Positive

if TYPE_CHECKING:
    from rich.table import Table

    from ..results import Calibration


def _fit_table(cal: Calibration) -> Table:
    """The parameter table: each row in its parameter's engineering unit (mΩ, mH, mWb), the estimate and its
    interval to the SE's second significant digit."""
    from rich.markup import escape
    from rich.table import Table

    from .._units import estimate_cells, format_value
    from ..physics import UNITS

    table = Table(title=f"{cal.source}: {cal.message}, {int(cal.iterations)} LM steps, "
                        f"sigma_hat {float(cal.sigma_hat) * 1e3:.3f} mA", title_justify="left")
    for col in ("parameter", "unit", "prior", "estimate", "std err", "95 % CI", "rel. CI [%]"):
        justify = "left" if col in ("parameter", "unit", "95 % CI") else "right"
        table.add_column(escape(col), justify=justify, no_wrap=True)
    for i, n in enumerate(cal.names):
        value, prior = float(cal.estimate[i]), float(getattr(cal.prior, n))
        if cal.identifiable[i]:
            cells = estimate_cells(value, UNITS[n], float(cal.se[i]), tuple(cal.ci95[i]))
            half = 0.5 * (cal.ci95[i, 1] - cal.ci95[i, 0])
            table.add_row(n, cells.unit, format_value(prior, cells.scale), cells.estimate, cells.se,
                          f"[{cells.ci[0]}, {cells.ci[1]}]",
                          f"±{format_value(100 * half / abs(value), 1.0, 100 * half / abs(value))}" if value else "-")
        else:
            cells = estimate_cells(value, UNITS[n])
            table.add_row(n, cells.unit, format_value(prior, cells.scale), f"[dim]{cells.estimate} (prior)[/dim]",
                          "-", "[red]not identifiable[/red]", "-")
    return table


@click.command("fit")
@click.argument("bench_path", metavar="BENCH", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--measured-speed/--simulated-speed", default=None,
              help="On free segments with a w_m column, use the measured speed as an input (J and B not needed; "
                   "--speed input); --simulated-speed integrates the speed from J and B of the motor file "
                   "instead (--speed ignore).")
@click.option("--speed", "speed_mode", type=click.Choice(["input", "output", "ignore"]), default=None,
              help="What a measured w_m is: an input of the electrical equations, a second measured output (the "
                   "speed simulated from J, B and the friction and fitted to it, weighed by the noise of each "
                   "sensor: the motor file's current_noise and speed_noise, else estimated), or ignored. "
                   "Default: output when J, B, T_coulomb or T_load are estimated, else input, unless the speed "
                   "is too coarse or noisy to be an exact input (a quantised encoder difference: the output says "
                   "so), when it is an output if the motor file states J and B.")
@click.option("--noise", type=_Positive(), default=None,
              help="The current sensor's noise standard deviation [A], if known: a sigma_hat well above it "
                   "is reported as model mismatch. Default: the motor file's current_noise, else the noise "
                   "estimated from the samples (robust second differences; the verdict says which).")
@click.option("--estimate", "estimate", default=None, metavar="NAMES",
              help="Comma-separated parameters to estimate, replacing the motor file's 'estimate', e.g. "
                   "R,Ld,Lq,lambda_m,v_dead,offset_d,offset_q (bench effects: v_dead, offset_d, offset_q, "
                   "offset_a, offset_b, alpha_R).")
@click.option("--delay", "delay_samples", type=click.FloatRange(0, 100), default=None,
              help="Fix the inverter's PWM/computation delay [samples, may be fractional: 0.5, 1.5], replacing "
                   "the motor file's 'delay_samples'; without it the delay is found from the data (--effects).")
@click.option("--effects", "effects", default="auto", show_default=True, metavar="auto|none|LIST",
              help="Bench effects to model: 'auto' fits those the data support (delay, dead_time, offsets; "
                   "one at a time, largest evidence first, each kept only if a likelihood-ratio test supports "
                   "it), 'none' fits none, or a comma-separated list fits those.")
@click.option("--magnetics", "magnetics", type=click.Choice(["auto", "linear", "saturating"]), default="auto",
              show_default=True,
              help="Magnetic model: 'auto' fits the saturation terms (d, q, cross) the data support, each with "
                   "the exponents that fit best, and keeps one only where it changes the flux by 2 % or more; "
                   "where that law cannot converge on a motor with a magnet, a PM-assisted motor's iron bridge "
                   "is tried; 'linear' constant Ld, Lq; 'saturating' every term the plan can identify.")
@click.option("--out", "out_dir", type=click.Path(), default=None,
              help="Directory for report.json, report.html and the PNG figures (created if missing; its parent "
                   "must exist).")
@_format_option
@click.option("--json", "as_json", is_flag=True, help="Print the result JSON on stdout instead of the table.")
def fit_command(bench_path, motor_path, measured_speed, speed_mode, noise, estimate, delay_samples, effects, magnetics,
                out_dir,
                format_path, as_json):
    """Calibrate R, Ld, Lq, lambda_m from a bench file or log (CSV, Parquet, MAT, MDF4, TDMS, HDF5).

    \b
    The file holds one row per sample: segment, locked (0/1), t [s],
    v_d, v_q [V], i_d, i_q [A], optional w_m [rad/s] and temperature [degC];
    or phase columns i_a, i_b, (i_c), v_a, v_b, (v_c) with theta_e or
    theta_m [rad].
    A bench log as the bench writes it (MDF4, TDMS, HDF5, a CSV export in
    any dialect) is read through a format file (--format; `drivecal inspect
    LOG` proposes one).
    The motor file's values are the starting point and the prior; a parameter
    the recording cannot identify is held there and reported as such. Bench
    effects (the inverter's delay, its dead time, sensor offsets) and the
    magnetic saturation are found from the data by default (--effects auto,
    --magnetics auto), and reported with the evidence;
    any parameter named in --estimate or the motor file's 'estimate' (also
    alpha_R, offset_a, offset_b) is fitted whatever the tests say.

    \b
    Exit status: the verdict's, so a test-station script can gate on it:
      0  calibrated
      3  partially calibrated (some parameters not identifiable by the plan)
      4  model mismatch suspected (the intervals are not to be trusted)
      5  not converged
      2  bad input (the file, an option or the motor file; one sentence on stderr)
    With a [tolerance] table in the motor file, the specification's instead
    (each parameter's whole 95 % interval against its limits):
      0  pass     6  fail (the parameters are named)
      7  inconclusive (an interval straddles a limit; the advice says what
         would decide)     4, 5  not calibrated (the verdict's status)
    """
    renderer = None
    if out_dir is not None:
        _check_out(out_dir, "--out", directory=True)
        from .._figures import FigureRenderer

        renderer = FigureRenderer().start()  # the figure workers load matplotlib while the fit runs
        click.get_current_context().call_on_close(renderer.close)
    from rich.markup import escape

    from ..data import choose_speed, load_bench
    from ..diagnose import check_saturation
    from ..identify import check_requested
    from ..report import build_result
    from ..results import Status
    from ..selection import parse_effects, select_effects

    chosen = parse_effects(effects)
    motor_file = _load_motor(motor_path)
    if estimate is not None:
        motor_file = motor_file.replace(estimate=_estimate_names(estimate))
    if delay_samples is not None:
        motor_file = motor_file.replace(delay_samples=delay_samples, motor=motor_file.motor.replace(delay=delay_samples))
    names = motor_file.names
    if delay_samples is not None:  # a delay given on the command line is fixed, not searched
        names = tuple(n for n in names if n != "delay")
        chosen = chosen if not isinstance(chosen, tuple) else tuple(e for e in chosen if e != "delay")
    prior = motor_file.motor
    bench = load_bench(bench_path, pole_pairs=float(prior.pole_pairs), nominal_R=float(prior.R), format=format_path)
    current_noise = noise if noise is not None else motor_file.current_noise
    speed = choose_speed(bench, prior, names, speed=_requested_speed(speed_mode, measured_speed),
                         current_noise=current_noise, speed_noise=motor_file.speed_noise,
                         mechanics_given=motor_file.mechanics_given)
    experiment = bench.experiment(speed=speed.mode, delay_samples=motor_file.delay_samples,
                                  current_noise=current_noise, speed_noise=motor_file.speed_noise)
    if motor_file.estimate is not None:
        check_requested(motor_file.names, experiment, bench_path)
    console = _console(as_json)
    with console.status("checking identifiability, fitting and choosing the bench effects..."):
        selection = select_effects(experiment, bench.currents, prior, names=names, effects=chosen,
                                   source=bench.source, fixed_delay=delay_samples is not None,
                                   magnetics=magnetics)
        cal = selection.calibration
        saturation = check_saturation(bench, prior, modelled=selection.magnetic_model == "saturating")
        maps = None
        if selection.magnetic_model == "saturating":
            from ..diagnose import prepare_unmodelled_effects, untested_effects
            from ..maps import flux_maps
            from ..model import compiled_ahead

            # The verdict's score tests (build_result's: an encoder offset's where the file has the angle) compile
            # beside the maps' two programs (the SyRM bench's cold fit 14.7 -> 14.1 s, A/B medians of 3).
            tested = untested_effects(cal.fit_names, experiment) if bool(cal.converged) else ()
            with compiled_ahead(prepare_unmodelled_effects, cal.motor, cal.fit_names, experiment, tested):
                maps = flux_maps(cal, bench.currents)
        if noise is None and motor_file.current_noise is not None:
            noise, noise_source = motor_file.current_noise, "the motor file's current_noise"
        else:
            noise_source = "--noise"
        payload = build_result(cal, bench, experiment=experiment, noise_sigma=noise, noise_source=noise_source,
                               input_path=bench_path,
                               motor_file=motor_path, measured_speed=speed.mode == "input" and bench.has_measured_speed,
                               speed=speed.to_dict(),
                               saturation=saturation.to_dict() if saturation.tested else None,
                               effects=selection.to_dict(), tolerance=motor_file.tolerance,
                               flux_maps=None if maps is None else maps.to_dict())
        if out_dir is not None:
            written = _write_fit_outputs(payload, out_dir, renderer)
    status = Status(payload["verdict"]["status"])
    exit_code = _exit_code(status, payload.get("spec"))
    if as_json:
        click.echo(json.dumps(payload, indent=2))
        return exit_code
    ident = cal.identifiability
    speed_words = "measured speed as input" if payload["measured_speed"] else "speed simulated from J and B"
    if experiment.speed_outputs:
        speed_words = (f"measured speed as a second output (weight {float(experiment.speed_weight):.3g} A per "
                       "rad/s: current noise over speed noise)")
    console.print(f"identifiability: {ident.summary(markup=True)}; {speed_words}")
    if speed.reason:
        console.print(f"speed: [yellow]{escape(speed.reason)}[/yellow]")
    for name, why in ident.reasons.items():
        console.print(f"  [red]{name}[/red]: {why}")
    console.print(_fit_table(cal))
    console.print(_effects_line(selection))
    if maps is not None:
        console.print(escape(str(maps)))
    verdict = payload["verdict"]
    colour = "green" if status is Status.CALIBRATED else "red"
    console.print(f"verdict: [{colour}]{escape(verdict['headline'])}[/{colour}]")
    for line in verdict.get("details", []):
        console.print(f"  {escape(line)}")
    for line in (payload["saturation"] or {}).get("findings", []):
        colour = "red" if "saturates" in line else "green"
        console.print(f"saturation check: [{colour}]{escape(line)}[/{colour}]")
    if payload.get("spec"):
        _print_spec(payload["spec"], payload["parameters"], console)
    if out_dir is not None:
        console.print(f"wrote {len(written)} files to {out_dir}/: " + ", ".join(p.name for p in written))
    return exit_code


def _exit_code(status, spec) -> int:
    """The verdict's exit status, or with a specification the judgement's (not calibrated: the verdict's)."""
    from ..results import Spec

    if not spec or Spec(spec["status"]) is Spec.NOT_CALIBRATED:
        return status.exit_code
    return Spec(spec["status"]).exit_code


def _print_spec(spec: dict, parameters: dict, console) -> None:
    """The judgement against the motor file's tolerances: the headline, a line per parameter, the advice."""
    from rich.markup import escape

    from .._units import display_unit, format_value

    colour = {"pass": "green", "fail": "red"}.get(spec["status"], "yellow")
    console.print(f"specification: [{colour}]{escape(spec['headline'])}[/{colour}]")
    for p in spec["parameters"]:
        low, high = p["ci95"]
        scale, unit = display_unit(p["estimate"] if low is None else max(abs(low), abs(high)), p["unit"])
        se = parameters.get(p["name"], {}).get("se")  # the digits of the fit table
        interval = "not identified" if low is None else (
            f"95 % CI [{format_value(low, scale, se)}, {format_value(high, scale, se)}]")
        console.print(f"  {p['name']}: {p['outcome']} ({interval} {unit}; tolerance {escape(p['tolerance'])})")
    for line in spec["advice"]:
        console.print(f"  [yellow]{escape(line)}[/yellow]")


def _requested_speed(speed_mode, measured_speed) -> str | None:
    """--speed, else the legacy --measured-speed/--simulated-speed, else None (``data.choose_speed`` decides)."""
    if speed_mode is not None:
        if measured_speed is not None:
            raise click.UsageError("give --speed or --measured-speed/--simulated-speed, not both")
        return speed_mode
    if measured_speed is not None:
        return "input" if measured_speed else "ignore"
    return None


def _effects_line(selection) -> str:
    """One line per bench effect: included or not, and the evidence."""
    from rich.markup import escape

    from .._units import format_quantity
    from ..physics import UNITS

    lines = [f"bench effects ({selection.mode}):"]
    for c in selection.choices:
        mark = "[green]fitted[/green]" if c.included else "[dim]not fitted[/dim]"
        evidence = f", {c.test} p = {c.p_value:.2g}" if c.test and c.p_value == c.p_value else ""
        value = "; ".join(f"{n} = {format_quantity(v, UNITS.get(n, '-'), 1.96 * s)} (95 %)"
                          for n, (v, s) in c.estimate.items() if s == s and s > 0)
        lines.append(f"  {c.effect}: {mark} ({escape(c.how)}{evidence})" + (f": {escape(value)}" if value else ""))
    return "\n".join(lines)


def _estimate_names(text: str) -> tuple[str, ...]:
    from ..physics import ESTIMABLE

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in ESTIMABLE]
    if unknown or not names:
        raise DrivecalError(f"--estimate: unknown parameter(s) {', '.join(unknown) or '(none given)'}; "
                            f"choose from {', '.join(ESTIMABLE)}.")
    return names


def _write_fit_outputs(payload, out_dir, renderer):
    from .._io import FILE_DPI, prepare_output_dir, write_bytes, write_json
    from ..report import fit_figure_jobs, write_html_report

    out = prepare_output_dir(out_dir)
    written = []
    # The page's own figures of these names: one drawing serves the page and the file.
    page = fit_figure_jobs(payload)
    jobs = {f"{name}.png": page[name] for name in ("convergence", "estimates", "identifiability") if name in page}
    pending = {name: renderer.submit(kind, kwargs, dpi=FILE_DPI) for name, (kind, kwargs) in jobs.items()}
    write_json(out / "report.json", payload)
    write_html_report(payload, out / "report.html", renderer=renderer)
    for name, job in pending.items():
        write_bytes(out / name, job.result())
        written.append(out / name)
    return written + [out / "report.json", out / "report.html"]
