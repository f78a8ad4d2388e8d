"""Fleet calibration: every motor off the line, one results table.

One bench file per motor, or one Parquet dataset of many split by serial
(``_inputs``); logs are read through a format file. A chunk's files are requested from the operating
system at once (``_prefetch``), then read and checked together
(``data.benches_from_frames``), grouped by plan shape (segment lengths, rotor
conditions, speed input) and fitted together: one ``jit(vmap(...))`` call per
group and chunk, each motor with its own applied voltages and measured speed.
A run's chunks are of equal size and batch sizes are rounded up to powers of
two (padding repeats a real motor and is dropped), so a process compiles each
shape once or twice and reuses it for the rest of the run. Chunks run in this
process, in local helper processes, or on a dask cluster (``_runners``).

Nothing is lost: every motor yields exactly one row, a file that fails
validation or a fit that does not converge included, with its reason. Rows are
written per chunk to ``<out>.parts/`` (each part atomically), so a killed run
resumes where it stopped; the final table is assembled, checked against the
fleet (robust z-scores, ``_checks``) and written atomically.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import shutil
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import pandas as pd

from .._io import atomic_path
from .._stats import next_power_of_two
from ..data import BenchData, BenchFormat, benches_from_frames, is_log, load_format, read_columns, read_table
from ..data import stacked_experiment
from ..errors import ClusterLost, DrivecalError
from ..fitting import fit_currents
from ..identify import check_requested
from ..diagnose import EFFECTS
from ..physics import ESTIMABLE
from ._effects import select_for
from ..model import model_experiment
from ..data import MotorFile
from ..results import Spec, Status, content_sha256, result_message
from ._checks import FLEET_COLUMNS, fleet_checks, residual_diagnostics, spec_checks
from ._report_stats import DEFAULT_OUTLIER_Z
from ._inputs import discover_paths, motors_in, prefetch as _prefetch, serial_of
from ._cluster import stopped
from ._runners import run_chunks, tune_if_dask_worker

# The fleet table's status words as constants: aliases of the ``Status`` labels, kept for one release
# (0.2) so code written against them still runs; use ``Status.CALIBRATED.label`` etc. instead.
STATUS_CALIBRATED = Status.CALIBRATED.label
STATUS_PARTIAL = Status.PARTIAL.label
STATUS_NOT_CONVERGED = Status.NOT_CONVERGED.label
STATUS_INVALID = Status.INVALID.label


# --------------------------------------------------------------------------- inputs


@dataclasses.dataclass(frozen=True)
class _Loaded:
    path: str
    serial: str
    sha256: str
    bench: BenchData | None
    reason: str | None
    tested_at: float = float("nan")  # the file's modification time (s since the epoch): when the bench wrote it


def _load(paths: Sequence[str], motor_file: MotorFile, fmt: BenchFormat | None = None) -> list[_Loaded]:
    """Read and check a chunk's bench files; one entry per motor (a file holding many motors, one per
    serial: ``_inputs.motors_in``), in order, failures with their reason.

    All of them are asked for first (:func:`_prefetch`); files laid out alike are checked together
    (``data.benches_from_frames``). ``fmt``: the bench format file of every input (None: drivecal's columns).
    """
    _prefetch(paths)
    read: list[tuple[str, str, str, Any]] = []  # path, serial, sha256, columns or the reason they are missing
    written: dict[str, float] = {}
    for path in paths:
        sha, serial = "", Path(path).stem
        try:
            content = Path(path).read_bytes()  # read once: hashed and parsed
            written[path] = os.stat(path).st_mtime
            sha = content_sha256(content)
            plain = fmt is None and not is_log(Path(path))
            columns = read_table(Path(path), content) if plain else read_columns(Path(path), fmt, content)
            for label, motor in motors_in(columns):
                read.append((path, label if label is not None else serial_of(path, motor), sha, motor))
        except (DrivecalError, OSError) as exc:
            read.append((path, serial, sha, str(exc)))
    readable = [r for r in read if not isinstance(r[3], str)]
    prior = motor_file.motor
    checked = iter(benches_from_frames([r[3] for r in readable], [r[0] for r in readable],
                                       pole_pairs=float(prior.pole_pairs), nominal_R=float(prior.R)))
    loaded = []
    for path, serial, sha, columns in read:
        result = columns if isinstance(columns, str) else next(checked)
        bench = result if isinstance(result, BenchData) else None
        loaded.append(_Loaded(path, serial, sha, bench, None if bench is not None else str(result),
                              written.get(path, float("nan"))))
    return loaded


def _shape_key(bench: BenchData, measured_speed: bool) -> tuple:
    return (
        round(bench.sample_rate, 6),
        tuple(
            (s.num_samples, s.locked, bool(measured_speed and s.w_m is not None and not s.locked), s.continues,
             s.inverter_off)
            for s in bench.segments
        ),
    )



def _bucket(n: int, chunk: int) -> int:
    """Batch size to compile for n motors: the next power of two, at most ``chunk``."""
    return min(chunk, next_power_of_two(n))


# --------------------------------------------------------------------------- one chunk


def _failed_row(item: _Loaded, status: Status, reason: str) -> dict[str, Any]:
    return {"serial": item.serial, "file": item.path, "file_sha256": item.sha256,
            "tested_at": _tested_at([item])[0], "status": status.label, "reason": reason, "converged": False}


def _tested_at(items: list[_Loaded]) -> pd.Series:
    """When each motor's bench file was written (its modification time, UTC; NaT where unknown): the
    fleet report's trends may follow it (``fleet-report --trend-by tested_at``)."""
    return pd.to_datetime(pd.Series([it.tested_at for it in items], dtype=float), unit="s", utc=True)


def _fit_group(items: list[_Loaded], motor_file: MotorFile, measured_speed: bool, chunk: int,
               effects: str | tuple[str, ...] = "auto") -> pd.DataFrame:
    prior, names = motor_file.motor, motor_file.names
    if isinstance(effects, tuple):  # a list of effects: fitted for every motor, as `drivecal fit` fits them
        wanted = set(names) | {n for e in effects for n in EFFECTS[e][0]}
        names = tuple(n for n in ESTIMABLE if n in wanted)
    delay = motor_file.delay_samples
    size = _bucket(len(items), chunk)
    pad = [0] * (size - len(items))  # padding repeats the first motor; its rows are dropped
    benches = [items[i].bench for i in list(range(len(items))) + pad]
    experiment = model_experiment(stacked_experiment(benches, measured_speed, delay, host=True), prior, names)
    currents = np.stack([bench.currents for bench in benches])
    cal = fit_currents(experiment, currents, prior, names=names, source=f"{len(items)} motors", delay_samples=delay)
    diag = residual_diagnostics(cal.residuals, np.asarray(experiment.segment_start))
    partial = not all(cal.identifiable)
    reason_partial = "; ".join(f"{n}: {cal.identifiability.reasons.get(n, 'not identifiable')}"
                               for n, ok in zip(cal.names, cal.identifiable) if not ok)
    n = len(items)
    converged = np.asarray(cal.converged)[:n]
    codes = np.asarray(cal.result_code)[:n]
    messages = [result_message(int(c), bool(ok)) for c, ok in zip(codes, converged)]
    # Columns for the whole chunk at once, not a Calibration and a dict per motor.
    columns: dict[str, Any] = {
        "serial": [it.serial for it in items], "file": [it.path for it in items],
        "file_sha256": [it.sha256 for it in items], "tested_at": _tested_at(items).array,
        "status": np.where(converged, (Status.PARTIAL if partial else Status.CALIBRATED).label,
                           Status.NOT_CONVERGED.label),
        "reason": [(reason_partial if partial else "") if ok else m for ok, m in zip(converged, messages)],
        "converged": converged.astype(bool), "message": messages,
        "iterations": np.asarray(cal.iterations)[:n].astype(int),
        "sigma_hat": np.asarray(cal.sigma_hat)[:n].astype(float),
        "num_samples": [it.bench.num_samples for it in items],
        "sample_rate": [float(it.bench.sample_rate) for it in items],
        "measured_speed": [bool(measured_speed and it.bench.has_measured_speed) for it in items],
    }
    for i, name in enumerate(cal.names):
        columns[name] = cal.estimate[:n, i]
        columns[f"{name}_se"] = cal.se[:n, i]
        columns[f"{name}_ci_low"] = cal.ci95[:n, i, 0]
        columns[f"{name}_ci_high"] = cal.ci95[:n, i, 1]
        columns[f"{name}_identifiable"] = np.full(n, bool(cal.identifiable[i]))
    columns["resid_min_p"] = diag["resid_min_p"][:n]
    columns["mismatch"] = diag["mismatch"][:n]
    columns["effects"] = [""] * n
    if effects == "auto":
        for i in np.flatnonzero(np.asarray(columns["mismatch"]) & converged):
            select_for(columns, int(i), items[i].bench, items[i].path, motor_file, measured_speed, effects)
    return pd.DataFrame(columns)


def calibrate_files(
    paths: Sequence[str],
    motor_file: MotorFile,
    *,
    chunk: int = 256,
    measured_speed: bool = True,
    effects: str | tuple[str, ...] = "auto",
    format: str | Path | BenchFormat | None = None,
) -> pd.DataFrame:
    """Calibrate one chunk of bench files; one row per motor (per file, or per serial of a file of many),
    failures included, in the order of ``paths``.

    ``effects``: as ``drivecal fit --effects``; in a batch only the motors whose
    residuals are not white go through the selection (see ``_select_for``). ``format``: the bench
    format file of every file (see ``data.load_format``); a file holding many motors gives a row per motor.

    Runs wherever it is called: in this process, or on a dask worker (the
    compiled fit stays in that worker's memory for its next chunk).
    """
    from .._version import __version__

    tune_if_dask_worker()
    loaded = _load([str(p) for p in paths], motor_file, load_format(format))
    failed: list[dict] = []
    fitted: list[pd.DataFrame] = []
    groups: dict[tuple, list[_Loaded]] = {}
    for item in loaded:
        if item.bench is None:
            failed.append(_failed_row(item, Status.INVALID, item.reason or "unreadable"))
            continue
        if motor_file.estimate is not None:
            try:
                check_requested(motor_file.names, item.bench.experiment(measured_speed, host=True), item.path)
            except DrivecalError as exc:
                failed.append(_failed_row(item, Status.INVALID, str(exc)))
                continue
        groups.setdefault(_shape_key(item.bench, measured_speed), []).append(item)
    for items in groups.values():
        for start in range(0, len(items), chunk):
            part = items[start : start + chunk]
            try:
                fitted.append(_fit_group(part, motor_file, measured_speed, chunk, effects))
            except DrivecalError as exc:
                failed += [_failed_row(it, Status.INVALID, str(exc)) for it in part]
    frames = ([pd.DataFrame(failed)] if failed else []) + fitted
    table = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=["file"])
    order = {item.path: i for i, item in enumerate(loaded)}
    table = table.iloc[np.argsort(table["file"].map(order).to_numpy(), kind="stable")].reset_index(drop=True)
    table["drivecal_version"] = __version__
    table["motor_file"] = motor_file.source
    table["motor_sha256"] = motor_sha256(motor_file)
    return table


