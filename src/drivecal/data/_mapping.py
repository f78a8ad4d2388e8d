"""A log read through a format file: its channels renamed to drivecal's columns, in SI units, cut into segments.

What comes out is a bench table (:data:`._readers.Columns`) as a drivecal file
holds it, for :func:`._checks.bench_from_frame` to check; what can go wrong on
the way (a channel the log lacks, channels of different lengths or rates, a unit
that contradicts the file's own, windows that do not fit the recording) is one
:class:`DataError` sentence naming the file, the channel and the fix.
"""

from __future__ import annotations

import difflib
from pathlib import Path

import numpy as np

from ..errors import DataError
from ._format_file import BenchFormat
from ._log_units import COLUMN_QUANTITY, MAPPABLE, SI_UNIT, canonical_unit, same_unit, to_si
from ._logs import LogChannel, is_log, read_log
from ._readers import Columns, read_table
from ._values import check_numbers, time_in_seconds
from ._windows import cut_windows


#: The source named in messages about a log read without a format file (its channels named as drivecal's).
_NO_FORMAT = "(no format file)"


def log_channels(path: Path, fmt: BenchFormat | None, content: bytes | None = None,
                 names: list[str] | None = None) -> tuple[dict[str, LogChannel], list[str]]:
    """The channels ``names`` (None: all) of any bench file or log, and the names of every channel in it."""
    if is_log(path):
        return read_log(path, names)
    delimiter, decimal = (fmt.delimiter, fmt.decimal) if fmt is not None else (None, None)
    table = read_table(path, content, delimiter=delimiter, decimal=decimal)
    wanted = list(table) if names is None else [n for n in names if n in table]
    return {n: LogChannel(n, table[n]) for n in wanted}, list(table)


def read_columns(path: Path, fmt: BenchFormat | None, content: bytes | None = None) -> Columns:
    """The bench table of ``path`` (any format), through the format ``fmt`` (None: drivecal's own columns)."""
    if fmt is None and not is_log(path):
        return read_table(path, content)
    if fmt is None:  # a log whose channels carry drivecal's names
        _, everything = read_log(path, [])
        named = {}
        for name in everything:  # an HDF5 dataset '/t', a TDMS channel 'group/t'
            if name.rsplit("/", 1)[-1] in MAPPABLE:
                named.setdefault(name.rsplit("/", 1)[-1], name)
        fmt = BenchFormat(named, source=_NO_FORMAT)
    channels, everything = log_channels(path, fmt, content, list(fmt.columns.values()))
    where = f"{path}"
    check_mapped(where, fmt, channels, everything)
    mapped = {column: channels[name] for column, name in fmt.columns.items()}
    _check_rates_and_lengths(where, mapped)
    columns: Columns = {}
    for column, channel in mapped.items():
        columns[column] = _in_si(where, column, channel, fmt)
    if "t" not in columns:
        own = next((c.time for c in mapped.values() if c.time is not None), None)
        if own is None:
            raise DataError(f"{where}: the log has no time base of its own and {fmt.source} maps no time channel; "
                            "add t = \"<the time channel>\" to [columns].")
        columns["t"] = own
    columns["t"] = time_in_seconds(columns["t"])
    if not fmt.windows:
        if "segment" not in columns:
            given = ("no format file is given" if fmt.source == _NO_FORMAT else
                     f"{fmt.source} has no [[segment]] windows")
            raise DataError(f"{where}: the log has no segment channel and {given}; add the windows to a format file "
                            "(drivecal inspect LOG proposes one) or map [columns] segment.")
        return columns
    check_numbers(columns, where, ["t"])
    return cut_windows(columns, fmt.windows, where, fmt.source)


def check_mapped(where: str, fmt: BenchFormat, channels: dict[str, LogChannel], everything: list[str]) -> None:
    """Every channel the format file maps is in the log, else the sentence naming it and its close matches."""
    for column, name in fmt.columns.items():
        if name not in channels:
            inside = [c for c in everything if _base(c) and (_base(c) in _base(name) or _base(name) in _base(c))]
            close = list(dict.fromkeys(inside + difflib.get_close_matches(name, everything, n=3, cutoff=0.5)))[:3]
            more = ", ..." if len(everything) > 8 else ""
            hint = (f"close matches: {', '.join(repr(c) for c in close)}" if close else
                    f"it has {len(everything)} channels ({', '.join(everything[:8])}{more})")
            raise DataError(f"{where}: channel '{name}' (mapped to '{column}' in {fmt.source}) is not in the log "
                            f"({hint}); correct [columns] {column} in the format file.")


def _base(name: str) -> str:
    """A channel's name without its group or path, in lower case (for close matches)."""
    return name.rsplit("/", 1)[-1].lower()


def _check_rates_and_lengths(where: str, mapped: dict[str, LogChannel]) -> None:
    """All mapped channels at one sample rate and of one length, else the sentence naming two that differ."""
    rated = [(k, c) for k, c in mapped.items() if c.rate is not None]
    for column, channel in rated[1:]:
        first_column, first = rated[0]
        if abs(channel.rate - first.rate) > 1e-6 * first.rate:
            raise DataError(f"{where}: channel '{channel.name}' ({column}) is sampled at {channel.rate:.6g} Hz but "
                            f"'{first.name}' ({first_column}) at {first.rate:.6g} Hz; log every mapped channel at "
                            "one rate (or resample them onto one time base).")
    items = list(mapped.items())
    for column, channel in items[1:]:
        first_column, first = items[0]
        if channel.values.shape[0] != first.values.shape[0]:
            raise DataError(f"{where}: channel '{channel.name}' ({column}) has {channel.values.shape[0]} samples but "
                            f"'{first.name}' ({first_column}) {first.values.shape[0]}; log every mapped channel over "
                            "the same span at one rate (or resample them onto one time base).")


def _in_si(where: str, column: str, channel: LogChannel, fmt: BenchFormat) -> np.ndarray:
    """A mapped channel's values in SI: converted from the format file's unit, which must agree with the file's."""
    if column not in COLUMN_QUANTITY:  # segment, serial: text
        return channel.values
    quantity = COLUMN_QUANTITY[column]
    unit = fmt.units.get(column)
    stated = (channel.unit or "").strip()
    if stated and quantity != "flag":
        said = f"{fmt.source} [units] {column} = '{unit}'" if unit else \
            f"{fmt.source} gives no unit for it ({SI_UNIT[quantity]} assumed)"
        if canonical_unit(stated) is None or not same_unit(stated, unit or SI_UNIT[quantity]):
            raise DataError(f"{where}: channel '{channel.name}' is logged in '{stated}' by the file but {said}; "
                            f"set [units] {column} = \"{stated}\" in the format file (or correct it).")
    if unit is None or channel.values.dtype.kind not in "fiub":
        return channel.values
    return to_si(channel.values, unit)
