"""The checks every bench file passes, written once for one file and for many.

A bench table's layout (its columns and its segment column) is checked first:
columns present, every value a number, segments named and each one block of
rows. What is left, the per-segment checks (clock, ``locked`` flag, winding
temperature, one sample rate, plausible current magnitude), is a set of
predicates vectorised over a stack of tables laid out alike (leading axis, one
table per row): :func:`bench_from_frame` applies them to a stack of one file,
:func:`benches_from_frames` to thousands at once. A failing table's one
:class:`DataError` sentence, naming the file, the column and the fix, is written
in one place (:meth:`_Checked.refusal`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from collections.abc import Hashable
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError
from .._stats import fast_median, noise_level
from ._bench_data import BenchData, SegmentData
from ._phase import check_pole_pairs, phase_to_dq
from ._format_file import BenchFormat, load_format
from ._mapping import read_columns
from ._readers import Columns, columns_of
from ._values import check_numbers

if TYPE_CHECKING:
    import pandas as pd

#: The dq columns of a bench file, with what each holds.
DQ_COLUMNS: dict[str, str] = {
    "segment": "the segment name on every row",
    "locked": "1 where the rotor is locked, 0 where it turns freely",
    "t": "the sample time in seconds",
    "v_d": "the applied d-axis voltage in V",
    "v_q": "the applied q-axis voltage in V",
    "i_d": "the measured d-axis current in A",
    "i_q": "the measured q-axis current in A",
}
#: The numeric columns of a dq bench file the checks read, in the order they are checked (those present).
_NUMERIC = ("locked", "t", "v_d", "v_q", "i_d", "i_q", "w_m", "theta_e", "inverter")
#: Samples at a segment's start from which the at-rest check estimates the sensor noise.
AT_REST_NOISE_SAMPLES = 256


def load_bench(path: str | Path, *, pole_pairs: float = 4.0, nominal_R: float | None = None,
               format: str | Path | BenchFormat | None = None) -> BenchData:
    """Read and check a bench file or log; see :func:`bench_from_frame`.

    Args:
        path: a bench table (.csv in any dialect, .parquet, .mat) or a bench log (.mf4/.mdf, .tdms,
            .h5/.hdf5).
        format: a format file (TOML path, or a loaded :class:`BenchFormat`) mapping the log's channels,
            units and segment windows onto drivecal's columns; None: the file has drivecal's columns.
    """
    path = Path(path)
    columns = read_columns(path, load_format(format))
    return bench_from_frame(columns, str(path), pole_pairs=pole_pairs, nominal_R=nominal_R)


def bench_from_frame(
    frame: pd.DataFrame | Columns,
    source: str = "bench data",
    *,
    pole_pairs: float = 4.0,
    nominal_R: float | None = None,
) -> BenchData:
    """Check a table of bench samples and split it into segments.

    Args:
        frame: one row per sample with the bench-file columns (dq or phase): a
            DataFrame, or a mapping of column name to equal-length arrays (as
            :func:`read_table` returns).
        source: the file name used in messages.
        pole_pairs: for a ``theta_m`` angle column (-).
        nominal_R: nominal resistance (ohm) for the plausibility check of the
            current magnitude (mA written as A); skipped when None.

    Raises:
        DataError: one sentence naming ``source``, the column and the fix.
    """
    frame = columns_of(frame, source)
    if next((v.shape[0] for v in frame.values()), 0) == 0:
        raise DataError(f"{source}: the file has no samples; record at least one segment.")
    if "i_d" not in frame and "i_a" in frame:
        frame = phase_to_dq(frame, source, pole_pairs)  # checks the pole pairs on the phase columns
    else:
        check_pole_pairs(frame, source, pole_pairs)
    for col, meaning in DQ_COLUMNS.items():
        if col not in frame:
            hint = " (or phase columns i_a, i_b, v_a, v_b with theta_e)" if col in ("i_d", "i_q", "v_d", "v_q") else ""
            raise DataError(f"{source}: missing column '{col}' ({meaning}){hint}; add it to the file.")
    numeric = [c for c in _NUMERIC if c in frame]
    check_numbers(frame, source, numeric)
    names, sizes = _segments(frame["segment"], source)
    checked = _check([frame], names, sizes, nominal_R, finite_known=True)
    if not checked.ok[0]:
        raise checked.refusal(0, frame, source)
    return checked.bench(0, source)


def benches_from_frames(
    frames: list[pd.DataFrame | Columns],
    sources: list[str],
    *,
    pole_pairs: float = 4.0,
    nominal_R: float | None = None,
) -> list[BenchData | DataError]:
    """:func:`bench_from_frame` of many tables: per table, in order, its BenchData or the DataError it raises.

    A table with the columns, length and segment column of an earlier valid one (dq columns of
    numbers) shares its layout: the per-segment checks run on all such tables at once, vectorised
    across them (~0.1 ms a table instead of ~0.7 ms, which a fleet pays per motor), and a table they
    reject gets the same one sentence as a file checked alone.
    """
    out: list[BenchData | DataError | None] = [None] * len(frames)
    tables: list[Columns | None] = [None] * len(frames)
    groups: list[tuple[Columns, BenchData, list[int]]] = []  # template, its bench, the tables like it
    for i, (frame, source) in enumerate(zip(frames, sources)):
        try:
            tables[i] = columns_of(frame, source)
        except DataError as exc:
            out[i] = exc
            continue
        group = next((g for g in groups if _same_layout(tables[i], g[0])), None)
        if group is not None:
            group[2].append(i)
            continue
        try:
            out[i] = bench_from_frame(tables[i], source, pole_pairs=pole_pairs, nominal_R=nominal_R)
        except DataError as exc:
            out[i] = exc
            continue
        if _checks_vectorise(tables[i]):
            groups.append((tables[i], out[i], []))
    for _, template, members in groups:
        if not members:
            continue
        names = [seg.name for seg in template.segments]
        sizes = [seg.num_samples for seg in template.segments]
        checked = _check([tables[i] for i in members], names, sizes, nominal_R, finite_known=False)
        for b, (i, ok) in enumerate(zip(members, checked.ok.tolist())):
            out[i] = checked.bench(b, sources[i]) if ok else checked.refusal(b, tables[i], sources[i])
            if ok:
                try:
                    check_pole_pairs(tables[i], sources[i], pole_pairs)
                except DataError as exc:
                    out[i] = exc
    return out  # type: ignore[return-value]


# --------------------------------------------------------------------------- the layout of a table


def _segments(segment: np.ndarray, source: str) -> tuple[list[str], list[int]]:
    """The segment names (stripped) in order of appearance and their numbers of rows; each a block of rows."""
    # Segment names by code (a handful of distinct names over thousands of rows: strip those, not every row).
    try:
        codes, labels = _factorize(segment)
    except TypeError:  # unhashable names: lists or arrays where text belongs
        row = next(k for k, x in enumerate(segment) if not isinstance(x, Hashable))
        raise DataError(f"{source}: column 'segment' holds lists ({str(segment[row])[:40]} in data row {row + 1}), "
                        "not names; give every row its segment's name as text.") from None
    labels = [str(x).strip() for x in labels]
    blank = (codes < 0) | np.isin(codes, [i for i, x in enumerate(labels) if not x])
    if blank.any():
        raise DataError(
            f"{source}: column 'segment' is empty in data row {int(np.flatnonzero(blank)[0]) + 1}; "
            "name the segment of every row."
        )
    # Names equal once stripped are one segment.
    distinct = sorted(set(labels))
    codes = np.asarray([distinct.index(x) for x in labels])[codes]
    # Segments in order of appearance; each must be one block of consecutive rows.
    boundaries = np.flatnonzero(codes[1:] != codes[:-1]) + 1
    starts = np.concatenate([[0], boundaries])
    stops = np.concatenate([boundaries, [codes.shape[0]]])
    order = [distinct[codes[i]] for i in starts]
    if len(set(order)) != len(order):
        again = next(n for n in order if order.count(n) > 1)
        raise DataError(
            f"{source}: segment '{again}' appears in two separate blocks of rows; keep each segment's rows together "
            "or give the blocks different names."
        )
    return order, (stops - starts).tolist()


def _factorize(values: np.ndarray) -> tuple[np.ndarray, list]:
    """``pandas.factorize(values)`` for a column of blocks: codes (-1 where missing: None or NaN) and the
    distinct values in order of appearance; TypeError for an unhashable value.

    The values are compared per row, hashed per block of equal rows (a bench file has a handful): numpy and
    no pandas, whose import a single fit would pay only for this (~0.3 s)."""
    values = np.asarray(values)
    try:
        differs = np.asarray(values[1:] != values[:-1], dtype=bool)
    except ValueError:  # arrays among the values (compared elementwise): unhashable
        raise TypeError("unhashable values") from None
    if differs.shape != (max(values.size - 1, 0),):
        raise TypeError("values that do not compare one to one")
    starts = np.concatenate([[0], np.flatnonzero(differs) + 1]) if values.size else np.zeros(0, int)
    index: dict = {}
    block_codes = np.empty(starts.size, dtype=np.intp)
    for k, i in enumerate(starts.tolist()):
        x = values[i]
        missing = x is None or (isinstance(x, (float, np.floating)) and x != x)
        block_codes[k] = -1 if missing else index.setdefault(x, len(index))
    codes = np.repeat(block_codes, np.diff(np.concatenate([starts, [values.size]])))
    return codes, list(index)


def _checks_vectorise(columns: Columns) -> bool:
    """A dq table whose numeric columns hold numbers: tables laid out as it are checked together."""
    if "i_a" in columns:
        return False
    return all(columns[c].dtype.kind in "fiub" for c in _NUMERIC if c in columns)


def _same_layout(columns: Columns, template: Columns) -> bool:
    """The same columns (names and types), length and segment column as ``template``."""
    return (
        columns.keys() == template.keys()
        and all(columns[c].dtype == template[c].dtype and columns[c].shape == template[c].shape for c in columns)
        and np.array_equal(columns["segment"], template["segment"])
    )


# --------------------------------------------------------------------------- the checks of segments
# Each a predicate over the samples (last axis) of a stack of segments (leading axes): one file is a
# stack of one.


def _clock(t: np.ndarray) -> tuple[np.ndarray, Any, Any, Any]:
    """A segment's sample clock ``t`` (s): the steps (s), the typical step (median, s), whether every
    step is positive, and whether every step is within 1e-3 of the typical one."""
    dt = np.diff(t, axis=-1)
    period = fast_median(dt, axis=-1)
    with np.errstate(invalid="ignore"):
        increasing = dt.min(axis=-1) > 0
        uniform = np.max(np.abs(dt - np.expand_dims(period, -1)), axis=-1) <= 1e-3 * period
    return dt, period, increasing, uniform


def _locked_flag(lock: np.ndarray) -> tuple[Any, Any]:
    """Whether a segment's ``locked`` column is one value, 0 or 1, throughout; and whether that is 1."""
    first = lock[..., 0]
    return (lock.min(axis=-1) == lock.max(axis=-1)) & ((first == 0.0) | (first == 1.0)), first == 1.0


