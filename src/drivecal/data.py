"""Bench data: what the bench applied and measured, segment by segment.

Bench files (CSV, Parquet or MATLAB ``.mat``) hold one row per sample with the
columns ``segment`` (name), ``locked`` (0/1), ``t`` (s), ``v_d``, ``v_q`` (V),
``i_d``, ``i_q`` (A) and optionally ``w_m`` (rad/s, measured mechanical speed)
and ``temperature`` (degC, winding temperature; R follows it).
Instead of dq columns a file may hold phase quantities ``i_a``, ``i_b``
(``i_c``), ``v_a``, ``v_b`` (``v_c``) (phase-to-neutral, A and V) with a rotor
angle ``theta_e`` (electrical, rad) or ``theta_m`` (mechanical, rad); they are
turned into dq with the amplitude-invariant Clarke and Park transforms.

Every check of a file lives in :func:`bench_from_frame`; each failure is one
:class:`DataError` sentence naming the file, the column and the fix.
"""

from __future__ import annotations

import dataclasses
import io
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from .errors import DataError
from .forward import Experiment
from .report import atomic_path

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
#: File formats by suffix.
FORMATS = (".csv", ".parquet", ".mat")


@dataclasses.dataclass(frozen=True)
class SegmentData:
    """One recorded segment.

    Attributes:
        name: segment label.
        locked: whether the rotor was locked.
        t: sample instants from the segment start (s), shape (N,).
        voltages: applied ``[v_d, v_q]`` (V), shape (N, 2), held between samples.
        currents: measured ``[i_d, i_q]`` (A), shape (N, 2).
        w_m: measured mechanical speed (rad/s), shape (N,), or None.
        at_rest: the segment starts from rest (zero currents and speed); when
            False the forward model starts from the first sample instead.
        temperature: winding temperature (degC) per sample, shape (N,), or None.
        theta_e: measured electrical rotor angle (rad) per sample, shape (N,),
            of a phase bench file, or None.
    """

    name: str
    locked: bool
    t: np.ndarray
    voltages: np.ndarray
    currents: np.ndarray
    w_m: np.ndarray | None = None
    at_rest: bool = True
    temperature: np.ndarray | None = None
    theta_e: np.ndarray | None = None

    @property
    def num_samples(self) -> int:
        return int(self.t.shape[0])

    def initial_state(self) -> np.ndarray:
        """``[i_d, i_q, w_m, theta_m]`` the forward model starts from (A, A, rad/s, rad)."""
        if self.at_rest:
            return np.zeros(4)
        w0 = 0.0 if (self.locked or self.w_m is None) else float(self.w_m[0])
        return np.array([self.currents[0, 0], self.currents[0, 1], w0, 0.0])


