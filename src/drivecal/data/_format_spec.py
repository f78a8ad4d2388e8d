"""The format file's schema (pydantic): its tables and keys, checked with one-sentence errors.

Apart from ``_format_file`` so that reading a bench file without a format file does not import pydantic.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import ValidationError, create_model

from ..errors import DataError
from .._schema import StrictModel, explain, quantity
from ._log_units import COLUMN_QUANTITY, MAPPABLE

_Columns = create_model("_Columns", __base__=StrictModel, **{c: (str | None, None) for c in MAPPABLE})
_Units = create_model("_Units", __base__=StrictModel, **{c: (str | None, None) for c in COLUMN_QUANTITY})


class _Window(StrictModel):
    name: str
    start: quantity("time")
    stop: quantity("time")
    locked: bool | None = None


class _Csv(StrictModel):
    delimiter: Literal[",", ";", "\t", "|", " "] | None = None
    decimal: Literal[".", ","] | None = None


class _FormatSpec(StrictModel):
    columns: _Columns
    units: _Units = _Units()
    segment: list[_Window] = []
    csv: _Csv = _Csv()


_KEYS = ("[columns] " + ", ".join(MAPPABLE) + "; [units] the same numeric names; [[segment]] name, start, stop, "
         "locked; [csv] delimiter, decimal")


def format_spec(raw: dict, source: str) -> Any:
    """A format file's table (as TOML gives it) checked against the schema: its ``columns``, ``units``, ``segment``
    and ``csv`` (pydantic models; times in s).

    Raises:
        DataError: one sentence naming the file, the key and the fix.
    """
    if "columns" not in raw:
        raise DataError(f"{source}: the format file has no [columns] table; map drivecal's columns to the log's "
                        "channels there (i_d = \"Id\", ...).")
    try:
        return _FormatSpec.model_validate(raw)
    except ValidationError as exc:
        raise DataError(str(explain(exc, source, "format", _KEYS))) from None