def _starts_at_rest(currents: np.ndarray, w_m: np.ndarray | None, locked: Any) -> Any:
    """Whether a segment starts from rest: its first currents ``(..., N, 2)`` A (and, unless ``locked``,
    speed ``(..., N)`` rad/s) within five noise levels of zero.

    The noise level comes from the segment's first :data:`AT_REST_NOISE_SAMPLES` samples: a MAD of
    ~250 second differences places the threshold to within ~10 %, and the medians over a whole
    1000-sample spin-up cost ~0.1 ms a file, which a fleet pays per motor.
    """
    window = slice(0, AT_REST_NOISE_SAMPLES)
    noise = np.maximum(np.max(noise_level(currents[..., window, :], axis=-2), axis=-1), 1e-6)
    at_rest = np.all(np.abs(currents[..., 0, :]) <= 5.0 * np.expand_dims(noise, -1), axis=-1)
    if w_m is not None and not np.all(locked):  # a locked rotor's speed is not looked at
        still = np.abs(w_m[..., 0]) <= np.maximum(5.0 * noise_level(w_m[..., window], axis=-1), 1e-6)
        at_rest = at_rest & (locked | still)
    return at_rest


def _continues(previous: _Segment, previous_last: np.ndarray, first: np.ndarray, seg: _Segment) -> np.ndarray:
    """Per table, whether ``seg`` continues ``previous``: its first sample (``first``, s) comes one sample
    period after the previous segment's last (``previous_last``, s) on one time axis, the rotor is in the
    same condition (locked or free), and the segment does not start from rest. The model then carries
    its state (currents, speed, angle) and the delayed command over, instead of restarting from the
    noisy first sample; a segment at rest after a contiguous one starts from rest. A free segment
    without a speed column that follows a free one on the same clock continues it whatever its first
    currents: a steady run carries only the friction's few mA, which look like rest, but a free rotor
    does not stop between two samples."""
    contiguous = np.abs(first - previous_last - seg.period) <= 0.25 * seg.period
    locked = np.asarray(seg.locked)
    same = np.asarray(previous.locked) == locked
    turning_unseen = ~locked if seg.w_m is None else np.zeros_like(locked)
    return contiguous & same & (~np.asarray(seg.at_rest) | turning_unseen)


