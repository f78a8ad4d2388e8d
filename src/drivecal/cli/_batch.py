"""``drivecal batch``: calibrate many motors, one bench file each, into one results table."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import click

from ._common import (EXIT_CLUSTER_LOST, _check_out, _console, _format_option,
                      _load_motor, _motor_option, _Positive, _warn)

if TYPE_CHECKING:
    from rich.console import Console


@click.command("batch")
@click.argument("inputs", metavar="INPUT...", nargs=-1, required=True)
@click.option("--out", "out_path", required=True, type=click.Path(),
              help="Results table (.parquet): one row per motor.")
@_motor_option
@click.option("--chunk", type=click.IntRange(min=1), default=256, show_default=True,
              help="Motors per compiled call and per saved part of the table.")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="Local helper processes, one per core (default: this machine's cores, at most one per "
                   "chunk; 1: everything in this process).")
@click.option("--scheduler", default=None, metavar="ADDRESS",
              help="Send chunks to a running dask.distributed scheduler, e.g. tls://10.0.0.5:8786 (TLS "
                   "certificates from dask's configuration; see docs/cluster.md).")
@click.option("--reconnect", type=click.FloatRange(min=0), default=0.0, metavar="SECONDS",
              help="With --scheduler: when the scheduler (or every worker) is lost, wait up to SECONDS for it to "
                   "come back and go on. Default 0: stop at once, exit status 8.")
@click.option("--resume", is_flag=True, help="Continue an interrupted run of the same --out: skip motors already done.")
@click.option("--measured-speed/--simulated-speed", default=True, show_default=True,
              help="Use a measured w_m as an input on free segments (see `drivecal fit --help`).")
@click.option("--outlier-z", type=_Positive(), default=5.0, show_default=True,
              help="Robust z-score (median/MAD of the batch) beyond which a parameter flags a motor.")
@click.option("--effects", "effects", default="auto", show_default=True, metavar="auto|none|LIST",
              help="Bench effects (delay, dead_time, offsets) as in `drivecal fit`; in a batch only the motors "
                   "whose residuals are not white are fitted again with the effects the data support.")
@_format_option
@click.option("--json", "as_json", is_flag=True, help="Print the run summary as JSON on stdout; no progress bar.")
def batch(inputs, out_path, motor_path, chunk, workers, scheduler, reconnect, resume, measured_speed, outlier_z,
          effects, format_path, as_json):
    """Calibrate many motors: one bench file per motor, one results table.

    \b
    INPUT is bench files, directories (searched recursively) or glob patterns.
    The serial number is the file name, or the file's `serial` column.
    One Parquet dataset (a file, or a directory of parts) may hold many
    motors: its rows are split by `serial`, one motor per serial. Bench logs
    (MDF4, TDMS, HDF5, CSV exports) are read through --format.
    Motors that share a plan shape are fitted together in one compiled call
    per chunk. Every file gets a row: a file that fails validation or a fit
    that does not converge is recorded with its reason and the run goes on.
    Each chunk's rows are saved as they finish, so a killed run continues
    with --resume and loses nothing. At the end every parameter is compared
    with the batch (robust z-score) and outliers are flagged.

    With a [tolerance] table in the motor file every motor is judged against
    it (column `spec`: pass, fail, inconclusive, not calibrated, invalid
    file; `spec_failed` names the parameters).

    \b
    Exit status: 0 all calibrated, 1 completed with failures, 2 bad input,
    8 the dask cluster was lost or could not be reached (the sentence says
    how many motors are saved; restart it, then run again with --resume).
    With a specification, the most serious first: 6 some motor failed it,
    1 some motor not judged (not calibrated, invalid file), 7 some
    inconclusive, 0 every motor passed.
    """
    if workers is not None and scheduler is not None:
        raise click.UsageError("give --workers (local processes) or --scheduler (a dask cluster), not both")
    if reconnect and scheduler is None:
        raise click.UsageError("--reconnect waits for a dask cluster: give its address with --scheduler")
    if scheduler is not None and _in_the_clear(scheduler):
        _warn(f"--scheduler {scheduler}: plain TCP is neither encrypted nor authenticated, and a dask scheduler "
              "runs whatever code it is sent; use its tls:// address (docs/cluster.md).")
    _check_out(out_path, "--out", example="out/results.parquet")
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    from ..errors import ClusterLost
    from ..fleet import run_batch, tune_for_batch
    from ..selection import parse_effects

    chosen = parse_effects(effects)
    tune_for_batch()  # this process is the batch: before JAX starts its threads
    motor_file = _load_motor(motor_path)
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

        try:
            summary = run_batch(inputs, out_path, motor_file, chunk=chunk, workers=workers, scheduler=scheduler,
                                reconnect=reconnect, resume=resume, measured_speed=measured_speed,
                                outlier_z=outlier_z, progress=progress, effects=chosen, format=format_path)
        except ClusterLost as exc:  # after the bar is gone: one sentence, its own exit status
            lost = exc
        else:
            lost = None
    if lost is not None:
        click.echo(f"drivecal: error: {lost}", err=True)
        raise SystemExit(EXIT_CLUSTER_LOST)
    if as_json:
        click.echo(json.dumps(summary.to_dict(), indent=2))
    else:
        _print_batch_summary(summary, console)
    if summary.exit_code:
        raise SystemExit(summary.exit_code)


def _print_batch_summary(summary, console: Console) -> None:
    rate = (summary.total - summary.done_before) / summary.seconds if summary.seconds > 0 else 0.0
    state = "[red]completed with failures[/red]" if summary.completed_with_failures else "[green]completed[/green]"
    console.print(f"{state}: {summary.total} motors in {summary.out} ({summary.done_before} from an earlier run); "
                  f"{summary.calibrated} calibrated, {summary.partial} partially, {summary.failed} failed "
                  f"(see the status and reason columns); {summary.seconds:.1f} s, {rate:.0f} motors/s")
    if summary.spec is not None:
        counts = ", ".join(f"{n} {label}" for label, n in summary.spec.items() if n)
        console.print(f"specification: {counts} (see the spec and spec_failed columns)")
    if summary.outliers:
        console.print(f"fleet outliers ({len(summary.outliers)}): " + ", ".join(summary.outliers))
    if summary.mismatch:
        console.print(f"model mismatch suspected ({len(summary.mismatch)}): " + ", ".join(summary.mismatch))


def _in_the_clear(scheduler: str) -> bool:
    """Whether ``scheduler`` is a plain-TCP address of another machine (not TLS, not this machine's loopback)."""
    import ipaddress

    scheme, _, rest = scheduler.rpartition("://")
    if scheme not in ("", "tcp"):
        return False
    host = rest.rsplit(":", 1)[0].strip("[]") if ":" in rest else rest
    if host == "localhost":
        return False
    try:
        return not ipaddress.ip_address(host).is_loopback
    except ValueError:  # a host name
        return True
