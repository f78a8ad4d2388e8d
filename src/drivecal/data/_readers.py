"""Reading bench files: CSV, Parquet and MATLAB ``.mat`` into columns of numpy arrays, unchecked.

The checks live in :mod:`._checks`; what is read here is a plain mapping of
column name to a 1-D array per column (:data:`Columns`).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa  # loaded by pandas already

from ..errors import DataError

#: File formats by suffix.
FORMATS = (".csv", ".parquet", ".mat")

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
            table = _read_parquet(path if content is None else pa.BufferReader(content))
            return {name: _arrow_to_numpy(column) for name, column in zip(table.column_names, table.columns)}
        source = path if content is None else io.BytesIO(content)
        if suffix == ".csv":
            return columns_of(pd.read_csv(source))
        return _read_mat(path, source)
    except DataError:
        raise
    except Exception as exc:  # a parser's own error: say which file and what it said
        raise DataError(f"{path}: cannot be read as a {suffix[1:]} bench file ({exc}).") from None


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
    if isinstance(column, pa.ChunkedArray):
        column = column.chunk(0) if column.num_chunks == 1 else column.combine_chunks()
    if not pa.types.is_dictionary(column.type):
        return column.to_numpy(zero_copy_only=False)
    labels = np.empty(len(column.dictionary) + 1, dtype=object)
    labels[:-1] = column.dictionary.to_pylist()  # the last label (None) is where a row is null
    indices = column.indices if column.null_count == 0 else column.indices.fill_null(len(labels) - 1)
    return labels[indices.to_numpy()]


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