def motor_sha256(motor_file: MotorFile) -> str:
    """SHA-256 (hex) of a motor file's content as loaded: every prior value (SI), ``estimate``, ``delay_samples``.

    Two motor files with the same priors and settings hash alike whatever their layout, units or
    comments; any other prior, parameter list or delay hashes differently. Recorded per row of the
    table (``motor_sha256``), so a resumed run can refuse another motor file.
    """
    content = {"motor": {k: float(v) for k, v in motor_file.motor.all_values().items()},
               "estimate": None if motor_file.estimate is None else list(motor_file.estimate),
               "delay_samples": _whole_or_float(motor_file.delay_samples)}
    return content_sha256(json.dumps(content, sort_keys=True).encode())

# --------------------------------------------------------------------------- the run


@dataclasses.dataclass(frozen=True)
class BatchSummary:
    """How a batch run ended.

    Attributes:
        out: the results table path.
        total: motors in the table.
        done_before: motors skipped because an earlier run (``--resume``) had them.
        calibrated, partial, failed: counts by status (failed = invalid or not converged).
        outliers: serials flagged by the fleet check.
        mismatch: serials whose residuals suggest model mismatch.
        seconds: wall time of this run (s).
        spec: with a specification (the motor file's ``[tolerance]``), the count of each
            :class:`drivecal.results.Spec` label; else None.
    """

    out: Path
    total: int
    done_before: int
    calibrated: int
    partial: int
    failed: int
    outliers: tuple[str, ...]
    mismatch: tuple[str, ...]
    seconds: float
    spec: dict[str, int] | None = None

    @property
    def completed_with_failures(self) -> bool:
        return self.failed > 0

    @property
    def exit_code(self) -> int:
        """The run's exit status, the most serious first: with a specification 6 (some motor failed it),
        1 (some motor could not be judged: not calibrated or an invalid file), 7 (some inconclusive),
        0 (all pass); without one 1 (completed with failures) or 0."""
        if self.spec is None:
            return 1 if self.completed_with_failures else 0
        count = self.spec.get
        if count(Spec.FAIL.label, 0):
            return Spec.FAIL.exit_code
        if count(Spec.NOT_CALIBRATED.label, 0) or count(Spec.INVALID.label, 0):
            return 1
        return Spec.INCONCLUSIVE.exit_code if count(Spec.INCONCLUSIVE.label, 0) else Spec.PASS.exit_code

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["out"] = str(self.out)
        d["outliers"], d["mismatch"] = list(self.outliers), list(self.mismatch)
        d["status"] = "completed with failures" if self.completed_with_failures else "completed"
        return d


