"""``drivecal demo``: the full calibration on the built-in synthetic bench, then a failed design."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import click

from ._common import _check_out, _console, _Positive

if TYPE_CHECKING:
    from rich.console import Console
    from rich.table import Table

    from ..demo import DemoResult, DesignRun
    from ..physics import MotorParams


def _design_table(run: DesignRun, truth: MotorParams) -> Table:
    from rich.markup import escape
    from rich.table import Table

    from .._units import estimate_cells, format_value
    from ..physics import UNITS

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
        if cal.identifiable[i]:  # each row in its engineering unit, to the SE's second significant digit
            cells = estimate_cells(float(cal.estimate[i]), UNITS[n], float(cal.se[i]), tuple(cal.ci95[i]))
            ci, est, err_se = f"[{cells.ci[0]}, {cells.ci[1]}]", cells.estimate, f"{e['error_in_se']:+.2f}"
        else:
            cells = estimate_cells(float(cal.estimate[i]), UNITS[n])
            ci, est, err_se = "[red]not identifiable[/red]", f"[dim]{cells.estimate} (prior)[/dim]", "-"
        table.add_row(n, cells.unit, format_value(e["true"], cells.scale), format_value(cal.initial[i], cells.scale),
                      est, f"{e['error_percent']:+.4f}", err_se, ci)
    return table


def _identifiability_lines(run: DesignRun) -> str:
    ident = run.calibration.identifiability
    lines = [f"identifiability ({run.label}): {ident.summary(markup=True)}"]
    lines += [f"  [red]{name}[/red]: {why}" for name, why in ident.reasons.items()]
    return "\n".join(lines)


def _print_demo(result: DemoResult, console: Console) -> None:
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


@click.command("demo")
@click.option("--out", "out_dir", type=click.Path(), default=None,
              help="Directory for report.json and the PNG figures (created if missing; its parent must exist).")
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
    if out_dir is not None:
        _check_out(out_dir, "--out", directory=True)
    import contextlib
    import gc

    from ..demo import run_demo, write_demo_outputs

    console = _console(as_json)
    renderer = contextlib.nullcontext()
    if out_dir is not None:  # without --out no figure is drawn: matplotlib (~0.4 s to import) stays out
        from .._figures import FigureRenderer

        # The figure workers start now and load matplotlib while the bench runs and the fits compile.
        renderer = FigureRenderer()
    with renderer, console.status("running the synthetic bench and fitting...") as status:
        result = run_demo(noise=noise, seed=seed, progress=lambda m: status.update(m) if not as_json else None)
        if out_dir is not None:
            status.update("writing figures and report.json")
            # The objects of the bench and the fits (traced programs among them) leave the garbage collector's
            # view: the figures' and the page's allocations no longer set off collections over them (the cold
            # demo's figures and page: 1.02-1.07 -> 0.98-1.01 s).
            gc.freeze()
            written = write_demo_outputs(result, out_dir, renderer)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
    else:
        _print_demo(result, console)
        if out_dir is not None:
            console.print(f"wrote {len(written)} files to {out_dir}/: " + ", ".join(p.name for p in written))
