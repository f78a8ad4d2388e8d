"""Plan files (TOML), validated with pydantic.

Every physical value is either a plain number in SI units or a string with a
unit, e.g. ``duration = "10 ms"``, ``v_d = "8 V"`` (parsed in ``drivecal._units``).
A wrong key or a unit of the wrong kind is refused with one sentence naming the
file, the key and the fix. The schema is documented in the README ("Plan
files") and exemplified in ``examples/``. Motor files are read in
``drivecal.data``.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import Field, ValidationError

from . import _waveforms as waveforms
from ..errors import DrivecalError
from .._units import StrictModel, explain, quantity, read_toml
from ._plan import Plan, Segment

Seconds, Hertz, Volts, Amperes = quantity("time"), quantity("frequency"), quantity("voltage"), quantity("current")


class StepSpec(StrictModel):
    """``initial`` before ``delay``, ``level`` after."""

    kind: Literal["step"]
    level: Volts
    initial: Volts = 0.0
    delay: Seconds = 0.0


class ChirpSpec(StrictModel):
    kind: Literal["chirp"]
    amplitude: Volts
    f_start: Hertz
    f_stop: Hertz
    sweep: Literal["linear", "log"] = "linear"
    offset: Volts = 0.0
    phase: float = 0.0


class MultisineSpec(StrictModel):
    kind: Literal["multisine"]
    amplitude: Volts
    f_min: Hertz
    f_max: Hertz
    num_tones: int = 16
    offset: Volts = 0.0


class PrbsSpec(StrictModel):
    kind: Literal["prbs"]
    amplitude: Volts
    order: int = 9
    bit_rate: Hertz | None = None
    offset: Volts = 0.0
    seed: int = 1


class SamplesSpec(StrictModel):
    """A measured sequence: inline ``values`` (V) or a CSV ``file`` with a ``column``."""

    kind: Literal["samples"]
    values: list[float] | None = None
    file: str | None = None
    column: str | None = None


Waveform = Annotated[Union[StepSpec, ChirpSpec, MultisineSpec, PrbsSpec, SamplesSpec], Field(discriminator="kind")]


class SegmentSpec(StrictModel):
    name: str
    duration: Seconds
    locked: bool
    v_d: Union[Volts, Waveform] = 0.0
    v_q: Union[Volts, Waveform] = 0.0
    temperature: quantity("temperature") | None = None


class PlanSpec(StrictModel):
    sample_rate: Hertz = 20_000.0
    v_dc: Volts = 48.0
    current_limit: Amperes = 30.0
    max_speed: quantity("speed") | None = None
    segment: list[SegmentSpec] = Field(min_length=1)


def _axis(spec, n: int, sample_rate: float, base: Path, where: str) -> np.ndarray:
    if isinstance(spec, float):
        return np.full(n, spec)
    params = spec.model_dump(exclude={"kind"})
    if isinstance(spec, SamplesSpec):
        if (spec.values is None) == (spec.file is None):
            raise DrivecalError(f"{where}: a 'samples' waveform needs exactly one of 'values' or 'file'.")
        if spec.file is not None:
            import pandas as pd

            csv = base / spec.file
            try:
                frame = pd.read_csv(csv)
            except FileNotFoundError:
                raise DrivecalError(f"{where}: file '{csv}' not found; check 'file'.") from None
            column = spec.column or frame.columns[0]
            if column not in frame:
                raise DrivecalError(f"{where}: '{csv}' has no column '{column}'; check 'column'.")
            params = {"values": frame[column].to_numpy(dtype=float)}
        else:
            params = {"values": spec.values}
    try:
        return waveforms.GENERATORS[spec.kind](n, sample_rate, **params)
    except DrivecalError as exc:
        raise DrivecalError(f"{where}: {exc}") from None


def plan_from_dict(data: dict, source: str = "plan", base: Path | None = None) -> Plan:
    """A checked :class:`Plan` from the TOML table ``data``.

    Raises:
        DrivecalError: an unknown key, a wrong unit, a bad waveform or an
            infeasible plan, naming ``source`` and the key.
    """
    try:
        spec = PlanSpec.model_validate(data)
    except ValidationError as exc:
        keys = ", ".join(PlanSpec.model_fields) + " (per [[segment]]: " + ", ".join(SegmentSpec.model_fields) + ")"
        raise explain(exc, source, "plan", keys) from None
    base = base or Path(".")
    segments = []
    for i, s in enumerate(spec.segment):
        n = int(round(s.duration * spec.sample_rate))
        if n < 2:
            raise DrivecalError(
                f"{source}: segment[{i}] ('{s.name}') lasts {s.duration:g} s = {n} sample(s) at "
                f"{spec.sample_rate:g} Hz; make 'duration' at least two sample periods."
            )
        v_d = _axis(s.v_d, n, spec.sample_rate, base, f"{source}: segment[{i}].v_d")
        v_q = _axis(s.v_q, n, spec.sample_rate, base, f"{source}: segment[{i}].v_q")
        segments.append(Segment(s.name, s.duration, s.locked, v_d=v_d, v_q=v_q, temperature=s.temperature))
    plan = Plan(tuple(segments), sample_rate=spec.sample_rate, v_dc=spec.v_dc, current_limit=spec.current_limit,
                max_speed=spec.max_speed)
    try:
        return plan.check_feasible()
    except DrivecalError as exc:
        raise DrivecalError(f"{source}: {exc}") from None


def load_plan(path: str | Path) -> Plan:
    """Read and check a plan TOML file (schema in the README, examples in ``examples/``)."""
    return plan_from_dict(read_toml(path), str(path), Path(path).parent)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def plan_toml(plan: Plan, waveforms_spec: dict[tuple[str, str], dict] | None = None, header: str = "") -> str:
    """A plan as a plan file (the schema :func:`load_plan` reads), SI numbers.

    Args:
        plan: the plan; constant voltages are written as numbers (V).
        waveforms_spec: per ``(segment name, "v_d" | "v_q")``, the waveform
            table to write instead of the samples (e.g. ``{"kind": "chirp",
            ...}`` in SI units); a per-sample voltage without one is written as
            ``kind = "samples"`` with its values.
        header: comment lines put on top (without the ``#``).
    """
    specs = waveforms_spec or {}
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines += [
        f"sample_rate = {_toml_value(float(plan.sample_rate))}    # Hz",
        f"v_dc = {_toml_value(float(plan.v_dc))}    # V",
        f"current_limit = {_toml_value(float(plan.current_limit))}    # A",
    ]
    if plan.max_speed is not None:
        lines.append(f"max_speed = {_toml_value(float(plan.max_speed))}    # rad/s")
    for seg in plan.segments:
        lines += ["", "[[segment]]", f"name = {_toml_value(seg.name)}",
                  f"duration = {_toml_value(float(seg.duration))}    # s", f"locked = {_toml_value(bool(seg.locked))}"]
        if seg.temperature is not None:
            lines.append(f"temperature = {_toml_value(float(seg.temperature))}    # degC")
        tables = []
        for axis in ("v_d", "v_q"):
            value = getattr(seg, axis)
            if (seg.name, axis) in specs:
                tables.append((axis, specs[(seg.name, axis)]))
            elif np.ndim(value) == 0:
                lines.append(f"{axis} = {_toml_value(float(value))}    # V")
            else:
                tables.append((axis, {"kind": "samples", "values": [float(v) for v in value]}))
        for axis, table in tables:
            lines.append(f"[segment.{axis}]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def write_plan(path: str | Path, plan: Plan, waveforms_spec: dict[tuple[str, str], dict] | None = None,
               header: str = "") -> Path:
    """Write :func:`plan_toml` to ``path`` atomically (whole or not at all); the written file is re-read and checked."""
    from .._io import atomic_path

    text = plan_toml(plan, waveforms_spec, header)
    plan_from_dict(tomllib.loads(text), str(path), Path(path).parent)  # what we write must load
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def plan_to_dict(plan: Plan) -> dict[str, Any]:
    """A plan as JSON: sample rate (Hz), V_dc (V), current limit (A), segments."""
    segments = []
    for seg in plan.segments:
        entry = {"name": seg.name, "duration": seg.duration, "locked": seg.locked}
        if seg.temperature is not None:
            entry["temperature"] = float(seg.temperature)
        for axis in ("v_d", "v_q"):
            value = getattr(seg, axis)
            entry[axis] = float(value) if not hasattr(value, "__len__") else [float(v) for v in value]
        segments.append(entry)
    return {
        "sample_rate": plan.sample_rate,
        "v_dc": plan.v_dc,
        "current_limit": plan.current_limit,
        "segments": segments,
    }