def parts_dir(out: Path) -> Path:
    """Where a run keeps its per-chunk results until the table is assembled."""
    return out.with_name(out.name + ".parts")


def _read_table(path: Path, out: Path) -> pd.DataFrame:
    """One saved table (the final one or a part); refused in one sentence if it cannot be read."""
    parts = parts_dir(out)
    where = (f"{path}: a part of the interrupted run in {parts}/" if path.parent == parts
             else f"{path}: the results table of the earlier run")
    fix = (f"delete {path.name} (its motors are calibrated again) or choose another --out" if path.parent == parts
           else f"delete it (and {parts.name}/) to start again, or choose another --out")
    try:
        if not path.is_file():
            raise IsADirectoryError(path)
        table = pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises ArrowInvalid, OSError, ... for a file that is not Parquet
        raise DrivecalError(f"{where} is not a readable Parquet table ({type(exc).__name__}); {fix}.") from None
    if len(table) and "file" not in table.columns:
        raise DrivecalError(f"{where} has no 'file' column, so it is not a drivecal results table; {fix}.")
    return table


def _read_done(out: Path) -> pd.DataFrame:
    tables = []
    if out.exists():
        tables.append(_read_table(out, out))
    parts = parts_dir(out)
    if parts.is_dir():
        tables += [_read_table(p, out) for p in sorted(parts.glob("part-*.parquet"))]
    return _combine(tables)


