"""Bench format files (TOML): how a bench's own log maps onto drivecal's columns, units and segments.

::

    [columns]              # drivecal name = the log's channel name
    t = "time"             # MDF4: channel name; TDMS: "group/channel" or channel; HDF5: dataset path
    i_d = "Id"
    w_m = "n_mech"

    [units]                # the unit each channel is logged in; converted to SI
    i_d = "mA"
    w_m = "rpm"

    [[segment]]            # windows of one continuous recording (when the log has no segment channel)
    name = "locked d-step"
    start = "0 s"          # from the recording's first sample
    stop = "10 ms"         # exclusive: start <= t < stop
    locked = true

    [csv]                  # optional: a CSV export's dialect (detected when left out)
    delimiter = ";"
    decimal = ","

A key drivecal does not know is refused in one sentence naming the file and the
known keys (:func:`load_format`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..errors import DataError
from .._units import read_toml
from ._log_units import check_unit


@dataclasses.dataclass(frozen=True)
class Window:
    """A segment of one continuous recording: samples with ``start <= t < stop`` (s, from its first sample)."""

    name: str
    start: float
    stop: float
    locked: bool | None = None


@dataclasses.dataclass(frozen=True)
class BenchFormat:
    """A loaded format file.

    Attributes:
        columns: drivecal column -> the log's channel name.
        units: drivecal column -> the unit it is logged in (canonical name, see ``LOG_UNITS``).
        windows: the segments as time windows (empty: the log has a segment channel).
        delimiter, decimal: a CSV export's dialect (None: detected).
        source: the format file's path (for messages).
    """

    columns: dict[str, str]
    units: dict[str, str] = dataclasses.field(default_factory=dict)
    windows: tuple[Window, ...] = ()
    delimiter: str | None = None
    decimal: str | None = None
    source: str = "format"


def load_format(path: str | Path | BenchFormat | None) -> BenchFormat | None:
    """Read and check a format file (or pass a loaded one, or None, through).

    Raises:
        DataError: one sentence naming the file, the key and the fix.
    """
    if path is None or isinstance(path, BenchFormat):
        return path
    raw = read_toml(path)
    return format_from_dict(raw, str(path))


def format_from_dict(raw: dict, source: str = "format") -> BenchFormat:
    """A format file's table (as TOML gives it) checked into a :class:`BenchFormat`."""
    from ._format_spec import format_spec  # pydantic's schema: only where a format file is read

    spec = format_spec(raw, source)
    columns = {k: v for k, v in spec.columns.model_dump().items() if v is not None}
    units = {k: check_unit(k, v, f"{source}: [units]") for k, v in spec.units.model_dump().items() if v is not None}
    windows = tuple(Window(w.name.strip(), w.start, w.stop, w.locked) for w in spec.segment)
    for w in windows:
        if not w.name:
            raise DataError(f"{source}: a [[segment]] window has an empty name; name every window.")
        if not w.stop > w.start:
            raise DataError(f"{source}: window '{w.name}' stops at {w.stop:.9g} s, not after its start "
                            f"{w.start:.9g} s; give stop > start.")
    names = [w.name for w in windows]
    again = next((n for n in names if names.count(n) > 1), None)
    if again is not None:
        raise DataError(f"{source}: two [[segment]] windows are named '{again}'; give each window a name of its own.")
    ordered = sorted(windows, key=lambda w: w.start)
    for a, b in zip(ordered, ordered[1:]):
        if b.start < a.stop:
            raise DataError(f"{source}: windows '{a.name}' ({a.start:.9g} s to {a.stop:.9g} s) and '{b.name}' "
                            f"({b.start:.9g} s to {b.stop:.9g} s) overlap; move one so that each sample belongs "
                            "to one window.")
    if windows and "segment" in columns:
        raise DataError(f"{source}: both a segment channel ([columns] segment) and [[segment]] windows are given; "
                        "keep one of them.")
    return BenchFormat(columns, units, windows, spec.csv.delimiter, spec.csv.decimal, source)
