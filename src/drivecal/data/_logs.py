"""Reading bench logs as they come off a bench: ASAM MDF4 (asammdf), NI TDMS (npTDMS) and HDF5 (h5py).

Each reader gives the log's channels (:class:`LogChannel`: the values, the unit
the file states, and the channel's own time base where the file has one), by
the names a format file uses: MDF4 channel names, TDMS ``"group/channel"`` (or
the channel's name alone where it is unique), HDF5 dataset paths (or a
dataset's name alone where it is unique). The libraries are imported inside the
readers: ``drivecal --help`` loads none of them.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataError

#: Log formats by suffix, with what writes them.
LOG_FORMATS: dict[str, str] = {".mf4": "MDF4", ".mdf": "MDF4", ".tdms": "TDMS", ".h5": "HDF5", ".hdf5": "HDF5"}


@dataclasses.dataclass(frozen=True)
class LogChannel:
    """One channel of a log.

    Attributes:
        name: its name in the log (as a format file names it).
        values: the samples, 1-D (numbers, or objects for text).
        unit: the unit the file states for it ("" or None: none stated).
        time: the channel's own time base (s, from the file's clock), or None.
        rate: its sample rate (Hz) where the file states or implies one, or None.
    """

    name: str
    values: np.ndarray
    unit: str | None = None
    time: np.ndarray | None = None
    rate: float | None = None


def is_log(path: Path) -> bool:
    return path.suffix.lower() in LOG_FORMATS


def read_log(path: Path, names: list[str] | None = None) -> tuple[dict[str, LogChannel], list[str]]:
    """The channels ``names`` of a log (all of them for None) and the names of every channel it holds.

    A name the log lacks is left out of the first (the caller names it, with the close matches).
    """
    suffix = path.suffix.lower()
    if not path.is_file():
        raise DataError(f"{path}: no such file; check the path.")
    reader = {"MDF4": _read_mdf, "TDMS": _read_tdms, "HDF5": _read_hdf5}[LOG_FORMATS[suffix]]
    try:
        return reader(path, names)
    except DataError:
        raise
    except Exception as exc:  # a library's own error: which file, what it said, on one line
        said = " ".join(str(exc).split())[:200] or type(exc).__name__
        kind = LOG_FORMATS[suffix]
        raise DataError(f"{path}: cannot be read as an {kind} log ({said}); check that the file is complete and "
                        f"an {kind} file (export it again).") from None


def _text(values: np.ndarray) -> np.ndarray:
    """Bytes or numpy text as an object array of str; anything else unchanged."""
    if values.dtype.kind in "SUO" and values.size and isinstance(values.flat[0], (bytes, np.bytes_, str)):
        return np.array([v.decode("utf-8", "replace").strip("\x00 ") if isinstance(v, (bytes, np.bytes_))
                         else str(v) for v in values], dtype=object)
    return values


def _read_mdf(path: Path, names: list[str] | None) -> tuple[dict[str, LogChannel], list[str]]:
    from asammdf import MDF

    with MDF(str(path)) as mdf:
        db = mdf.channels_db
        masters = {g: mdf.masters_db.get(g) for g in range(len(mdf.groups))}
        everything = list(db)
        wanted = everything if names is None else [n for n in names if n in db]

        def is_master(group: int, index: int) -> bool:
            return masters.get(group) == index

        chosen: dict[str, tuple[int, int]] = {}
        # Data channels first: a master channel ('time') in many groups is then taken from theirs.
        for name in sorted(wanted, key=lambda n: all(is_master(g, i) for g, i in db[n])):
            places = list(db[name])
            data = [p for p in places if not is_master(*p)]
            if data and len(data) > 1 and names is not None:
                raise DataError(f"{path}: channel '{name}' appears in {len(data)} channel groups; rename it in "
                                "the bench's logger so that each mapped channel has one name.")
            if data:
                chosen[name] = data[0]
                continue
            groups = [g for g, _ in chosen.values()]
            chosen[name] = next((p for p in places if p[0] in groups), places[0])
        out = {}
        for name, (group, index) in chosen.items():
            sig = mdf.get(name, group=group, index=index, raw=False)
            values = _text(np.asarray(sig.samples))
            time = np.asarray(sig.timestamps, dtype=float)
            out[name] = LogChannel(name, values, str(sig.unit or "") or None, time, _rate_of(time))
    return out, everything


def _read_tdms(path: Path, names: list[str] | None) -> tuple[dict[str, LogChannel], list[str]]:
    from nptdms import TdmsFile

    tdms = TdmsFile.read(str(path))
    channels = {f"{g.name}/{c.name}": c for g in tdms.groups() for c in g.channels()}
    by_name: dict[str, list[str]] = {}
    for key, c in channels.items():
        by_name.setdefault(c.name, []).append(key)
    everything = list(channels)
    out = {}
    for name in (everything if names is None else names):
        key = name.strip("/") if name.strip("/") in channels else None
        if key is None and name in by_name:
            if len(by_name[name]) > 1:
                raise DataError(f"{path}: channel '{name}' is in {len(by_name[name])} groups "
                                f"({', '.join(by_name[name])}); name it as \"group/channel\" in the format file.")
            key = by_name[name][0]
        if key is None:
            continue
        c = channels[key]
        props = c.properties
        values = _text(np.asarray(c[:]))
        increment = props.get("wf_increment")
        time = rate = None
        if increment:
            time = float(props.get("wf_start_offset", 0.0)) + float(increment) * np.arange(values.shape[0])
            rate = 1.0 / float(increment)
        unit = props.get("unit_string")
        out[name] = LogChannel(name, values, str(unit) if unit else None, time, rate)
    return out, everything


def _read_hdf5(path: Path, names: list[str] | None) -> tuple[dict[str, LogChannel], list[str]]:
    import h5py

    with h5py.File(path, "r") as f:
        datasets: dict[str, Any] = {}

        def collect(key: str, obj: Any) -> None:  # a value returned would stop the walk
            if isinstance(obj, h5py.Dataset):
                datasets["/" + key] = obj

        f.visititems(collect)
        by_name: dict[str, list[str]] = {}
        for key in datasets:
            by_name.setdefault(key.rsplit("/", 1)[-1], []).append(key)
        everything = list(datasets)
        out = {}
        for name in (everything if names is None else names):
            key = "/" + name.strip("/")
            if key not in datasets and name in by_name:
                if len(by_name[name]) > 1:
                    raise DataError(f"{path}: dataset '{name}' is at {len(by_name[name])} paths "
                                    f"({', '.join(by_name[name])}); give its full path in the format file.")
                key = by_name[name][0]
            if key not in datasets:
                continue
            ds = datasets[key]
            values = ds.asstr()[()] if h5py.check_string_dtype(ds.dtype) else ds[()]
            values = _text(np.atleast_1d(np.asarray(values)))
            if values.ndim != 1:
                shape = " x ".join(str(n) for n in values.shape)
                raise DataError(f"{path}: dataset '{key}' is a {shape} array; store each channel as a 1-D dataset "
                                "of its own.")
            unit = next((ds.attrs[a] for a in ("unit", "units", "Unit") if a in ds.attrs), None)
            unit = unit.decode() if isinstance(unit, bytes) else unit
            rate = next((float(ds.attrs[a]) for a in ("sample_rate", "rate") if a in ds.attrs), None)
            out[name] = LogChannel(name, values, str(unit) if unit else None, None, rate)
    return out, everything


def _rate_of(time: np.ndarray | None) -> float | None:
    """The sample rate (Hz) of a time base (s): one over its median step; None for fewer than two samples."""
    if time is None or time.shape[0] < 2:
        return None
    step = float(np.median(np.diff(time)))
    return 1.0 / step if step > 0 else None