def _check_same_run(done: pd.DataFrame, out: Path, motor_file: MotorFile) -> None:
    """Refuse to resume ``out`` with another motor file or another drivecal version than its rows were made with."""
    from .._version import __version__

    if not len(done):
        return
    fix = "or start a new --out"
    versions = sorted(set(done["drivecal_version"].dropna().astype(str))) if "drivecal_version" in done else []
    if versions != [__version__]:
        earlier = " and ".join(versions) or "an unrecorded version"
        raise DrivecalError(f"--resume {out}: its rows were calibrated by drivecal {earlier}, this is drivecal "
                            f"{__version__}; resume with drivecal {earlier}, {fix}.")
    sha = motor_sha256(motor_file)
    hashes = done["motor_sha256"].fillna("").astype(str) if "motor_sha256" in done else pd.Series([""])
    if set(hashes) != {sha}:
        earlier = hashes[hashes != sha].iloc[0] if (hashes != sha).any() else ""
        sources = done.get("motor_file", pd.Series(["an unrecorded motor file"] * len(done)))
        source = str(sources[(hashes != sha).to_numpy()].iloc[0]) if earlier else "an unrecorded motor file"
        was = f"{source} (content sha256 {earlier[:12]})" if earlier else "an unrecorded motor file"
        raise DrivecalError(f"--resume {out}: its rows were calibrated with motor file {was}, this run with "
                            f"{motor_file.source} (content sha256 {sha[:12]}); resume with the same motor file, "
                            f"{fix}.")


