"""Reading bench files: CSV (any dialect), Parquet and MATLAB ``.mat`` into columns of numpy arrays, unchecked.

The checks live in :mod:`._checks`; what is read here is a plain mapping of
column name to a 1-D array per column (:data:`Columns`).
"""

from __future__ import annotations

import io
import re
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import DataError
from ._values import time_in_seconds

if TYPE_CHECKING:
    import pandas as pd

#: Bench tables by suffix: the files drivecal reads and writes with its own columns.
TABLE_FORMATS = (".csv", ".parquet", ".mat")
#: Every file format read, by suffix: the tables and the bench logs (MDF4, TDMS, HDF5; see ``._logs``).
FORMATS = TABLE_FORMATS + (".mf4", ".mdf", ".tdms", ".h5", ".hdf5")

#: A bench table as read: column name -> one numpy array per column, all of one length (floats,
#: integers, or objects for text). What every check works on: a DataFrame lookup costs ~0.1 ms,
#: which a fleet pays per column and motor.
Columns = dict


def columns_of(frame: pd.DataFrame | Columns, source: str = "bench data") -> Columns:
    """The columns of a bench table as 1-D numpy arrays (a DataFrame, or a mapping of equal-length columns).

    A time column ``t`` of a timestamp or duration type becomes float64 seconds from its first
    sample (:func:`._values.time_in_seconds`).
    """
    pd = sys.modules.get("pandas")  # not imported: ``frame`` is no DataFrame (and importing pandas costs)
    if pd is not None and isinstance(frame, pd.DataFrame):
        out = {}
        for c in frame.columns:
            series = frame[c]
            if isinstance(series, pd.DataFrame):
                raise DataError(f"{source}: column '{c}' appears more than once; give each column one name.")
            if isinstance(series.dtype, pd.DatetimeTZDtype):
                series = series.dt.tz_convert("UTC").dt.tz_localize(None)
            out[str(c)] = series.to_numpy()
    else:
        out = {str(c): np.atleast_1d(np.asarray(v)) for c, v in frame.items()}
        for name, v in out.items():
            if v.ndim != 1:
                shape = " x ".join(str(n) for n in v.shape)
                raise DataError(f"{source}: column '{name}' is a {shape} array; give one value per sample in every "
                                "column (a vector: save each column of a matrix as a column of its own).")
        lengths = {k: v.shape[0] for k, v in out.items()}
        if len(set(lengths.values())) > 1:
            raise DataError(f"{source}: the columns must be 1-D and of one length, got lengths {lengths}; "
                            "give one value per sample in every column.")
    if "t" in out:
        out["t"] = time_in_seconds(out["t"])
    return out


def read_table(path: Path, content: bytes | None = None, *, delimiter: str | None = None,
               decimal: str | None = None) -> Columns:
    """The raw columns of a bench file (.csv, .parquet, .mat), unchecked.

    ``content``: the file's bytes when already read (a fleet hashes them too),
    so the file is read once. ``delimiter``, ``decimal``: a CSV file's field separator and decimal
    mark (None: detected, :func:`csv_dialect`).
    """
    suffix = path.suffix.lower()
    if suffix not in TABLE_FORMATS:
        raise DataError(f"{path}: unknown bench-file format '{suffix}'; use one of {', '.join(FORMATS)}"
                        + (" (a bench log: give its format file, --format)." if suffix in FORMATS else "."))
    if content is None and not path.is_file():
        raise DataError(f"{path}: no such file; check the path.")
    import pyarrow as pa

    try:
        if suffix == ".parquet":
            # Arrow columns straight to numpy: no DataFrame (pandas' conversion and lookups cost
            # ~1 ms a file, which a fleet pays per motor). Nulls become NaN (numbers) or None (text).
            table = _read_parquet(path if content is None else pa.BufferReader(content))
            return {name: _arrow_to_numpy(column) for name, column in zip(table.column_names, table.columns)}
        if suffix == ".csv":
            content = content if content is not None else path.read_bytes()
            if delimiter is None or decimal is None:
                found = csv_dialect(content[:8192])
                delimiter, decimal = delimiter or found[0], decimal or found[1]
            return _read_csv(content, delimiter, decimal)
        return _read_mat(path, path if content is None else io.BytesIO(content))
    except DataError:
        raise
    except Exception as exc:  # a parser's own error: say which file and what it said, on one line
        said = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise DataError(f"{path}: cannot be read as a {suffix[1:]} bench file ({said}); check that the file is "
                        f"complete and a {suffix[1:]} file (write it again).") from None


