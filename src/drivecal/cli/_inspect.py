"""``drivecal inspect``: what a bench log holds, and a format file proposed for it."""

from __future__ import annotations

import click

from ._common import _check_out, _console, _format_option


@click.command("inspect")
@click.argument("log_path", metavar="LOG", type=click.Path(dir_okay=False))
@_format_option
@click.option("--out", "out_path", type=click.Path(), default=None, metavar="FORMAT.toml",
              help="Write the proposed format file there (atomically) instead of printing it.")
def inspect(log_path, format_path, out_path):
    """List a bench log's channels and propose a format file: channel names, units, segment windows.

    \b
    LOG is an MDF4 (.mf4, .mdf), TDMS (.tdms), HDF5 (.h5, .hdf5), CSV
    (any delimiter and decimal mark), Parquet or MAT file. Each channel is
    listed with the unit the file states, its sample rate and its length.
    drivecal's columns are matched to the channels by the names benches
    commonly use (Id, Iq_meas, Ud_ref, n_mech, ...), or as --format says;
    the segments of a continuous recording are proposed as windows around
    each stretch where a voltage is commanded between rests, locked unless
    the measured speed shows the rotor turning. Edit the proposal, then
    `drivecal fit LOG --format FORMAT.toml`. Without --out the format file
    is printed on stdout and the channel table on stderr.

    Exit status: 0, or 2 for bad input (one sentence on stderr; nothing written).
    """
    if out_path is not None:
        _check_out(out_path, "--out", example="bench_format.toml")
    from rich.markup import escape
    from rich.table import Table

    from .._io import atomic_path
    from ..data import inspect_log

    found = inspect_log(log_path, format_path)
    console = _console(out_path is None)  # the format file alone on stdout: `inspect LOG > FORMAT.toml`
    table = Table(title=f"{escape(found.path)}: {len(found.channels)} channels", title_justify="left")
    for col in ("channel", "unit", "rate [Hz]", "samples", "drivecal column"):
        table.add_column(col, justify="right" if col in ("rate [Hz]", "samples") else "left", no_wrap=True)
    for c in found.channels:
        rate = "-" if c.rate != c.rate else f"{c.rate:.6g}"
        table.add_row(escape(c.name), escape(c.unit) or "-", rate, str(c.length), c.column or "-")
    console.print(table)
    if found.windows:
        console.print(f"proposed {len(found.windows)} segment windows: "
                      + ", ".join(f"{escape(p.window.name)} ({p.last - p.first + 1} samples)" for p in found.windows))
    if found.speed:
        console.print(f"speed channel {escape(found.columns['w_m'])}: {escape(found.speed)}; `drivecal fit` weighs it "
                      "by that (a second measured output where it is too coarse to be an exact input)")
    if out_path is None:
        click.echo(found.format_text, nl=False)
        return 0
    with atomic_path(out_path) as tmp:
        tmp.write_text(found.format_text)
    console.print(f"wrote {escape(str(out_path))}: check it, then `drivecal fit {escape(str(log_path))} --format "
                  f"{escape(str(out_path))}`")
    return 0