def _combine(tables: list[pd.DataFrame]) -> pd.DataFrame:
    """Rows of several runs or parts as one table: the latest row per file, without fleet columns."""
    tables = [t for t in tables if len(t)]
    if not tables:
        return pd.DataFrame()
    done = pd.concat(tables, ignore_index=True)
    fleet_columns = [c for c in done.columns if c.startswith("z_") or c in FLEET_COLUMNS]
    key = ["file", "serial"] if "serial" in done.columns else "file"  # a file of many motors: a row per serial
    return done.drop(columns=fleet_columns).drop_duplicates(key, keep="last")


def run_batch(
    inputs: Sequence[str | os.PathLike],
    out: str | os.PathLike,
    motor_file: MotorFile,
    *,
    chunk: int = 256,
    workers: int | None = None,
    scheduler: str | None = None,
    reconnect: float = 0.0,
    resume: bool = False,
    measured_speed: bool = True,
    outlier_z: float = DEFAULT_OUTLIER_Z,
    progress: Callable[[int, int], None] = lambda done, total: None,
    effects: str | tuple[str, ...] = "auto",
    format: str | Path | BenchFormat | None = None,
) -> BatchSummary:
    """Calibrate every bench file of ``inputs`` into the Parquet table ``out``.

    Args:
        inputs: files, directories or glob patterns.
        out: results table (.parquet).
        motor_file: nominal motor (prior) and the parameters to estimate.
        chunk: motors per compiled call and per saved part.
        workers: local helper processes, each pinned to a core of its own when
            there are enough (default: this process's cores, at most one per
            chunk); 1 runs everything in this process.
        scheduler: address of a running dask scheduler (``tls://host:8786``, its certificates from dask's
            configuration; or ``tcp://host:8786``); chunks go to its workers instead. Losing it, or every
            worker, raises :class:`drivecal.errors.ClusterLost` (what was lost, the motors saved, the fix).
        reconnect: seconds to wait for a lost scheduler (or every worker) to come back before giving up
            (0: give up at once; workers are always given 10 s).
        resume: keep the rows of an earlier, interrupted run of the same
            ``out`` and calibrate only the files not yet in it.
        measured_speed: use a measured ``w_m`` as input (see ``BenchData.experiment``).
        outlier_z: robust z-score threshold of the fleet check (recorded in the table's ``outlier_z``).
        progress: called as ``progress(done, total)`` after each chunk.
        effects: bench effects, as ``drivecal fit --effects`` (see :func:`calibrate_files`).
        format: a bench format file for every input (channel names, units, windows; ``data.load_format``).
    """
    import time

    t0 = time.perf_counter()
    out = Path(out)
    if out.suffix.lower() != ".parquet":
        raise DrivecalError(f"--out {out}: the results table is written as Parquet; give a .parquet file name.")
    if chunk < 1:
        raise DrivecalError(f"--chunk {chunk}: give a positive number of motors per chunk.")
    parts = parts_dir(out)
    saved_parts = parts.exists() and (not parts.is_dir() or any(parts.iterdir()))  # an empty parts/ holds nothing
    if not resume and (out.exists() or saved_parts):
        raise DrivecalError(
            f"--out {out}: results of an earlier run exist; pass --resume to continue it, or remove "
            f"{out.name} (and {parts.name}/) to start again."
        )
    fmt = load_format(format)  # refused before anything is written
    files = discover_paths(inputs)
    done = _read_done(out) if resume else pd.DataFrame()
    _check_same_run(done, out, motor_file)
    done_files = set(done["file"]) if len(done) else set()
    todo = [f for f in files if f not in done_files]
    # Chunks of equal size (at most ``chunk``): all then compile to one batch size, where a short
    # last chunk would load (or compile) a kernel of its own.
    size = math.ceil(len(todo) / math.ceil(len(todo) / chunk)) if todo else chunk
    chunks = [todo[i : i + size] for i in range(0, len(todo), size)]
    # Parts are numbered past every existing one: chunks finish out of order, so an interrupted run
    # can leave gaps, and numbering by count would overwrite a saved part.
    numbers = [p.stem.removeprefix("part-") for p in parts.glob("part-*.parquet")]
    first_part = max((int(n) for n in numbers if n.isdigit()), default=-1) + 1

    def save(k: int, table: pd.DataFrame) -> None:
        parts.mkdir(parents=True, exist_ok=True)  # made by the first part: nothing is left when nothing is saved
        with atomic_path(parts / f"part-{first_part + k:06d}.parquet") as tmp:
            table.to_parquet(tmp, index=False)

    progress(len(done_files & set(files)), len(files))
    finished = len(done_files & set(files))
    fresh = []
    calibrate = functools.partial(calibrate_files, motor_file=motor_file, chunk=chunk, measured_speed=measured_speed,
                                  effects=effects, format=fmt)
    try:
        for k, table in run_chunks(chunks, calibrate, workers, scheduler, reconnect):
            save(k, table)
            fresh.append(table)
            finished += len(table)
            progress(finished, len(files))
    except ClusterLost as exc:  # the sentence says how many motors are saved, and where
        raise stopped(exc, finished, len(files), f"{parts}/" if parts.is_dir() else str(out)) from None

    table = _combine([done] + fresh)  # the earlier runs' rows and this run's (as saved in the parts)
    order = {f: i for i, f in enumerate(files)}
    table = table.assign(_order=table["file"].map(order).fillna(len(files))).sort_values(["_order", "file"],
                                                                                          kind="stable")
    table = fleet_checks(table.drop(columns="_order").reset_index(drop=True), outlier_z)
    table = spec_checks(table, motor_file.tolerance)
    with atomic_path(out) as tmp:
        table.to_parquet(tmp, index=False)
    shutil.rmtree(parts, ignore_errors=True)

    status = table["status"]
    return BatchSummary(
        out=out,
        total=len(table),
        done_before=len(done_files & set(files)),
        calibrated=int((status == Status.CALIBRATED.label).sum()),
        partial=int((status == Status.PARTIAL.label).sum()),
        failed=int(status.isin([Status.INVALID.label, Status.NOT_CONVERGED.label]).sum()),
        outliers=tuple(table.loc[table["outlier"], "serial"].astype(str)),
        mismatch=tuple(table.loc[table.get("mismatch", pd.Series(False, index=table.index)).fillna(False)
                                 .astype(bool), "serial"].astype(str)),
        seconds=time.perf_counter() - t0,
        spec=None if "spec" not in table else {s.label: int((table["spec"] == s.label).sum()) for s in Spec},
    )


def _whole_or_float(value: float) -> int | float:
    """A whole number as int (the hash of a motor file with a whole delay is that of 0.2's), else the float."""
    return int(value) if float(value).is_integer() else float(value)