#: Arrow column types of a CSV file read as pandas would read it (numbers as float64 or int64, True/False as
#: bool; the text columns of :data:`TEXT_COLUMNS` are labels); a file with a column of any other type (text
#: elsewhere, a timestamp, a column with no value) goes to pandas.
_ARROW_CSV_KINDS = ("int64", "double", "bool")


def _read_csv(content: bytes, delimiter: str, decimal: str) -> Columns:
    """A CSV bench file's columns: by Arrow's reader where it reads the file as pandas does, else by pandas.

    Arrow's reader is ~3x faster a file (which a fleet of CSV files pays per motor) and its numbers are
    pandas' to the bit (both round each decimal correctly). pandas decides where they could differ: a
    name given twice (pandas renames the second), a column read as a timestamp or with no value at all,
    and whatever Arrow cannot parse (so the error a user reads is pandas', as before). Empty text is
    None, as in a Parquet file. The text columns are the file's text, as written: a serial ``000123``
    stays ``000123`` (pandas read it as the number 123).
    """
    import pyarrow as pa
    import pyarrow.csv as pa_csv

    labels = pa.dictionary(pa.int32(), pa.string())
    try:
        table = pa_csv.read_csv(
            pa.BufferReader(content), read_options=pa_csv.ReadOptions(use_threads=False),
            parse_options=pa_csv.ParseOptions(delimiter=delimiter),
            convert_options=pa_csv.ConvertOptions(decimal_point=decimal, strings_can_be_null=True,
                                                  column_types={name: labels for name in TEXT_COLUMNS}))
    except (pa.ArrowException, ValueError):
        table = None
    if (table is not None and len(set(table.column_names)) == len(table.column_names)
            and all(pa.types.is_dictionary(f.type) or str(f.type) in _ARROW_CSV_KINDS for f in table.schema)):
        return columns_of({name: _arrow_to_numpy(column) for name, column in zip(table.column_names, table.columns)})
    import pandas as pd

    return columns_of(pd.read_csv(io.BytesIO(content), sep=delimiter, decimal=decimal))


#: A decimal comma between digits (``1,25``), as a semicolon-separated export writes numbers.
_DECIMAL_COMMA = re.compile(rb"(?:^|[;\t|])\s*[-+]?\d+,\d+(?:[eE][-+]?\d+)?\s*(?=[;\t|\r\n]|$)", re.M)


def csv_dialect(head: bytes) -> tuple[str, str]:
    """A CSV file's field separator and decimal mark, from its first bytes.

    The header line decides the separator: ',' unless it has none and has ';', a tab or '|'
    (in that order); with another separator than ',', numbers written as ``1,25`` mean a decimal
    comma. A plain comma-separated file is read as before.
    """
    first = head.split(b"\n", 1)[0]
    if b"," in first:
        return ",", "."
    delimiter = next((d for d in (";", "\t", "|") if d.encode() in first), ",")
    if delimiter == ",":
        return ",", "."
    return delimiter, "," if _DECIMAL_COMMA.search(head) else "."


#: Text columns of a bench file: read from Parquet as dictionaries (a few labels, not one Python
#: string per row: 0.15 ms a file, which a fleet pays per motor).
TEXT_COLUMNS = ("segment", "serial")


