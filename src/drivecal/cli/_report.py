"""``drivecal report``: print a saved result's calibration report; optionally write its HTML."""

from __future__ import annotations

import json

import click

from ._common import _check_out


@click.command("report")
@click.argument("result_json", type=click.Path(dir_okay=False))
@click.option("--html", "html_out", type=click.Path(), default=None,
              help="Write the self-contained HTML report (figures embedded) to this file.")
@click.option("--json", "as_json", is_flag=True, help="Print the verdict of each fit as JSON on stdout.")
def report(result_json, html_out, as_json):
    """Print the calibration report of a saved result JSON; optionally write the HTML report.

    RESULT_JSON is a file written by `drivecal fit` or `drivecal demo --out DIR`
    (DIR/report.json). The HTML equals the one the run wrote, apart from its
    time stamp.
    """
    if html_out is not None:
        _check_out(html_out, "--html", example="out/report.html")
    from ..report import write_html_report
    from ..results import Calibration, load_result, result_fits

    doc = load_result(result_json)
    fits = result_fits(doc)
    if as_json:
        click.echo(json.dumps({k: f.get("verdict") for k, f in fits.items()}, indent=2))
    else:
        for label, fit_doc in fits.items():
            click.echo(f"== {label}")
            click.echo(str(Calibration.from_dict(fit_doc, result_json)))  # the verdict first
            click.echo()
    if html_out is not None:
        write_html_report(doc, html_out)
        click.echo(f"wrote {html_out}", err=as_json)