def _temperature(values: np.ndarray) -> tuple[Any, Any]:
    """A segment's ``temperature`` (degC, NaN where blank): whether it is not recorded (all blank), and
    whether it is recorded right (all blank or every value finite)."""
    blank = np.all(np.isnan(values), axis=-1)
    return blank, blank | np.all(np.isfinite(values), axis=-1)


def _rate_differs(rate: Any, first: Any) -> Any:
    """A segment's sample rate (Hz) differs from the first segment's."""
    return np.abs(rate - first) > 1e-6 * first


def _implausible_currents(v_max: Any, i_max: Any, nominal_R: float) -> Any:
    """Currents (peak ``i_max``, A) far above anything the voltages (peak ``v_max``, V) could drive."""
    # |i| cannot settle above max|v|/R; a factor 10 leaves room for a 50 % wrong R and transients.
    return (v_max > 0) & (i_max > 10.0 * v_max / nominal_R)


@dataclasses.dataclass
class _Segment:
    """The checks of one segment over a stack of B tables: each array has the tables on axis 0."""

    name: str
    lo: int
    hi: int
    clock: np.ndarray | None = None  # (B, n) the sample instants from the segment start (s)
    voltages: np.ndarray | None = None  # (B, n, 2) V
    currents: np.ndarray | None = None  # (B, n, 2) A
    w_m: np.ndarray | None = None  # (B, n) rad/s, or None
    theta_e: np.ndarray | None = None  # (B, n) rad, or None
    temperature: np.ndarray | None = None  # (B, n) degC (NaN where blank), or None
    dt: np.ndarray | None = None  # (B, n - 1) the steps (s)
    period: np.ndarray | None = None  # (B,) the typical step (s)
    increasing: np.ndarray | None = None
    uniform: np.ndarray | None = None
    lock_ok: np.ndarray | None = None
    locked: np.ndarray | None = None
    at_rest: np.ndarray | None = None
    no_temperature: np.ndarray | None = None
    temperature_ok: np.ndarray | None = None
    inverter_ok: np.ndarray | None = None  # (B,) the 'inverter' column is one value, 0 or 1, over the segment
    inverter_off: Any = False  # per table: the inverter was off (switches open, no current)
    continues: Any = False  # per table: the segment continues the previous one (see _continues)


