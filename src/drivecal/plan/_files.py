"""Plan files (TOML), validated with pydantic.

Every physical value is either a plain number in SI units or a string with a
unit, e.g. ``duration = "10 ms"``, ``v_d = "8 V"`` (parsed in ``drivecal._units``).
A wrong key or a unit of the wrong kind is refused with one sentence naming the
file, the key and the fix. The schema is documented in docs/plans.md ("Plan
files") and exemplified in ``examples/``. Motor files are read in
``drivecal.data``.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import AfterValidator, Discriminator, Field, Tag, ValidationError, field_validator

from . import _waveforms as waveforms
from ..errors import DrivecalError
from .._schema import StrictModel, explain, quantity
from .._units import read_toml
from ._plan import Inverter, Plan, Segment, inverter_setting_error

Seconds, Hertz, Volts, Amperes = quantity("time"), quantity("frequency"), quantity("voltage"), quantity("current")


class StepSpec(StrictModel):
    """``initial`` before ``delay``, ``level`` after."""

    kind: Literal["step"]
    level: Volts
    initial: Volts = 0.0
    delay: Seconds = 0.0


class RampSpec(StrictModel):
    """``initial`` before ``delay``, then a straight line to ``level`` over ``rise``, ``level`` after."""

    kind: Literal["ramp"]
    level: Volts
    rise: Seconds
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


#: The waveform kinds of a ``[segment.v_d]`` / ``[segment.v_q]`` table.
KINDS = ("step", "ramp", "chirp", "multisine", "prbs", "samples")


def _no_kind(table: dict) -> dict:
    kinds = ", ".join(f"'{k}'" for k in KINDS)
    if "kind" not in table:
        raise ValueError(f"a waveform table needs a 'kind', one of {kinds}")
    kind = table["kind"]
    shown = repr(kind) if len(repr(kind)) <= 40 else repr(kind)[:37] + "..."
    raise ValueError(f"unknown waveform kind {shown}; write kind = one of {kinds}")


def _axis_tag(value: Any) -> str:
    """The branch of a segment's v_d/v_q: a constant voltage, a waveform table by its kind, or a table of no
    known kind (refused with the kinds). Tags are written '<tag>', which error locations leave out."""
    if not isinstance(value, dict):
        return "<voltage>"
    kind = value.get("kind")
    return f"<{kind}>" if isinstance(kind, str) and kind in KINDS else "<unknown kind>"


#: A segment's voltage on one axis: a constant (number or "8 V") or a waveform table.
Axis = Annotated[
    Union[
        Annotated[Volts, Tag("<voltage>")],
        Annotated[StepSpec, Tag("<step>")],
        Annotated[RampSpec, Tag("<ramp>")],
        Annotated[ChirpSpec, Tag("<chirp>")],
        Annotated[MultisineSpec, Tag("<multisine>")],
        Annotated[PrbsSpec, Tag("<prbs>")],
        Annotated[SamplesSpec, Tag("<samples>")],
        Annotated[dict, AfterValidator(_no_kind), Tag("<unknown kind>")],
    ],
    Discriminator(_axis_tag),
]


class SegmentSpec(StrictModel):
    name: str
    duration: Seconds
    locked: bool
    v_d: Axis = 0.0
    v_q: Axis = 0.0
    temperature: quantity("temperature") | None = None
    continues: bool = Field(default=False, alias="continue")
    inverter: Literal["on", "off"] = "on"


class InverterSpec(StrictModel):
    """The ``[inverter]`` table: what ``drivecal simulate`` runs the plan on (:class:`Inverter`)."""

    model: Literal["averaged", "switching"] = "averaged"
    modulation: Literal["svpwm", "sine"] = "svpwm"
    dead_time: Seconds = 0.0
    device_drop: Volts = 0.0


class PlanSpec(StrictModel):
    sample_rate: Hertz = 20_000.0
    v_dc: Volts = 48.0
    current_limit: Amperes = 30.0
    max_speed: quantity("speed") | None = None
    max_torque: quantity("torque") | None = None
    current_noise: Amperes | None = None
    inverter: InverterSpec = InverterSpec()
    segment: list[SegmentSpec]

    @field_validator("inverter", mode="before")
    @classmethod
    def _a_table(cls, value: Any) -> Any:
        if not isinstance(value, (dict, InverterSpec)):
            raise ValueError("write the inverter as an [inverter] table with model = \"averaged\" or "
                             "\"switching\", modulation, dead_time and device_drop")
        return value


#: The most samples a plan may hold (all segments): 500 s at 20 kHz. More is a typo in a duration or a
#: sample rate, and would not fit in memory.
MAX_SAMPLES = 10_000_000
#: Absolute zero [degC].
_ABSOLUTE_ZERO = -273.15


def _check_spec(spec: PlanSpec, source: str) -> list[int]:
    """What pydantic's types do not say: signs, names, sample counts; each refusal names its key.
    Returns the number of samples of each segment."""
    for key, unit, example in (("sample_rate", "Hz", "20 kHz"), ("v_dc", "V", "48 V"),
                               ("current_limit", "A", "30 A"), ("max_speed", "rad/s", "300 rad/s"),
                               ("max_torque", "N*m", "50 N*m"), ("current_noise", "A", "20 mA")):
        value = getattr(spec, key)
        if value is not None and not value > 0:
            raise DrivecalError(f"{source}: '{key}' must be positive, got {value:g} {unit}; write e.g. "
                                f"{key} = \"{example}\".")
    _check_inverter(spec, source)
    if not spec.segment:
        raise DrivecalError(f"{source}: 'segment': the plan has no segments; add at least one [[segment]] table.")
    seen: dict[str, int] = {}
    counts = []
    for i, s in enumerate(spec.segment):
        where = f"{source}: 'segment[{i}]"
        if not s.name.strip():
            raise DrivecalError(f"{where}.name' is empty; give each segment a name.")
        if not s.name.isprintable() or len(s.name) > 200:
            raise DrivecalError(f"{where}.name' must be one printable line of at most 200 characters, got "
                                f"{s.name[:40]!r}.")
        if s.name in seen:
            raise DrivecalError(f"{where}.name': {s.name!r} is already the name of segment[{seen[s.name]}]; "
                                "give each segment a name of its own.")
        seen[s.name] = i
        samples = s.duration * spec.sample_rate
        if not s.duration > 0:
            raise DrivecalError(f"{where}.duration' must be positive, got {s.duration:g} s.")
        if sum(counts) + samples > MAX_SAMPLES:
            raise DrivecalError(f"{where}.duration': {s.duration:g} s at {spec.sample_rate:g} Hz brings the plan "
                                f"past {MAX_SAMPLES:.0e} samples; shorten it or lower 'sample_rate'.")
        n = int(round(samples))
        if n < 2:
            raise DrivecalError(f"{where}.duration': segment '{s.name}' lasts {s.duration:g} s = {n} sample(s) "
                                f"at {spec.sample_rate:g} Hz; make it at least two sample periods.")
        counts.append(n)
        if s.temperature is not None and s.temperature < _ABSOLUTE_ZERO:
            raise DrivecalError(f"{where}.temperature' is below absolute zero ({s.temperature:g} degC); "
                                "give the winding temperature in degC.")
        for axis in ("v_d", "v_q"):
            _check_waveform(getattr(s, axis), f"{where}.{axis}")
    return counts


def _check_inverter(spec: PlanSpec, source: str) -> None:
    inv = spec.inverter
    bad = inverter_setting_error(inv.dead_time, inv.device_drop, spec.sample_rate, spec.v_dc)
    if bad is not None:
        key, _, _, reason = bad
        raise DrivecalError(f"{source}: 'inverter.{key}' {reason}")


def _check_waveform(spec, where: str) -> None:
    if isinstance(spec, (StepSpec, RampSpec)) and spec.delay < 0:
        raise DrivecalError(f"{where}.delay' must be >= 0, got {spec.delay:g} s.")
    if isinstance(spec, RampSpec) and not spec.rise > 0:
        raise DrivecalError(f"{where}.rise' must be positive, got {spec.rise:g} s; write e.g. rise = \"50 ms\".")
    if isinstance(spec, (ChirpSpec, MultisineSpec)) and not math.isfinite(getattr(spec, "phase", 0.0)):
        raise DrivecalError(f"{where}.phase' must be a finite number [rad], got {spec.phase!r}.")
    if isinstance(spec, PrbsSpec) and spec.bit_rate is not None and not spec.bit_rate > 0:
        raise DrivecalError(f"{where}.bit_rate' must be positive, got {spec.bit_rate:g} Hz.")
    if isinstance(spec, SamplesSpec) and spec.values is not None:
        bad = [k for k, v in enumerate(spec.values) if not math.isfinite(v)]
        if bad:
            raise DrivecalError(f"{where}.values[{bad[0]}]' must be a finite voltage, got {spec.values[bad[0]]!r}.")


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
            if not csv.is_file():
                raise DrivecalError(f"{where}.file: '{csv}' is not a file; check 'file' (relative to the plan file).")
            try:
                frame = pd.read_csv(csv)
            except (OSError, ValueError, UnicodeDecodeError, pd.errors.ParserError) as exc:
                reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
                raise DrivecalError(f"{where}.file: '{csv}' cannot be read as CSV ({reason}); check 'file'.") from None
            if len(frame.columns) == 0:
                raise DrivecalError(f"{where}.file: '{csv}' has no columns; check 'file'.")
            column = spec.column or frame.columns[0]
            if column not in frame:
                raise DrivecalError(f"{where}.column: '{csv}' has no column '{column}'; check 'column'.")
            try:
                values = frame[column].to_numpy(dtype=float)
            except (TypeError, ValueError):
                raise DrivecalError(f"{where}.column: column '{column}' of '{csv}' is not all numbers; "
                                    "give voltages in V.") from None
            if not np.all(np.isfinite(values)):
                raise DrivecalError(f"{where}.column: column '{column}' of '{csv}' has a missing or infinite "
                                    "value; give one finite voltage per sample.")
            params = {"values": values}
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
    if not isinstance(data, dict):
        raise DrivecalError(f"{source}: a plan file is a TOML table with keys such as sample_rate, v_dc and "
                            f"[[segment]], got {type(data).__name__}.")
    try:
        spec = PlanSpec.model_validate(data)
    except ValidationError as exc:
        keys = ", ".join(PlanSpec.model_fields) + " (per [[segment]]: " + ", ".join(
            f.alias or n for n, f in SegmentSpec.model_fields.items()) + "; in [inverter]: " + ", ".join(
            InverterSpec.model_fields) + ")"
        raise explain(exc, source, "plan", keys) from None
    counts = _check_spec(spec, source)
    base = base or Path(".")
    segments = []
    for i, (s, n) in enumerate(zip(spec.segment, counts)):
        v_d = _axis(s.v_d, n, spec.sample_rate, base, f"{source}: segment[{i}].v_d")
        v_q = _axis(s.v_q, n, spec.sample_rate, base, f"{source}: segment[{i}].v_q")
        segments.append(Segment(s.name, s.duration, s.locked, v_d=v_d, v_q=v_q, temperature=s.temperature,
                                continues=s.continues, inverter=s.inverter))
    plan = Plan(tuple(segments), sample_rate=spec.sample_rate, v_dc=spec.v_dc, current_limit=spec.current_limit,
                max_speed=spec.max_speed, max_torque=spec.max_torque, inverter=Inverter(**spec.inverter.model_dump()),
                current_noise=spec.current_noise)
    try:
        return plan.check_feasible()
    except DrivecalError as exc:
        raise DrivecalError(f"{source}: {exc}") from None


def load_plan(path: str | Path) -> Plan:
    """Read and check a plan TOML file (schema in docs/plans.md, examples in ``examples/``)."""
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
    if plan.max_torque is not None:
        lines.append(f"max_torque = {_toml_value(float(plan.max_torque))}    # N*m, the rotor clamp's limit")
    if plan.current_noise is not None:  # not written when not recorded, so older plans round-trip unchanged
        lines.append(f"current_noise = {_toml_value(float(plan.current_noise))}    # A, the sensor noise the plan "
                     "was designed for")
    inv = plan.inverter
    if not inv.is_default:  # the averaged, ideal inverter is no table
        lines += ["", "[inverter]    # what `drivecal simulate` runs the plan on",
                  f"model = {_toml_value(inv.model)}", f"modulation = {_toml_value(inv.modulation)}",
                  f"dead_time = {_toml_value(float(inv.dead_time))}    # s, per switching edge",
                  f"device_drop = {_toml_value(float(inv.device_drop))}    # V"]
    for seg in plan.segments:
        lines += ["", "[[segment]]", f"name = {_toml_value(seg.name)}",
                  f"duration = {_toml_value(float(seg.duration))}    # s", f"locked = {_toml_value(bool(seg.locked))}"]
        if seg.temperature is not None:
            lines.append(f"temperature = {_toml_value(float(seg.temperature))}    # degC")
        if seg.continues:
            lines.append("continue = true    # starts where the previous segment ended")
        if seg.inverter != "on":
            lines.append(f"inverter = {_toml_value(seg.inverter)}    # switches open: no current, the rotor coasts")
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
