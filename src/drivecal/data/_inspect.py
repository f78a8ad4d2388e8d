"""What a bench log holds, and a format file proposed for it (``drivecal inspect``).

The channels are listed with their units, rates and lengths; drivecal's columns
are matched to them by the names benches commonly use (``Id``, ``Iq_meas``,
``Ud_ref``, ``n_mech``, ...) unless a format file says; the segment windows are
proposed where a voltage is commanded between rests, locked unless the measured
speed shows the rotor turning (:func:`._windows.propose_windows`).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from ._format_file import BenchFormat, load_format
from ._log_units import COLUMN_QUANTITY, SI_UNIT, canonical_unit, to_si
from ._logs import LogChannel
from ._mapping import check_mapped, log_channels
from ._speed import speed_resolution
from ._values import time_in_seconds
from ._windows import Proposal, propose_windows

#: The names benches give drivecal's columns (compared in lower case, without '_', '-', ' ' or '.').
_ALIASES: dict[str, tuple[str, ...]] = {
    "segment": ("segment", "seg", "step", "segmentname"),
    "locked": ("locked", "rotorlocked", "lock", "islocked"),
    "t": ("t", "time", "zeit", "timestamp", "times"),
    "v_d": ("vd", "ud", "vdref", "udref", "vdcmd", "udcmd", "udset", "vdset", "udsoll"),
    "v_q": ("vq", "uq", "vqref", "uqref", "vqcmd", "uqcmd", "uqset", "vqset", "uqsoll"),
    "i_d": ("id", "idmeas", "idact", "idist", "imeasd"),
    "i_q": ("iq", "iqmeas", "iqact", "iqist", "imeasq"),
    "w_m": ("wm", "nmech", "speed", "n", "omegam", "wmech", "rpm", "nact", "nist", "speedmech"),
    "theta_e": ("thetae", "phiel", "thetael", "angleel", "anglee"),
    "theta_m": ("thetam", "phimech", "thetamech", "anglemech", "angle"),
    "temperature": ("temperature", "temp", "twinding", "twdg", "tempwinding"),
    "i_a": ("ia", "iu", "iphasea"), "i_b": ("ib", "iv", "iphaseb"), "i_c": ("ic", "iw", "iphasec"),
    "v_a": ("va", "ua", "uu", "vu"), "v_b": ("vb", "ub", "uv"), "v_c": ("vc", "uc", "uw"),
}


def _key(name: str) -> str:
    return re.sub(r"[\s_.\-\[\]()]", "", name.rsplit("/", 1)[-1]).lower()


@dataclasses.dataclass(frozen=True)
class ChannelInfo:
    """One channel: name, the unit the file states ("" if none), sample rate (Hz, NaN if unknown), samples,
    and the drivecal column it is taken for ("" if none)."""

    name: str
    unit: str
    rate: float
    length: int
    column: str


@dataclasses.dataclass(frozen=True)
class Inspection:
    """A log's channels, the mapping used, the proposed windows and the proposed format file's text; ``speed``:
    the steps of the speed channel where it is quantised (``SpeedResolution.describe``), else empty."""

    path: str
    channels: tuple[ChannelInfo, ...]
    columns: dict[str, str]
    units: dict[str, str]
    windows: tuple[Proposal, ...]
    format_text: str
    speed: str = ""


def guess_columns(names: list[str]) -> dict[str, str]:
    """drivecal column -> the channel taken for it, by the names benches commonly use (each channel once)."""
    out: dict[str, str] = {}
    taken: set[str] = set()
    for column, aliases in _ALIASES.items():
        found = next((n for a in aliases for n in names if _key(n) == a and n not in taken), None)
        if found is not None:
            out[column] = found
            taken.add(found)
    return out


def inspect_log(path: str | Path, format: str | Path | BenchFormat | None = None) -> Inspection:
    """List the channels of ``path`` and propose a format file for it (see the module's docstring)."""
    path = Path(path)
    fmt = load_format(format)
    channels, everything = log_channels(path, fmt)
    if fmt is not None:
        check_mapped(str(path), fmt, channels, everything)
    columns = dict(fmt.columns) if fmt is not None else guess_columns(everything)
    units = dict(fmt.units) if fmt is not None else {}
    if fmt is None:
        for column, name in columns.items():
            stated = channels[name].unit
            if column in COLUMN_QUANTITY and stated and canonical_unit(stated) is not None:
                units[column] = canonical_unit(stated)
    by_channel = {name: column for column, name in columns.items()}
    time_of = _time(channels, columns, units)
    infos = []
    for name in everything:
        c = channels[name]
        rate = c.rate if c.rate is not None else _rate(time_of if time_of is not None and
                                                         time_of.shape[0] == c.values.shape[0] else None)
        infos.append(ChannelInfo(name, c.unit or "", rate, int(c.values.shape[0]), by_channel.get(name, "")))
    proposals: list[Proposal] = []
    if (fmt is None or not fmt.windows) and "segment" not in columns and time_of is not None:
        def si(column):
            name = columns.get(column)
            if name is None or channels[name].values.shape != time_of.shape:
                return None
            values = channels[name].values
            return to_si(values, units[column]) if column in units else values
        proposals = propose_windows(time_of, si("v_d"), si("v_q"), si("w_m"))
    windows = proposals if proposals else []
    text = _format_text(path, columns, units, windows, fmt)
    speed = ""
    if "w_m" in columns and time_of is not None and channels[columns["w_m"]].values.shape == time_of.shape:
        w = channels[columns["w_m"]].values
        found = speed_resolution([to_si(w, units["w_m"]) if "w_m" in units else w], _rate(time_of))
        speed = found.describe() if found.step is not None else ""
    return Inspection(str(path), tuple(infos), columns, units, tuple(windows), text, speed)


def _time(channels: dict[str, LogChannel], columns: dict[str, str], units: dict[str, str]) -> np.ndarray | None:
    """The recording's clock (s): the time channel taken for ``t``, or a channel's own time base."""
    if "t" in columns and columns["t"] in channels:
        values = channels[columns["t"]].values
        if values.dtype.kind in "mM":
            return np.asarray(time_in_seconds(values), dtype=float)
        if values.dtype.kind in "fiu":
            return np.asarray(to_si(values, units["t"]) if "t" in units else values, dtype=float)
    return next((c.time for c in channels.values() if c.time is not None), None)


def _rate(time: np.ndarray | None) -> float:
    if time is None or time.shape[0] < 2:
        return float("nan")
    step = float(np.median(np.diff(time)))
    return 1.0 / step if step > 0 else float("nan")


def _ms(seconds: float) -> str:
    return f'"{seconds * 1e3:.10g} ms"'


def _format_text(path: Path, columns: dict[str, str], units: dict[str, str], windows: list[Proposal],
                 fmt: BenchFormat | None) -> str:
    lines = [f"# drivecal format file for {path.name}, proposed by `drivecal inspect`: check it, then",
             f"# drivecal fit {path.name} --format THIS.toml", "", "[columns]  # drivecal name = the log's channel"]
    lines += [f'{column} = "{name}"' for column, name in columns.items()]
    missing = [c for c in ("t", "v_d", "v_q", "i_d", "i_q") if c not in columns]
    lines += [f'# {c} = "?"  (no channel found: name it)' for c in missing if c != "t"]
    lines += ["", "[units]  # the unit each channel is logged in (converted to SI)"]
    for column in columns:
        if column in units:
            lines.append(f'{column} = "{units[column]}"')
        elif column in COLUMN_QUANTITY and COLUMN_QUANTITY[column] != "flag":
            lines.append(f'# {column} = "{SI_UNIT[COLUMN_QUANTITY[column]]}"  (the file states no unit: check)')
    if fmt is not None and fmt.windows:
        windows_text = [("", w.name, w.start, w.stop, w.locked) for w in fmt.windows]
    else:
        windows_text = [("", p.window.name, p.window.start, p.window.stop, p.window.locked) for p in windows]
    if windows_text:
        lines += ["", "# segments: windows of the recording, start <= t < stop from its first sample"]
    for _, name, start, stop, locked in windows_text:
        lines += ["", "[[segment]]", f'name = "{name}"', f"start = {_ms(start)}", f"stop = {_ms(stop)}"]
        lines.append(f"locked = {str(locked).lower()}" if locked is not None else
                     "# locked = true  (no speed channel to tell: say whether the rotor is locked)")
    return "\n".join(lines) + "\n"