@dataclasses.dataclass(frozen=True)
class BenchData:
    """A whole bench run at one sample rate.

    Attributes:
        segments: the recorded segments in order.
        sample_rate: samples per second (Hz).
        source: where the data came from (a file path or "synthetic bench").
    """

    segments: tuple[SegmentData, ...]
    sample_rate: float
    source: str = "synthetic bench"

    @property
    def currents(self) -> np.ndarray:
        """Measured ``[i_d, i_q]`` (A) of all segments end to end, shape (M, 2)."""
        return np.concatenate([s.currents for s in self.segments], axis=0)

    @property
    def num_samples(self) -> int:
        """M, the samples over all segments."""
        return sum(s.num_samples for s in self.segments)

    @property
    def has_measured_speed(self) -> bool:
        """Some free segment carries a measured speed ``w_m``."""
        return any(s.w_m is not None and not s.locked for s in self.segments)

    def experiment(self, measured_speed: bool = True, delay_samples: int = 0, host: bool = False) -> Experiment:
        """The applied voltages and rotor conditions, for the forward model.

        Args:
            measured_speed: on free segments with a measured ``w_m``, use it as
                an input of the electrical equations (J and B then play no
                part); when False the speed is simulated from J and B.
            delay_samples: the inverter's PWM/computation delay (samples): the
                recorded command k acts at sample k + delay_samples.
            host: numpy arrays (see ``Experiment.from_segments``).
        """
        speeds = [
            s.w_m if (measured_speed and s.w_m is not None and not s.locked) else None for s in self.segments
        ]
        return Experiment.from_segments(
            [s.voltages for s in self.segments],
            [s.locked for s in self.segments],
            1.0 / self.sample_rate,
            initial_states=[s.initial_state() for s in self.segments],
            speeds=speeds,
            temperatures=[s.temperature for s in self.segments],
            angles=[s.theta_e for s in self.segments],
            delay_samples=delay_samples,
            host=host,
        )

    def with_currents(self, currents: np.ndarray) -> BenchData:
        """The same run with the currents replaced by ``currents`` (A), shape (M, 2)."""
        currents = np.asarray(currents, dtype=float)
        if currents.shape != (self.num_samples, 2):
            raise DataError(
                f"{self.source}: expected currents of shape ({self.num_samples}, 2), got {currents.shape}."
            )
        out, k = [], 0
        for seg in self.segments:
            out.append(dataclasses.replace(seg, currents=currents[k : k + seg.num_samples]))
            k += seg.num_samples
        return dataclasses.replace(self, segments=tuple(out))

    def add_noise(self, sigma: float, seed: int) -> BenchData:
        """Currents plus seeded zero-mean Gaussian sensor noise of ``sigma`` (A)."""
        rng = np.random.default_rng(seed)
        return self.with_currents(self.currents + rng.normal(0.0, sigma, size=(self.num_samples, 2)))

    def to_frame(self) -> pd.DataFrame:
        """One row per sample with the bench-file columns."""
        frames = []
        for seg in self.segments:
            cols = {
                "segment": seg.name,
                "locked": int(seg.locked),
                "t": seg.t,
                "v_d": seg.voltages[:, 0],
                "v_q": seg.voltages[:, 1],
                "i_d": seg.currents[:, 0],
                "i_q": seg.currents[:, 1],
            }
            if any(s.w_m is not None for s in self.segments):
                cols["w_m"] = seg.w_m if seg.w_m is not None else np.zeros(seg.num_samples)
            if any(s.theta_e is not None for s in self.segments):
                cols["theta_e"] = seg.theta_e if seg.theta_e is not None else np.zeros(seg.num_samples)
            if any(s.temperature is not None for s in self.segments):
                cols["temperature"] = seg.temperature if seg.temperature is not None else np.full(seg.num_samples,
                                                                                                  np.nan)
            frames.append(pd.DataFrame(cols))
        return pd.concat(frames, ignore_index=True)

    def to_phase_frame(self, theta_e: np.ndarray) -> pd.DataFrame:
        """The run as phase quantities: ``i_a, i_b, i_c, v_a, v_b, v_c`` (A, V, phase-to-neutral)
        and ``theta_e`` (rad), by inverse amplitude-invariant Park and Clarke.

        Args:
            theta_e: electrical rotor angle at every sample (rad), shape (M,).
        """
        frame = self.to_frame()
        theta_e = np.asarray(theta_e, dtype=float)
        cos, sin = np.cos(theta_e), np.sin(theta_e)
        for prefix in ("i", "v"):
            d, q = frame.pop(f"{prefix}_d").to_numpy(), frame.pop(f"{prefix}_q").to_numpy()
            alpha, beta = d * cos - q * sin, d * sin + q * cos
            frame[f"{prefix}_a"] = alpha
            frame[f"{prefix}_b"] = -0.5 * alpha + 0.5 * math.sqrt(3.0) * beta
            frame[f"{prefix}_c"] = -0.5 * alpha - 0.5 * math.sqrt(3.0) * beta
        frame["theta_e"] = theta_e
        return frame

    def save(self, path: str | Path) -> Path:
        """Write the bench file (format from the suffix: .csv, .parquet, .mat), atomically."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in FORMATS:
            raise DataError(f"{path}: unknown bench-file format '{suffix}'; use one of {', '.join(FORMATS)}.")
        frame = self.to_frame()
        with atomic_path(path) as tmp:
            if suffix == ".csv":
                frame.to_csv(tmp, index=False, float_format="%.17g")
            elif suffix == ".parquet":
                frame.to_parquet(tmp, index=False)
            else:
                from scipy.io import savemat

                columns = {c: frame[c].to_numpy() for c in frame.columns if c != "segment"}
                columns["segment"] = np.array(frame["segment"].tolist(), dtype=object)
                savemat(tmp, columns, oned_as="column", appendmat=False)
        return path


# --------------------------------------------------------------------------- reading


#: A bench table as read: column name -> one numpy array per column, all of one length (floats,
#: integers, or objects for text). What every check works on: a DataFrame lookup costs ~0.1 ms,
#: which a fleet pays per column and motor.
Columns = dict


def columns_of(frame: pd.DataFrame | Columns, source: str = "bench data") -> Columns:
    """The columns of a bench table as 1-D numpy arrays (a DataFrame, or a mapping of equal-length columns)."""
    if isinstance(frame, pd.DataFrame):
        return {str(c): frame[c].to_numpy() for c in frame.columns}
    out = {str(c): np.atleast_1d(np.asarray(v)) for c, v in frame.items()}
    lengths = {k: v.shape[0] for k, v in out.items()}
    if len(set(lengths.values())) > 1 or any(v.ndim != 1 for v in out.values()):
        raise DataError(f"{source}: the columns must be 1-D and of one length, got lengths {lengths}; "
                        "give one value per sample in every column.")
    return out


def _num_rows(columns: Columns) -> int:
    return next((v.shape[0] for v in columns.values()), 0)


def read_table(path: Path, content: bytes | None = None) -> Columns:
    """The raw columns of a bench file (.csv, .parquet, .mat), unchecked.

    ``content``: the file's bytes when already read (a fleet hashes them too),
    so the file is read once.
    """
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise DataError(f"{path}: unknown bench-file format '{suffix}'; use one of {', '.join(FORMATS)}.")
    if content is None and not path.is_file():
        raise DataError(f"{path}: no such file; check the path.")
    try:
        if suffix == ".parquet":
            # Arrow columns straight to numpy: no DataFrame (pandas' conversion and lookups cost
            # ~1 ms a file, which a fleet pays per motor). Nulls become NaN (numbers) or None (text).
            import pyarrow as pa
            import pyarrow.parquet as pq

            table = pq.ParquetFile(path if content is None else pa.BufferReader(content)).read(use_threads=False)
            return {name: table.column(name).to_numpy() for name in table.column_names}
        source = path if content is None else io.BytesIO(content)
        if suffix == ".csv":
            return columns_of(pd.read_csv(source))
        return _read_mat(path, source)
    except DataError:
        raise
    except Exception as exc:  # a parser's own error: say which file and what it said
        raise DataError(f"{path}: cannot be read as a {suffix[1:]} bench file ({exc}).") from None


def _read_mat(path: Path, source: Path | io.BytesIO) -> Columns:
    """The columns of a MATLAB bench file (``source``: its path or its bytes; ``path`` names it in messages)."""
    from scipy.io import loadmat

    raw = {k: v for k, v in loadmat(source, squeeze_me=True).items() if not k.startswith("__")}
    lengths = {k: np.size(v) for k, v in raw.items()}
    if len(set(lengths.values())) > 1:
        longest = max(lengths.values())
        short = sorted(k for k, n in lengths.items() if n != longest)
        raise DataError(
            f"{path}: column(s) {', '.join(short)} have {', '.join(str(lengths[k]) for k in short)} samples but the "
            f"others {longest}: the columns were logged at different sample rates; resample them onto one time base."
        )
    columns = {}
    for k, v in raw.items():
        arr = np.atleast_1d(v)
        columns[k] = (np.array([str(x).strip() for x in arr], dtype=object) if arr.dtype.kind in "OUS"
                      else arr.astype(float))
    return columns


def _noise_level(x: np.ndarray) -> Any:
    """Robust sensor-noise estimate (A) from second differences (MAD), insensitive to slow signals.

    ``x`` has samples along axis 0: shape (N,) gives a float, (N, k) one level per column, shape (k,).
    """
    if x.shape[0] < 4:
        return 0.0 if x.ndim == 1 else np.zeros(x.shape[1:])
    d2 = np.diff(x, 2, axis=0)
    level = _median(np.abs(d2 - _median(d2))) / 0.6745 / math.sqrt(6.0)
    return float(level) if x.ndim == 1 else level


def _median(x: np.ndarray) -> Any:
    """``np.median`` along axis 0 by partition (~5x faster on a few thousand samples)."""
    n = x.shape[0]
    part = np.partition(x, [(n - 1) // 2, n // 2], axis=0)
    return 0.5 * (part[(n - 1) // 2] + part[n // 2])


def _clarke_park(columns: Columns, prefix: str, theta_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude-invariant Clarke then Park of phase quantities ``<prefix>_a/b(/c)``."""
    a, b = columns[f"{prefix}_a"].astype(float), columns[f"{prefix}_b"].astype(float)
    # Without the third phase, assume no zero-sequence component: c = -a - b.
    c = columns[f"{prefix}_c"].astype(float) if f"{prefix}_c" in columns else -a - b
    alpha = (2.0 * a - b - c) / 3.0
    beta = (b - c) / math.sqrt(3.0)
    cos, sin = np.cos(theta_e), np.sin(theta_e)
    return alpha * cos + beta * sin, -alpha * sin + beta * cos


