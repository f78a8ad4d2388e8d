"""File schemas (plan, motor and format files): strict pydantic models, physical quantities as fields, one-sentence errors.

Base layer, beside ``_units`` (which parses and prints the quantities without pydantic): only the modules that
read a file import this one, so a command that reads none (``drivecal fit FILE`` with the default motor) does
not import pydantic (~0.2 s on a 2-core machine).
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, ValidationError

from ._units import parse_quantity
from .errors import DrivecalError


def quantity(name: str) -> Any:
    """The type of a field holding a ``name`` quantity (a key of the units table): a float in SI,
    read from a number or a ``"<number> <prefix><unit>"`` string (:func:`parse_quantity`)."""
    return Annotated[float, BeforeValidator(lambda v: parse_quantity(v, name))]


class StrictModel(BaseModel):
    """A file's schema: unknown keys refused, values frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def _location(loc: tuple) -> str:
    parts = []
    for item in loc:
        if isinstance(item, int):
            parts[-1] = f"{parts[-1]}[{item}]" if parts else f"[{item}]"
        elif isinstance(item, str) and (item.startswith(("function-", "tagged-union[", "nullable["))
                                         or (item.startswith("<") and item.endswith(">"))):
            continue  # pydantic's validator and union branch names (tags are written '<tag>') are no keys
        else:
            text = str(item)
            # a key that is not one plain printable word is shown quoted and escaped: the message stays one line
            parts.append(text if text and text.isprintable() and "'" not in text and "." not in text
                         and text.strip() == text else repr(text))
    return ".".join(parts)


def explain(error: ValidationError, path: str, kind: str, keys: str) -> DrivecalError:
    """One sentence out of pydantic's errors: the most specific one, with its key."""
    errors = error.errors()
    # A value that was valid as one branch of a union shows failures of the others;
    # an unknown key or a unit message is what the user needs.
    def rank(e):
        # Among equals the deepest location is the most specific (a waveform table's key).
        return {"extra_forbidden": 0, "value_error": 1, "missing": 2}.get(e["type"], 3), -len(e["loc"])

    e = min(errors, key=rank)
    where = _location(e["loc"])
    if e["type"] == "extra_forbidden":
        return DrivecalError(f"{path}: unknown key '{where}' in the {kind} file; the known keys are {keys}.")
    if e["type"] == "missing":
        return DrivecalError(f"{path}: '{where}' is missing; add it to the {kind} file.")
    msg = e["msg"].removeprefix("Value error, ")
    return DrivecalError(f"{path}: '{where}': {msg}.")
