"""``drivecal fleet-report``: the HTML summary of a ``drivecal batch`` table."""

from __future__ import annotations

import click

from ._common import _check_out


@click.command("fleet-report")
@click.argument("results", metavar="RESULTS.parquet", type=click.Path(dir_okay=False))
@click.option("--html", "html_out", required=True, type=click.Path(),
              help="Write the self-contained HTML fleet report (histograms, outliers, trends) here.")
def fleet_report(results, html_out):
    """Summarise a `drivecal batch` table: counts, outliers, failures, histograms and trends.

    The page lists the outliers with their robust z-scores (median/MAD of the
    batch), the motors that failed with their reasons, and plots each
    parameter's distribution and its trend along the serial order.
    """
    target = _check_out(html_out, "--html", example="out/fleet.html")
    from ..fleet import write_fleet_report

    table = write_fleet_report(results, target)
    outliers = table.loc[table["outlier"].fillna(False).astype(bool), "serial"].astype(str).tolist()
    click.echo(f"wrote {target}: {len(table)} motors, {len(outliers)} outlier(s)"
               + (": " + ", ".join(outliers) if outliers else ""))
