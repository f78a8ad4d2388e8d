"""Property-based fuzzing of the bench-file readers and checks: CSV, Parquet, MAT and in-memory tables.

Every generated input (random column sets, dtypes, NaN/Inf placement, wrong shapes, truncated or
corrupted bytes) either loads into a valid BenchData or raises a DrivecalError whose one-line message
names the file; never any other exception, and no warning escapes (warnings are errors inside the test).

``DRIVECAL_FUZZ_EXAMPLES`` (default 2000) inputs per reader, seeded (``DRIVECAL_FUZZ_SEED``): the
values of a table come from a numpy generator seeded by hypothesis, its structure (columns, dtypes,
corruptions) from hypothesis itself, so a failure shrinks to a small case and prints the seed.
"""

from __future__ import annotations

import io
import math
import os
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, seed, settings
from hypothesis import strategies as st

from drivecal.data import BenchData, bench_from_frame, benches_from_frames, read_table
from drivecal.errors import DrivecalError

EXAMPLES = int(os.environ.get("DRIVECAL_FUZZ_EXAMPLES", "2000"))
SEED = int(os.environ.get("DRIVECAL_FUZZ_SEED", "20261124"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, derandomize=False, print_blob=True,
                suppress_health_check=list(HealthCheck))

DQ = ["segment", "locked", "t", "v_d", "v_q", "i_d", "i_q"]
OPTIONAL = ["w_m", "temperature", "theta_e", "serial"]
PHASE = ["segment", "locked", "t", "i_a", "i_b", "i_c", "v_a", "v_b", "v_c", "theta_e", "theta_m"]
#: What may be done to a column.
MUTATIONS = ["drop", "int", "bool", "complex", "text", "numtext", "timestamp", "duration", "list", "nan", "inf",
             "none", "category", "matrix", "short", "constant", "huge", "degrees", "reverse"]
#: What may be done to a file's bytes.
CORRUPTIONS = ["none"] * 6 + ["truncate", "flip", "empty", "garbage"]


def _base(rng: np.random.Generator, n: int, phase: bool, extras: list[str]) -> dict[str, np.ndarray]:
    """A plausible table of ``n`` rows (one to three segments), as float/text numpy columns."""
    cuts = np.sort(rng.choice(np.arange(1, max(n, 2)), size=min(int(rng.integers(0, 3)), max(n - 1, 0)),
                               replace=False)) if n > 1 else np.array([], dtype=int)
    seg_id = np.searchsorted(cuts, np.arange(n), side="right")
    names = np.array(["d", "q step", "spin"], dtype=object)
    fs = float(rng.choice([1e3, 2e4, 1e5]))
    t = np.arange(n) / fs
    cols: dict[str, np.ndarray] = {"segment": names[seg_id], "locked": (seg_id < 2).astype(float), "t": t}
    if phase:
        theta = rng.choice([0.0, 300.0, 3000.0]) * t + rng.uniform(0, 6)
        if rng.random() < 0.5:
            theta = np.mod(theta, 2 * np.pi)
        i_d, i_q = rng.normal(0, 1, n), rng.normal(0, 1, n)
        for p, (d, q) in (("i", (i_d, i_q)), ("v", (rng.normal(0, 5, n), rng.normal(0, 5, n)))):
            alpha = d * np.cos(theta) - q * np.sin(theta)
            beta = d * np.sin(theta) + q * np.cos(theta)
            cols[f"{p}_a"], cols[f"{p}_b"] = alpha, -0.5 * alpha + math.sqrt(3) / 2 * beta
            cols[f"{p}_c"] = -cols[f"{p}_a"] - cols[f"{p}_b"] + rng.normal(0, 1e-3, n)
        cols["theta_e"] = theta
        if rng.random() < 0.3:
            cols["theta_m"] = cols.pop("theta_e") / 4.0
    else:
        for c in ("v_d", "v_q"):
            cols[c] = rng.normal(0, 5, n)
        for c in ("i_d", "i_q"):
            cols[c] = rng.normal(0, 0.01, n)
    for c in extras:
        cols[c] = (np.array(["SN7"] * n, dtype=object) if c == "serial" else
                   np.full(n, 40.0) if c == "temperature" else rng.normal(0, 1, n))
    return cols


def _mutate(cols: dict, name: str, how: str, rng: np.random.Generator, fmt: str) -> None:
    """Change column ``name`` in place as ``how`` says (some changes only where ``fmt`` can hold them)."""
    if name not in cols:
        return
    x = cols[name]
    if not isinstance(x, np.ndarray) or x.ndim != 1:
        return
    n = x.shape[0]
    if how == "drop":
        del cols[name]
    elif how == "int":
        cols[name] = np.round(pd.to_numeric(x, errors="coerce")).astype(np.int64) if x.dtype.kind == "f" and np.all(
            np.isfinite(x)) else x
    elif how == "bool":
        cols[name] = rng.random(n) < 0.5
    elif how == "complex" and fmt != "parquet":
        cols[name] = x + 1j * rng.normal(0, 1, n) if x.dtype.kind == "f" else x
    elif how == "text":
        cols[name] = np.array([rng.choice(["abc", "", " ", "1,5", "nan", "1e400", "-"]) for _ in range(n)],
                              dtype=object)
    elif how == "numtext" and x.dtype.kind == "f":
        cols[name] = np.array([repr(float(v)) for v in x], dtype=object)
    elif how in ("timestamp", "duration") and fmt != "mat" and x.dtype.kind == "f" and np.all(np.isfinite(x)):
        delta = pd.to_timedelta(np.clip(x, -1e3, 1e3) * 1e9, unit="ns").to_numpy()
        cols[name] = delta + np.datetime64("2024-01-01T00:00:00", "ns") if how == "timestamp" else delta
    elif how == "list" and n:
        width = int(rng.integers(0, 3))
        out = np.empty(n, dtype=object)
        for k in range(n):
            out[k] = list(rng.normal(0, 1, width)) if fmt != "mat" else rng.normal(0, 1, width)
        cols[name] = out
    elif how in ("nan", "inf", "none") and n:
        y = x.astype(object) if how == "none" else (x.astype(float) if x.dtype.kind in "fiub" else x.copy())
        rows = rng.choice(n, size=int(rng.integers(1, n + 1)), replace=False)
        if how == "nan" and rng.random() < 0.5:
            rows = np.arange(0, n, int(rng.integers(2, 5)))
        y[rows] = None if how == "none" or y.dtype.kind in "mM" else (np.nan if how == "nan" else rng.choice([np.inf, -np.inf]))
        cols[name] = y
    elif how == "category" and fmt == "parquet":
        cols[name] = pd.Categorical(np.asarray(x).astype(str))
    elif how == "matrix" and fmt in ("mat", "dict"):
        cols[name] = np.stack([x, x], axis=1) if rng.random() < 0.5 or n % 2 else x.reshape(n // 2, 2)
    elif how == "short" and fmt in ("mat", "dict") and n:
        cols[name] = x[: int(rng.integers(0, n))]
    elif how == "constant":
        cols[name] = np.zeros(n) if x.dtype.kind == "f" else x
    elif how == "huge" and x.dtype.kind == "f":
        with np.errstate(over="ignore"):
            cols[name] = x * float(rng.choice([1e300, 1e-300, -1e200]))
    elif how == "degrees" and x.dtype.kind == "f":
        cols[name] = np.mod(np.degrees(x), 360.0)
    elif how == "reverse":
        cols[name] = x[::-1].copy()


def _encode(cols: dict, fmt: str, rng: np.random.Generator) -> bytes:
    """The table as a file's bytes."""
    if fmt == "csv":
        buf = io.StringIO()
        pd.DataFrame({k: pd.Series(v) for k, v in cols.items()}).to_csv(buf, index=False)
        return buf.getvalue().encode()
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        arrays = {}
        for k, v in cols.items():
            try:
                arrays[k] = pa.array(v, from_pandas=True) if not isinstance(v, pd.Categorical) else \
                    pa.DictionaryArray.from_pandas(v)
            except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, TypeError, ValueError):
                arrays[k] = pa.array([str(x) for x in v])
        lengths = {len(a) for a in arrays.values()}
        if len(lengths) > 1:
            return b""
        buf = io.BytesIO()
        pq.write_table(pa.table(arrays) if arrays else pa.table({}), buf)
        return buf.getvalue()
    from scipy.io import savemat

    buf = io.BytesIO()
    out = {}
    for k, v in cols.items():
        if isinstance(v, np.ndarray) and v.dtype == object and v.size and all(isinstance(x, str) for x in v):
            out[k] = v
        elif isinstance(v, np.ndarray) and v.dtype == object:
            out[k] = np.array([np.nan if x is None else x for x in v], dtype=object)
        else:
            out[k] = v
    if rng.random() < 0.1:
        out = {"bench": out}  # all of it one struct
    savemat(buf, out, oned_as=str(rng.choice(["column", "row"])))
    return buf.getvalue()


def _corrupt(content: bytes, how: str, rng: np.random.Generator) -> bytes:
    if how == "truncate" and content:
        return content[: int(rng.integers(0, len(content)))]
    if how == "flip" and content:
        b = bytearray(content)
        for k in rng.choice(len(b), size=min(len(b), int(rng.integers(1, 8))), replace=False):
            b[k] = int(rng.integers(0, 256))
        return bytes(b)
    if how == "empty":
        return b""
    if how == "garbage":
        return rng.integers(0, 256, int(rng.integers(1, 400))).astype(np.uint8).tobytes()
    return content


@st.composite
def tables(draw, fmt: str):
    """(columns, the numpy generator's seed, corruption) of one generated input for format ``fmt``."""
    value_seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(value_seed)
    n = draw(st.integers(0, 40))
    phase = draw(st.booleans())
    extras = draw(st.lists(st.sampled_from(OPTIONAL + ["x", "i_dc"]), max_size=3, unique=True))
    cols = _base(rng, n, phase, extras)
    names = draw(st.lists(st.sampled_from(sorted(cols) + ["i_d", "t"]), max_size=4))
    for name in names:
        how = draw(st.sampled_from(MUTATIONS))
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            try:
                _mutate(cols, name, how, rng, fmt)
            except (ValueError, TypeError, OverflowError):
                pass  # a change the generator cannot make to this column
    corruption = draw(st.sampled_from(CORRUPTIONS)) if fmt != "dict" else "none"
    return cols, value_seed, corruption


def _valid(bench: BenchData) -> None:
    assert bench.segments and math.isfinite(bench.sample_rate) and bench.sample_rate > 0
    for seg in bench.segments:
        assert seg.t.ndim == 1 and seg.t.shape[0] >= 2 and seg.t.dtype == np.float64
        assert np.all(np.diff(seg.t) > 0)
        for arr in (seg.voltages, seg.currents):
            assert arr.dtype == np.float64 and arr.shape == (seg.t.shape[0], 2) and np.all(np.isfinite(arr))
        assert isinstance(seg.locked, bool) and isinstance(seg.at_rest, bool)


def _check_one(load, source: str, what: str) -> None:
    """``load()`` gives a valid BenchData or a one-line DrivecalError naming ``source``; nothing else escapes."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            try:
                bench = load()
            except DrivecalError as exc:
                message = str(exc)
                assert "\n" not in message and message.startswith(source), message
                return
        _valid(bench)
    except Exception as exc:
        raise AssertionError(f"fuzz seed {SEED}: {what}: {type(exc).__name__}: {exc}") from exc


@pytest.mark.parametrize("fmt", ["csv", "parquet", "mat"])
def test_fuzz_files(fmt):
    @seed(SEED)
    @FUZZ
    @given(tables(fmt))
    def run(case):
        cols, value_seed, corruption = case
        rng = np.random.default_rng(value_seed + 1)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # writing the file is not under test
                content = _encode(cols, fmt, rng)
        except Exception:  # a table the writer itself cannot store: nothing to read
            return
        content = _corrupt(content, corruption, rng)
        path = Path(f"fuzz.{fmt}")
        kw = {"nominal_R": 0.45} if value_seed % 2 else {}
        _check_one(lambda: bench_from_frame(read_table(path, content), str(path), **kw), str(path),
                   f"{fmt} table {sorted(cols)} values seed {value_seed}, corruption {corruption}")

    run()


def test_fuzz_tables_in_memory():
    """Tables handed over as columns (the Python API), alone and as a fleet (benches_from_frames)."""
    @seed(SEED)
    @FUZZ
    @given(tables("dict"))
    def run(case):
        cols, value_seed, _ = case
        _check_one(lambda: bench_from_frame(cols, "table"), "table", f"columns {sorted(cols)} seed {value_seed}")
        other = dict(cols)  # laid out alike: checked on the vectorised path when the first one passes
        if "i_d" in other and other["i_d"].dtype.kind == "f" and other["i_d"].ndim == 1:
            other["i_d"] = other["i_d"] * 1e4
        frames = [cols, other]
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                results = benches_from_frames(frames, ["table0", "table1"], nominal_R=0.45)
        except Exception as exc:
            raise AssertionError(f"fuzz seed {SEED}: fleet, columns {sorted(cols)} seed {value_seed}: "
                                 f"{type(exc).__name__}: {exc}") from exc
        for result, source in zip(results, ["table0", "table1"]):
            if isinstance(result, DrivecalError):
                assert str(result).startswith(source) and "\n" not in str(result)
            else:
                _valid(result)

    run()