def _pick(flags: Any, b: int) -> bool:
    """Table ``b``'s flag of a per-table list, or the flag itself (False: not recorded)."""
    return bool(flags[b]) if isinstance(flags, list) else bool(flags)


@dataclasses.dataclass
class _Checked:
    """Tables laid out alike (one segment column), checked together; ``ok[b]``: table b passed them all."""

    numeric: list[str]
    column: dict[str, np.ndarray]  # the numeric columns, (B, N) floats
    currents: np.ndarray  # (B, N, 2) A
    voltages: np.ndarray  # (B, N, 2) V
    finite: np.ndarray | None  # (B,) every numeric value finite; None: known to be
    segments: list[_Segment]
    rates: list[list[float]]  # per segment, per table (Hz)
    nominal_R: float | None  # ohm, for the current magnitude check; None: not asked for
    ok: np.ndarray  # (B,)

    def bench(self, b: int, source: str) -> BenchData:
        """Table ``b`` (it passed) as a BenchData."""
        return BenchData(tuple(
            SegmentData(seg.name, seg.locked[b], seg.clock[b], seg.voltages[b], seg.currents[b],
                        None if seg.w_m is None else seg.w_m[b], seg.at_rest[b],
                        None if seg.temperature is None or seg.no_temperature[b] else seg.temperature[b],
                        None if seg.theta_e is None else seg.theta_e[b],
                        continues=_pick(seg.continues, b), inverter_off=_pick(seg.inverter_off, b))
            for seg in self.segments
        ), sample_rate=self.rates[0][b], source=source)

    def refusal(self, b: int, table: Columns, source: str) -> DataError:
        """The one sentence of table ``b`` (it failed), of the first check it fails in the order they read it."""
        if self.finite is not None and not self.finite[b]:
            try:
                check_numbers(table, source, self.numeric)
            except DataError as exc:
                return exc
        for seg in self.segments:
            lo, where = seg.lo, f"{source}: segment '{seg.name}'"
            if seg.clock is None:
                return DataError(f"{where} has a single sample; a segment needs at least two samples (drop or "
                                 "extend it).")
            t, dt, period = self.column["t"][b, seg.lo:seg.hi], seg.dt[b], float(seg.period[b])
            if not seg.increasing[b]:
                if np.any(dt == 0):
                    k = int(np.flatnonzero(dt == 0)[0])
                    return DataError(
                        f"{where}: column 't' repeats the timestamp {t[k]:.9g} s (data rows {lo + k + 1} and "
                        f"{lo + k + 2}); remove the duplicated rows."
                    )
                k = int(np.flatnonzero(dt < 0)[0])
                return DataError(
                    f"{where}: column 't' decreases from {t[k]:.9g} s to {t[k + 1]:.9g} s at data row {lo + k + 2}; "
                    "sort the rows by time within each segment."
                )
            if not seg.uniform[b]:
                k = int(np.argmax(np.abs(dt - period)))
                return DataError(
                    f"{where}: column 't' is not uniformly sampled (step {dt[k]:.6g} s at data row {lo + k + 2}, "
                    f"typical {period:.6g} s); resample the segment onto a uniform time grid."
                )
            if not seg.lock_ok[b]:
                return DataError(
                    f"{where}: column 'locked' must be one value, 0 or 1, over the segment; "
                    f"got {np.unique(self.column['locked'][b, seg.lo:seg.hi]).tolist()}."
                )
            if seg.inverter_ok is not None and not seg.inverter_ok[b]:
                return DataError(
                    f"{where}: column 'inverter' must be one value over the segment, 1 (on) or 0 (off: switches "
                    f"open, no current); got {np.unique(self.column['inverter'][b, seg.lo:seg.hi]).tolist()}; "
                    "split the segment where the inverter turns on or off."
                )
            if seg.temperature is not None and not seg.temperature_ok[b]:
                k = int(np.flatnonzero(~np.isfinite(seg.temperature[b]))[0])
                return DataError(
                    f"{where}: column 'temperature' is blank or not a number at sample {k + 1} although other samples "
                    "of the segment have one; give every sample of the segment a temperature in degC, or none."
                )
        first = self.segments[0]
        for seg, rate in zip(self.segments, self.rates):
            if _rate_differs(rate[b], self.rates[0][b]):
                return DataError(
                    f"{source}: segment '{seg.name}' is sampled at {rate[b]:.6g} Hz but '{first.name}' at "
                    f"{self.rates[0][b]:.6g} Hz; record every segment at one sample rate (or resample)."
                )
        v_max, i_max = float(np.max(np.abs(self.voltages[b]))), float(np.max(np.abs(self.currents[b])))
        nominal_R = self.nominal_R
        assert nominal_R is not None and _implausible_currents(v_max, i_max, nominal_R), "table b passed every check"
        return DataError(
            f"{source}: currents reach {i_max:.4g} A but voltages of at most {v_max:.3g} V across "
            f"R = {nominal_R:.3g} ohm cannot drive more than ~{v_max / nominal_R:.3g} A: are 'i_d'/'i_q' in mA? "
            "Give currents in A (divide by 1000)."
        )