def _read_parquet(source: Any) -> Any:
    """A Parquet file as an Arrow table, the text columns of :data:`TEXT_COLUMNS` it has dictionary-encoded."""
    import pyarrow.parquet as pq

    def read(text):
        return pq.ParquetFile(source, read_dictionary=list(text)).read(use_threads=False)

    # Naming a column the file lacks fails; try the usual sets before opening the file twice.
    for text in (TEXT_COLUMNS, TEXT_COLUMNS[:1]):
        try:
            return read(text)
        except KeyError:
            if hasattr(source, "seek"):
                source.seek(0)
    names = set(pq.ParquetFile(source).schema_arrow.names)
    if hasattr(source, "seek"):
        source.seek(0)
    return read([c for c in TEXT_COLUMNS if c in names])


def _arrow_to_numpy(column: Any) -> np.ndarray:
    """One Arrow column as numpy: dictionary-encoded text as an object array of its labels (None where null)."""
    import pyarrow as pa

    if isinstance(column, pa.ChunkedArray):
        column = column.chunk(0) if column.num_chunks == 1 else column.combine_chunks()
    if not pa.types.is_dictionary(column.type):
        numbers = _numbers(column)
        return numbers if numbers is not None else column.to_numpy(zero_copy_only=False)
    labels = np.empty(len(column.dictionary) + 1, dtype=object)
    labels[:-1] = column.dictionary.to_pylist()  # the last label (None) is where a row is null
    indices = column.indices if column.null_count == 0 else column.indices.fill_null(len(labels) - 1)
    numbers = _numbers(indices)
    return labels[numbers if numbers is not None else indices.to_numpy()]


def _numbers(array: Any) -> np.ndarray | None:
    """A numeric Arrow array without nulls as a numpy view of its values (read-only, as ``to_numpy`` gives it);
    None for any other. Arrow's own conversion imports pandas (~0.3 s, which a fit needs for nothing else)."""
    import pyarrow as pa

    if array.null_count or not (pa.types.is_integer(array.type) or pa.types.is_floating(array.type)):
        return None
    dtype = np.dtype(array.type.to_pandas_dtype())
    return np.frombuffer(array.buffers()[1], dtype=dtype, count=len(array), offset=array.offset * dtype.itemsize)


def _read_mat(path: Path, source: Path | io.BytesIO) -> Columns:
    """The columns of a MATLAB bench file (``source``: its path or its bytes; ``path`` names it in messages).

    One variable per column (vectors, a cell array of text for ``segment``), or all of them as the
    fields of one struct (``bench.t``, ``bench.i_d``, ...), read as if they were variables.
    """
    from scipy.io import loadmat
    from scipy.io.matlab import MatReadError

    content = source.getvalue() if isinstance(source, io.BytesIO) else Path(source).read_bytes()
    defect = mat5_defect(content)
    if defect is not None:
        raise DataError(f"{path}: is truncated or corrupted ({defect}); save it again with MATLAB's save (-v7 or "
                        "earlier) or scipy.io.savemat.")
    source = io.BytesIO(content)
    try:
        raw = {k: v for k, v in loadmat(source, squeeze_me=True).items() if not k.startswith("__")}
    except NotImplementedError as exc:  # MATLAB -v7.3 (HDF5)
        raise DataError(f"{path}: is a MATLAB -v7.3 (HDF5) file, which is not read ({' '.join(str(exc).split())}); "
                        "save it with save(..., '-v7').") from None
    except (MatReadError, ValueError, TypeError, OSError, EOFError, KeyError, IndexError, OverflowError,
            MemoryError, UnicodeDecodeError, AttributeError) as exc:
        said = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise DataError(f"{path}: is truncated or not a MAT file (scipy.io.loadmat: {said}); save it again with "
                        "MATLAB's save (-v7 or earlier) or scipy.io.savemat.") from None
    structs = [k for k, v in raw.items() if isinstance(v, np.ndarray) and v.dtype.names]
    if len(raw) == 1 and structs:
        name = structs[0]
        struct = raw[name]
        if struct.size != 1:
            raise DataError(f"{path}: holds one struct array '{name}' of {struct.size} elements; save one struct "
                            "(or one variable per column).")
        raw = {str(f): struct[f].item() if struct.ndim == 0 else struct[f].ravel()[0] for f in struct.dtype.names}
        raw = {k: v for k, v in raw.items()}
        structs = [k for k, v in raw.items() if isinstance(v, np.ndarray) and v.dtype.names]
    if structs:
        raise DataError(f"{path}: variable '{structs[0]}' is a struct among other variables; save each column as a "
                        "variable of its own (or all of them as the fields of one struct).")
    if not raw:
        raise DataError(f"{path}: holds no variables; save one vector per column (segment, locked, t, ...).")
    raw = {k: np.asarray(v) if not isinstance(v, str) else np.array([v], dtype=object) for k, v in raw.items()}
    for k, v in raw.items():
        if v.ndim > 1:
            shape = " x ".join(str(n) for n in v.shape)
            raise DataError(f"{path}: variable '{k}' is a {shape} matrix; save each column as a vector of its own "
                            "(one value per sample).")
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
        if arr.dtype.kind in "OUS":
            columns[k] = np.array([_mat_cell(x) for x in arr], dtype=object)
        elif arr.dtype.kind in "iuf":
            columns[k] = arr.astype(float)
        else:  # booleans, complex numbers: as they are, for the checks to name
            columns[k] = arr
    return columns


