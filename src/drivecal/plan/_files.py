"""Plan and motor files (TOML), validated with pydantic.

Every physical value is either a plain number in SI units or a string with a
unit, e.g. ``duration = "10 ms"``, ``v_d = "8 V"``, ``Ld = "3.2 mH"``. A wrong
key or a unit of the wrong kind is refused with one sentence naming the file,
the key and the fix. The schemas are documented in the README ("Plan files",
"Motor files") and exemplified in ``examples/``.
"""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from . import _waveforms as waveforms
from ..errors import DrivecalError
from ..physics import DEFAULT_MOTOR, ESTIMABLE, ESTIMATED, MotorParams
from ._plan import Plan, Segment

_PREFIXES = {"": 1.0, "k": 1e3, "M": 1e6, "m": 1e-3, "u": 1e-6, "µ": 1e-6, "μ": 1e-6, "n": 1e-9}
#: Base units by quantity; the unit written in a file must be one of these with a prefix.
_UNITS = {
    "time": ("s",),
    "frequency": ("Hz",),
    "voltage": ("V",),
    "current": ("A",),
    "resistance": ("ohm", "Ohm", "Ω"),
    "inductance": ("H",),
    "flux": ("Wb", "V*s", "Vs"),
    "inertia": ("kg*m^2", "kg m^2", "kgm^2"),
    "friction": ("N*m*s", "Nms", "N m s"),
    "speed": ("rad/s",),
    "torque": ("N*m", "Nm", "N m"),
    "temperature": ("degC", "°C", "C"),
    "temperature coefficient": ("1/K",),
}
_EXAMPLE = {"time": "10 ms", "frequency": "20 kHz", "voltage": "8 V", "current": "30 A", "resistance": "0.45 ohm",
            "inductance": "3.2 mH", "flux": "0.0533 Wb", "inertia": "1.2e-3 kg*m^2", "friction": "8e-5 N*m*s",
            "speed": "300 rad/s", "torque": "0.1 N*m", "temperature": "75 degC",
            "temperature coefficient": "3.93e-3 1/K"}
_NUMBER_UNIT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(.*?)\s*$")


class _UnitError(ValueError):
    pass