def _phase_to_dq(frame: Columns, source: str, pole_pairs: float) -> Columns:
    """Replace phase columns by dq columns (amplitude-invariant transforms)."""
    for name in ("i_b", "v_a", "v_b"):
        if name not in frame:
            raise DataError(f"{source}: phase data needs column '{name}' (with i_a, i_b, v_a, v_b, optional i_c, v_c).")
    _check_finite(frame, source, [c for c in frame if c[:2] in ("i_", "v_")] + ["theta_e", "theta_m"])
    if "theta_e" in frame:
        theta_e = frame["theta_e"].astype(float)
    elif "theta_m" in frame:
        theta_e = pole_pairs * frame["theta_m"].astype(float)
    else:
        raise DataError(
            f"{source}: phase data needs a rotor angle column: 'theta_e' (electrical, rad) or "
            "'theta_m' (mechanical, rad; multiplied by pole_pairs from the motor file)."
        )
    out = dict(frame)
    out["theta_e"] = theta_e
    out["i_d"], out["i_q"] = _clarke_park(frame, "i", theta_e)
    out["v_d"], out["v_q"] = _clarke_park(frame, "v", theta_e)
    return out


def _check_finite(columns: Columns, source: str, names: list[str]) -> None:
    """Every value of the columns ``names`` (those present) a finite number, else a DataError naming the first bad row."""
    for col in names:
        if col not in columns:
            continue
        raw = columns[col]
        if raw.dtype.kind in "fiub" and np.all(np.isfinite(raw)):
            continue  # the common case, without pd.to_numeric's per-column cost
        values = pd.to_numeric(raw, errors="coerce").astype(float)
        bad = ~np.isfinite(values)
        if not bad.any():
            continue
        rows = np.flatnonzero(~bad)
        stride = np.diff(rows)
        if rows.size >= 2 and stride.min() == stride.max() and stride[0] > 1:
            raise DataError(
                f"{source}: column '{col}' has a value only on every {stride[0]}th row: it was logged at a lower "
                f"sample rate than 't'; resample '{col}' onto the time base of 't'."
            )
        row = int(np.flatnonzero(bad)[0])
        what = "a missing value" if pd.isna(raw[row]) else f"'{raw[row]}'"
        raise DataError(
            f"{source}: column '{col}' has {what} in data row {row + 1} ({int(bad.sum())} bad value(s) in all); "
            "every value must be a finite number: remove or repair those rows."
        )


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
    if _num_rows(frame) == 0:
        raise DataError(f"{source}: the file has no samples; record at least one segment.")
    if "i_d" not in frame and "i_a" in frame:
        frame = _phase_to_dq(frame, source, pole_pairs)
    for col, meaning in DQ_COLUMNS.items():
        if col not in frame:
            hint = " (or phase columns i_a, i_b, v_a, v_b with theta_e)" if col in ("i_d", "i_q", "v_d", "v_q") else ""
            raise DataError(f"{source}: missing column '{col}' ({meaning}){hint}; add it to the file.")
    optional = [c for c in ("w_m", "theta_e") if c in frame]
    numeric = ["locked", "t", "v_d", "v_q", "i_d", "i_q"] + optional
    _check_finite(frame, source, numeric)
    # Segment names by code (a handful of distinct names over thousands of rows: strip those, not every row).
    codes, labels = pd.factorize(frame["segment"], use_na_sentinel=True)
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

    column = {c: frame[c].astype(float, copy=False) for c in numeric}
    # The file's current and voltage pairs once; each segment keeps a slice.
    currents_all = np.stack([column["i_d"], column["i_q"]], axis=1)
    voltages_all = np.stack([column["v_d"], column["v_q"]], axis=1)
    segments, rates = [], []
    for name, lo, hi in zip(order, starts, stops):
        rows = slice(lo, hi)
        where = f"{source}: segment '{name}'"
        if hi - lo < 2:
            raise DataError(f"{where} has a single sample; a segment needs at least two samples (drop or extend it).")
        t = column["t"][rows]
        dt = np.diff(t)
        if dt.min() <= 0:
            if np.any(dt == 0):
                k = int(np.flatnonzero(dt == 0)[0])
                raise DataError(
                    f"{where}: column 't' repeats the timestamp {t[k]:.9g} s (data rows {lo + k + 1} and "
                    f"{lo + k + 2}); remove the duplicated rows."
                )
            k = int(np.flatnonzero(dt < 0)[0])
            raise DataError(
                f"{where}: column 't' decreases from {t[k]:.9g} s to {t[k + 1]:.9g} s at data row {lo + k + 2}; "
                "sort the rows by time within each segment."
            )
        period = float(_median(dt))
        if np.max(np.abs(dt - period)) > 1e-3 * period:
            k = int(np.argmax(np.abs(dt - period)))
            raise DataError(
                f"{where}: column 't' is not uniformly sampled (step {dt[k]:.6g} s at data row {lo + k + 2}, "
                f"typical {period:.6g} s); resample the segment onto a uniform time grid."
            )
        rates.append(1.0 / period)
        lock = column["locked"][rows]
        if lock.min() != lock.max() or lock[0] not in (0.0, 1.0):
            raise DataError(
                f"{where}: column 'locked' must be one value, 0 or 1, over the segment; "
                f"got {np.unique(lock).tolist()}."
            )
        locked = bool(lock[0])
        currents, voltages = currents_all[rows], voltages_all[rows]
        w_m = column["w_m"][rows] if "w_m" in column else None
        # A segment starts from rest unless its first sample says otherwise (beyond the noise).
        noise = max(float(np.max(_noise_level(currents))), 1e-6)
        at_rest = bool(np.all(np.abs(currents[0]) <= 5.0 * noise))
        if w_m is not None and not locked:
            at_rest = at_rest and abs(w_m[0]) <= max(5.0 * _noise_level(w_m), 1e-6)
        temperature = _segment_temperature(frame["temperature"][lo:hi], where) if "temperature" in frame else None
        theta_e = column["theta_e"][rows] if "theta_e" in column else None
        segments.append(SegmentData(name, locked, t - t[0], voltages, currents, w_m, at_rest, temperature, theta_e))

    rate = rates[0]
    for seg, r in zip(segments, rates):
        if abs(r - rate) > 1e-6 * rate:
            raise DataError(
                f"{source}: segment '{seg.name}' is sampled at {r:.6g} Hz but '{segments[0].name}' at {rate:.6g} Hz; "
                "record every segment at one sample rate (or resample)."
            )
    bench = BenchData(tuple(segments), sample_rate=rate, source=source)
    if nominal_R is not None:
        _check_current_magnitude(bench, nominal_R)
    return bench