def _mat_cell(x: Any) -> Any:
    """One element of a cell array or char array: text stripped, a 1-element number as the number, else as is."""
    if isinstance(x, (str, np.str_)):
        return str(x).strip()
    if isinstance(x, bytes):
        return x.decode("latin-1").strip()
    if isinstance(x, np.ndarray) and x.size == 1 and x.dtype.kind in "iuf":
        return float(x.ravel()[0])
    return x


#: MAT-file v5 data types (miINT8 ... miUTF32; 8, 10 and 11 are reserved).
_MAT5_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18})


def mat5_defect(content: bytes) -> str | None:
    """What makes a MAT-file v5 stream malformed (a tag of an unknown type, an element running past its
    end, a compressed element that does not inflate), or None when its elements are well formed or it is
    not a v5 file.

    scipy's reader trusts the tags and can crash the process (a segmentation fault) on a corrupted one,
    so every element's tag is walked here first, nested and compressed ones included.
    """
    import struct
    import zlib

    if len(content) < 128 or content[126:128] not in (b"IM", b"MI") or content[:4] == b"\x89HDF":
        return None
    if content[124:126] not in (b"\x00\x01", b"\x01\x00"):
        return None  # -v7.3 (HDF5) and others: scipy says what they are
    order = "<" if content[126:128] == b"IM" else ">"

    def walk(data: bytes, start: int, stop: int, depth: int) -> str | None:
        if depth > 32:
            return "elements nested too deep"
        pos = start
        while pos < stop:
            if stop - pos < 8:
                return f"{stop - pos} stray bytes at byte {pos}"
            first, second = struct.unpack_from(order + "II", data, pos)
            small = first >> 16
            if small:  # small data element: type and size in one word, at most 4 bytes of data
                kind, size = first & 0xFFFF, small
                if kind not in _MAT5_TYPES or size > 4 or kind in (14, 15):
                    return f"a bad element tag at byte {pos}"
                pos += 8
                continue
            kind, size = first, second
            if kind not in _MAT5_TYPES:
                return f"an element of unknown type {kind} at byte {pos}"
            body = pos + 8
            if size > stop - body:
                return f"an element of {size} bytes at byte {pos} runs past the end"
            if kind == 14:
                found = walk(data, body, body + size, depth + 1)
                if found:
                    return found
            elif kind == 15:
                try:
                    inner = zlib.decompress(data[body:body + size])
                except zlib.error:
                    return f"a compressed element at byte {pos} does not inflate"
                found = walk(inner, 0, len(inner), depth + 1)
                if found:
                    return found
            pos = body + size + (-size % 8 if kind != 15 else 0)
        return None

    return walk(content, 128, len(content), 0)