def parse_quantity(value: Any, quantity: str) -> float:
    """A number (SI) or ``"<number> <prefix><unit>"`` string, converted to SI.

    Raises ``ValueError`` with a message that names the expected unit.
    """
    if isinstance(value, bool):
        raise _UnitError(f"expected a {quantity} such as '{_EXAMPLE[quantity]}', got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if not isinstance(value, str):
        raise _UnitError(f"expected a {quantity} such as '{_EXAMPLE[quantity]}', got {value!r}")
    match = _NUMBER_UNIT.match(value)
    if not match:
        raise _UnitError(f"'{value}' is not a number with a unit; write e.g. '{_EXAMPLE[quantity]}'")
    number, unit = float(match.group(1)), match.group(2)
    if unit == "":
        return number
    for base in _UNITS[quantity]:
        if unit.endswith(base) and unit[: -len(base)] in _PREFIXES:
            return number * _PREFIXES[unit[: -len(base)]]
    raise _UnitError(
        f"'{value}' has unit '{unit}' but a {quantity} in {_UNITS[quantity][0]} is expected; "
        f"write e.g. '{_EXAMPLE[quantity]}'"
    )


def _q(quantity: str):
    return Annotated[float, BeforeValidator(lambda v: parse_quantity(v, quantity))]


Seconds, Hertz, Volts, Amperes = _q("time"), _q("frequency"), _q("voltage"), _q("current")


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StepSpec(_Strict):
    """``initial`` before ``delay``, ``level`` after."""

    kind: Literal["step"]
    level: Volts
    initial: Volts = 0.0
    delay: Seconds = 0.0


class ChirpSpec(_Strict):
    kind: Literal["chirp"]
    amplitude: Volts
    f_start: Hertz
    f_stop: Hertz
    sweep: Literal["linear", "log"] = "linear"
    offset: Volts = 0.0
    phase: float = 0.0


class MultisineSpec(_Strict):
    kind: Literal["multisine"]
    amplitude: Volts
    f_min: Hertz
    f_max: Hertz
    num_tones: int = 16
    offset: Volts = 0.0


class PrbsSpec(_Strict):
    kind: Literal["prbs"]
    amplitude: Volts
    order: int = 9
    bit_rate: Hertz | None = None
    offset: Volts = 0.0
    seed: int = 1


class SamplesSpec(_Strict):
    """A measured sequence: inline ``values`` (V) or a CSV ``file`` with a ``column``."""

    kind: Literal["samples"]
    values: list[float] | None = None
    file: str | None = None
    column: str | None = None


Waveform = Annotated[Union[StepSpec, ChirpSpec, MultisineSpec, PrbsSpec, SamplesSpec], Field(discriminator="kind")]


class SegmentSpec(_Strict):
    name: str
    duration: Seconds
    locked: bool
    v_d: Union[Volts, Waveform] = 0.0
    v_q: Union[Volts, Waveform] = 0.0
    temperature: _q("temperature") | None = None


class PlanSpec(_Strict):
    sample_rate: Hertz = 20_000.0
    v_dc: Volts = 48.0
    current_limit: Amperes = 30.0
    max_speed: _q("speed") | None = None
    segment: list[SegmentSpec] = Field(min_length=1)


class MotorSpec(_Strict):
    R: _q("resistance") = float(DEFAULT_MOTOR.R)
    Ld: _q("inductance") = float(DEFAULT_MOTOR.Ld)
    Lq: _q("inductance") = float(DEFAULT_MOTOR.Lq)
    lambda_m: _q("flux") = float(DEFAULT_MOTOR.lambda_m)
    pole_pairs: int = int(DEFAULT_MOTOR.pole_pairs)
    J: _q("inertia") = float(DEFAULT_MOTOR.J)
    B: _q("friction") = float(DEFAULT_MOTOR.B)
    T_load: _q("torque") = 0.0
    v_dead: _q("voltage") = 0.0
    i_dead: _q("current") = float(DEFAULT_MOTOR.i_dead)
    offset_d: _q("current") = 0.0
    offset_q: _q("current") = 0.0
    offset_a: _q("current") = 0.0
    offset_b: _q("current") = 0.0
    alpha_R: _q("temperature coefficient") = float(DEFAULT_MOTOR.alpha_R)
    T_ref: _q("temperature") = float(DEFAULT_MOTOR.T_ref)
    delay_samples: int = Field(default=0, ge=0, le=100)
    estimate: list[Literal["R", "Ld", "Lq", "lambda_m", "v_dead", "offset_d", "offset_q", "offset_a", "offset_b",
                           "alpha_R"]] | None = None


class MotorFile(BaseModel):
    """A loaded motor file: the nominal motor (the fit's prior) and what to estimate.

    Attributes:
        motor: nominal values of all parameters (bench effects included), SI.
        estimate: the parameters the user asks for, or None for "R, Ld, Lq,
            lambda_m, holding any the data cannot identify at the nominal
            value". Bench effects (v_dead, offsets, alpha_R) are estimated
            only when listed here.
        delay_samples: the inverter's PWM/computation delay (samples).
        source: the file path, for messages.
    """

    model_config = ConfigDict(frozen=True, arbitrary_types_allowed=True)
    motor: MotorParams
    estimate: tuple[str, ...] | None = None
    delay_samples: int = 0
    source: str = "default motor"

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters to estimate, in drivecal's order."""
        if self.estimate is None:
            return ESTIMATED
        return tuple(n for n in ESTIMABLE if n in self.estimate)


def _location(loc: tuple) -> str:
    parts = []
    for item in loc:
        if isinstance(item, int):
            parts[-1] = f"{parts[-1]}[{item}]" if parts else f"[{item}]"
        elif item in ("step", "chirp", "multisine", "prbs", "samples", "float", "function-before[<lambda>(), float]"):
            continue  # pydantic's union branch names are not keys of the file
        elif isinstance(item, str) and (item.startswith("function-") or item.startswith("tagged-union[")):
            continue
        else:
            parts.append(str(item))
    return ".".join(parts)


def _explain(error: ValidationError, path: str, kind: str, keys: str) -> DrivecalError:
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


def read_toml(path: str | Path) -> dict:
    path = Path(path)
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise DrivecalError(f"{path}: no such file; check the path.") from None
    except tomllib.TOMLDecodeError as exc:
        raise DrivecalError(f"{path}: not valid TOML ({exc}); fix the syntax.") from None


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
        raise _explain(exc, source, "plan", keys) from None
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


def motor_from_dict(data: dict, source: str = "motor") -> MotorFile:
    """A :class:`MotorFile` from the TOML table ``data`` (missing keys take the default motor's values)."""
    try:
        spec = MotorSpec.model_validate(data)
    except ValidationError as exc:
        raise _explain(exc, source, "motor", ", ".join(MotorSpec.model_fields)) from None
    values = spec.model_dump(exclude={"estimate", "delay_samples"})
    signed = ("T_load", "offset_d", "offset_q", "offset_a", "offset_b", "T_ref")
    for name, value in values.items():
        if not math.isfinite(value):
            raise DrivecalError(f"{source}: '{name}' must be a finite number, got {value!r}.")
        if name == "v_dead" and value < 0:
            raise DrivecalError(f"{source}: 'v_dead' is a voltage magnitude and must be >= 0, got {value!r}.")
        if not value > 0 and name not in signed + ("v_dead",):
            raise DrivecalError(f"{source}: '{name}' must be a positive number, got {value!r}.")
    motor = MotorParams(**{k: float(v) for k, v in values.items()})
    estimate = None if spec.estimate is None else tuple(spec.estimate)
    if estimate is not None and not estimate:
        raise DrivecalError(f"{source}: 'estimate' is empty; list at least one of R, Ld, Lq, lambda_m.")
    return MotorFile(motor=motor, estimate=estimate, delay_samples=spec.delay_samples, source=source)


def load_motor(path: str | Path | None) -> MotorFile:
    """Read a motor TOML file; ``None`` gives the default 48 V motor."""
    if path is None:
        return MotorFile(motor=DEFAULT_MOTOR)
    return motor_from_dict(read_toml(path), str(path))


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
