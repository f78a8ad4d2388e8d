"""``drivecal fleet-report``: the HTML summary of a ``drivecal batch`` table."""

from __future__ import annotations

import click

from ._common import _check_out, _warn


@click.command("fleet-report")
@click.argument("results", metavar="RESULTS.parquet", type=click.Path(dir_okay=False))
@click.option("--html", "html_out", required=True, type=click.Path(),
              help="Write the self-contained HTML fleet report (counts, checks, outliers, trends) here.")
@click.option("--motor", "motor_path", type=click.Path(dir_okay=False), default=None, metavar="MOTOR.toml",
              help="Motor file whose nominal values and [tolerance] limits are drawn (and give the % of nominal); "
                   "without it, no nominal or tolerance lines.")
@click.option("--trend-by", "trend_by", default="serial", show_default=True, metavar="serial|COLUMN",
              help="Order of the trends along the line: the serial (natural order: SN2 before SN10) or a column "
                   "of the table with test times.")
def fleet_report(results, html_out, motor_path, trend_by):
    """Summarise a `drivecal batch` table: counts, outliers, failures, histograms and trends.

    Pass/fail against the specification comes first (when the batch judged
    one), then the calibration status, each check with its false-alarm rate
    on healthy motors, the parameters in engineering units against the
    nominal and the limits, and the listed motors. Each parameter's figure
    shows it along the line with a rolling median and band (drift), and its
    histogram, on a robust axis range: values beyond it are drawn at its
    edge and listed with their values.
    """
    target = _check_out(html_out, "--html", example="out/fleet.html")
    from ..fleet import write_fleet_report

    nominal, tolerances = _nominal_and_limits(motor_path)
    table = write_fleet_report(results, target, nominal=nominal, tolerances=tolerances, trend_by=trend_by)
    flagged = table["outlier"].fillna(False).astype(bool) if "outlier" in table else table["serial"].isna()
    outliers = table.loc[flagged, "serial"].astype(str).tolist()
    line = (f"wrote {target}: {len(table)} motors, {len(outliers)} outlier(s)"
            + (": " + ", ".join(outliers) if outliers else ""))
    if "spec" in table:
        from .._status import Spec

        counts = table["spec"].value_counts()
        line += "; specification: " + ", ".join(f"{int(counts[s.label])} {s.label}" for s in Spec
                                                if s.label in counts)
    click.echo(line)


def _nominal_and_limits(motor_path):
    """The nominal values (the keys the motor file gives) and the tolerance limits of ``--motor``, SI; read
    without JAX (``data.motor_nominal``) unless the file states its magnetic law as published."""
    if motor_path is None:
        return None, None
    from .._parameters import ESTIMATED
    from ..data import motor_nominal

    motor = motor_nominal(motor_path)
    missing = [n for n in ESTIMATED if n in motor.defaulted]
    if missing:
        _warn(f"--motor {motor_path}: {', '.join(missing)} not in the file; no nominal line for "
              f"{'them' if len(missing) > 1 else 'it'}.")
    tolerances = {n: (t.low, t.high) for n, t in motor.tolerance.items()}
    nominal = {n: motor.values[n] for n in (*ESTIMATED, *tolerances) if n not in motor.defaulted and n in motor.values}
    return nominal, tolerances