def _check(tables: list[Columns], names: list[str], sizes: list[int], nominal_R: float | None,
           finite_known: bool) -> _Checked:
    """The per-segment checks of ``tables`` (dq columns, laid out alike: segments ``names`` of ``sizes``
    rows), each vectorised across the tables. ``finite_known``: every numeric value is known to be finite."""
    numeric = [c for c in _NUMERIC if c in tables[0]]
    if len(tables) == 1:
        column = {c: tables[0][c].astype(float, copy=False)[None] for c in numeric}  # (1, N)
    else:
        column = {c: np.stack([table[c] for table in tables]).astype(float, copy=False) for c in numeric}  # (B, N)
    ok = np.ones(len(tables), dtype=bool)
    finite = None
    if not finite_known:
        for c in numeric:
            ok &= np.all(np.isfinite(column[c]), axis=1)
        finite = ok.copy()
    temperature = None
    if "temperature" in tables[0]:
        import pandas as pd

        temperature = np.stack([pd.to_numeric(table["temperature"], errors="coerce").astype(float)
                                for table in tables])
    currents = np.stack([column["i_d"], column["i_q"]], axis=-1)  # (B, N, 2)
    voltages = np.stack([column["v_d"], column["v_q"]], axis=-1)
    w_m, theta_e = column.get("w_m"), column.get("theta_e")
    segments, rates = [], []
    lo = 0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for name, n in zip(names, sizes):
            seg = _Segment(name, lo, lo + n)
            lo += n
            if n < 2:
                ok[:] = False
                rates.append(np.full(len(tables), np.nan))
                segments.append(seg)
                continue
            rows = slice(seg.lo, seg.hi)
            seg.voltages, seg.currents = voltages[:, rows], currents[:, rows]
            seg.w_m = None if w_m is None else w_m[:, rows]
            seg.theta_e = None if theta_e is None else theta_e[:, rows]
            seg.temperature = None if temperature is None else temperature[:, rows]
            t = column["t"][:, rows]
            seg.dt, seg.period, seg.increasing, seg.uniform = _clock(t)
            seg.lock_ok, seg.locked = _locked_flag(column["locked"][:, rows])
            seg.at_rest = _starts_at_rest(seg.currents, seg.w_m, seg.locked)
            seg.clock = t - t[:, :1]
            ok &= seg.increasing & seg.uniform & seg.lock_ok
            if "inverter" in column:
                seg.inverter_ok, on = _locked_flag(column["inverter"][:, rows])
                ok &= seg.inverter_ok
                seg.inverter_off = (~on).tolist()
            if segments and segments[-1].clock is not None:
                seg.continues = _continues(segments[-1], column["t"][:, segments[-1].hi - 1], t[:, 0], seg).tolist()
            if seg.temperature is not None:
                seg.no_temperature, seg.temperature_ok = _temperature(seg.temperature)
                ok &= seg.temperature_ok
                seg.no_temperature = seg.no_temperature.tolist()
            seg.locked, seg.at_rest = seg.locked.tolist(), seg.at_rest.tolist()  # Python bools, as SegmentData holds
            rates.append(1.0 / seg.period)
            segments.append(seg)
        for r in rates[1:]:
            ok &= ~_rate_differs(r, rates[0])
        if nominal_R is not None:
            ok &= ~_implausible_currents(np.max(np.abs(voltages), axis=(1, 2)),
                                         np.max(np.abs(currents), axis=(1, 2)), nominal_R)
    return _Checked(numeric, column, currents, voltages, finite, segments,
                    [r.tolist() for r in rates], nominal_R, ok)