def _segment_temperature(rows: np.ndarray, where: str) -> np.ndarray | None:
    """A segment's ``temperature`` column (degC): all blank means not recorded (None); else every value finite."""
    values = pd.to_numeric(rows, errors="coerce").astype(float)
    if np.all(np.isnan(values)):
        return None
    if not np.all(np.isfinite(values)):
        k = int(np.flatnonzero(~np.isfinite(values))[0])
        raise DataError(
            f"{where}: column 'temperature' is blank or not a number at sample {k + 1} although other samples of the "
            "segment have one; give every sample of the segment a temperature in degC, or none."
        )
    return values


def _check_current_magnitude(bench: BenchData, nominal_R: float) -> None:
    """Refuse currents far above anything the applied voltages could drive (mA written as A)."""
    v_max = max(float(np.max(np.abs(s.voltages))) for s in bench.segments)
    i_max = max(float(np.max(np.abs(s.currents))) for s in bench.segments)
    # |i| cannot settle above max|v|/R; a factor 10 leaves room for a 50 % wrong R and transients.
    bound = 10.0 * v_max / nominal_R
    if v_max > 0 and i_max > bound:
        raise DataError(
            f"{bench.source}: currents reach {i_max:.4g} A but voltages of at most {v_max:.3g} V across "
            f"R = {nominal_R:.3g} ohm cannot drive more than ~{v_max / nominal_R:.3g} A: are 'i_d'/'i_q' in mA? "
            "Give currents in A (divide by 1000)."
        )


def load_bench(path: str | Path, *, pole_pairs: float = 4.0, nominal_R: float | None = None) -> BenchData:
    """Read and check a bench file (.csv, .parquet or .mat); see :func:`bench_from_frame`."""
    path = Path(path)
    return bench_from_frame(read_table(path), str(path), pole_pairs=pole_pairs, nominal_R=nominal_R)
