"""Fuzz the plan and motor TOML schemas: any document is a Plan/MotorFile or one DrivecalError naming a field.

Random documents (random keys, wrong types, unit strings right and wrong, nested tables, NaN/Inf, negative
and huge numbers, near-valid plans) go through ``plan_from_dict`` / ``motor_from_dict``. Nothing else may
come out: no other exception, no warning. ``DRIVECAL_FUZZ_EXAMPLES`` sets the number of documents per schema
(default 2000), ``DRIVECAL_FUZZ_SEED`` the seed (printed with a failing example).
"""

from __future__ import annotations

import datetime
import math
import os
import warnings

import pytest
from hypothesis import HealthCheck, given, note, seed, settings
from hypothesis import strategies as st

import drivecal as dc
from drivecal.data import HinkkanenSpec, MotorSpec

EXAMPLES = int(os.environ.get("DRIVECAL_FUZZ_EXAMPLES", "2000"))
SEED = int(os.environ.get("DRIVECAL_FUZZ_SEED", "20230"))
SOURCE = "fuzz.toml"
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, print_blob=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])

# --- values ------------------------------------------------------------------------------------------------

SPECIAL_FLOATS = [math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1e-300, 5e-324, 1e300, -1e300, 1e-9, 2.0]
UNITS = ["s", "ms", "us", "µs", "Hz", "kHz", "MHz", "V", "mV", "kV", "A", "mA", "ohm", "mohm", "Ω", "H", "mH",
         "uH", "Wb", "mWb", "V*s", "kg*m^2", "N*m*s", "rad/s", "N*m", "degC", "°C", "1/K", "", "m", "volts",
         "k", "Hz Hz", "ohms", "MV", "nH"]
NUMBER_TEXT = st.one_of(st.sampled_from(["1", "-1", "0", "1e3", "2.5", ".5", "1e999", "-1e999", "1e-400", "nan",
                                         "inf", "3.", "+7", "1_000", "0x10", ""]),
                        st.floats(-1e4, 1e4, allow_nan=False).map(repr))
UNIT_STRINGS = st.builds(lambda n, sp, u: f"{n}{sp}{u}", NUMBER_TEXT, st.sampled_from(["", " ", "  "]),
                         st.sampled_from(UNITS))
KEYS = st.one_of(st.text(min_size=0, max_size=8),
                 st.sampled_from(["R", "Ld", "segment", "kind", "v_d", "name", "duration", "values", "estimate",
                                  "<voltage>", "step", "float", "function-x", "__class__", "model_config"]))
SCALARS = st.one_of(
    st.sampled_from(SPECIAL_FLOATS),
    st.floats(-100.0, 100.0),
    st.integers(-100, 100),
    st.sampled_from([2**63, -(2**63) - 1, 10**400, 2**64]),
    st.booleans(),
    st.text(max_size=12),
    UNIT_STRINGS,
    st.just(datetime.date(2024, 1, 1)),
    st.just(datetime.datetime(2024, 1, 1, 12, 0)),
)
JUNK = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                     st.dictionaries(KEYS, inner, max_size=4)), max_leaves=8)


def _often(right, rare, times: int = 16):
    """``right`` about ``times`` out of ``times + 1`` draws, else ``rare`` (one_of would draw each half the time)."""
    return st.sampled_from(range(times + 1)).flatmap(lambda i: right if i else rare)


def _quantity(unit: str, good: list[float], bad: tuple[float, ...] = (0.0, -1.0, math.nan, math.inf, 1e300)):
    """A value for a quantity field: mostly right (a number or a unit string), sometimes a bad number or
    anything at all."""
    def written(values):
        return st.one_of(st.sampled_from(values), st.sampled_from(values).map(lambda x: f"{x!r} {unit}"))

    return _often(written(good), st.one_of(written(list(bad)), JUNK))


def _table(required: dict, optional: dict | None = None):
    """A table: mostly the ``required`` keys and some ``optional`` ones; sometimes any subset, or an unknown key."""
    optional = optional or {}
    usual = st.fixed_dictionaries(required, optional=optional)
    anything = st.fixed_dictionaries({}, optional={**required, **optional})
    extra = st.builds(lambda d, k, v: {**d, k: v}, usual, KEYS, JUNK)
    return _often(usual, st.one_of(anything, extra))


# --- plans -------------------------------------------------------------------------------------------------

VOLTS = _quantity("V", [0.0, 1.0, -2.0, 8.0, 1e-3], (30.0, 1e6, math.nan))
HERTZ = _quantity("Hz", [1.0, 10.0, 100.0, 500.0, 5e3])
SECONDS = _quantity("s", [1e-3, 5e-3, 0.02, 0.1], (0.0, -0.01, 1e-6, 1e4, math.nan))

WAVEFORM_FIELDS = {
    "kind": st.one_of(st.sampled_from(["step", "chirp", "multisine", "prbs", "samples", "sine", "STEP", ""]), JUNK),
    "level": VOLTS, "initial": VOLTS, "delay": SECONDS, "amplitude": VOLTS, "offset": VOLTS,
    "f_start": HERTZ, "f_stop": HERTZ, "f_min": HERTZ, "f_max": HERTZ, "bit_rate": HERTZ,
    "sweep": st.one_of(st.sampled_from(["linear", "log", "exp"]), JUNK),
    "phase": st.one_of(st.sampled_from([0.0, 1.0, math.nan, math.inf]), JUNK),
    "num_tones": st.one_of(st.integers(-2, 40), st.sampled_from([10**9, 10**30]), JUNK),
    "order": st.one_of(st.integers(-1, 18), st.sampled_from([10**30]), JUNK),
    "seed": st.one_of(st.integers(-5, 5), st.sampled_from([2**70, -(2**70)]), JUNK),
    "values": st.one_of(st.lists(st.floats(-5, 5), max_size=5),
                        st.lists(st.sampled_from([1.0, math.nan, math.inf]), min_size=100, max_size=100),
                        st.integers(2, 200).map(lambda n: [0.5] * n), JUNK),
    "file": st.one_of(st.sampled_from(["", ".", "missing.csv", "/", "/etc/hostname", "/dev/null"]), JUNK),
    "column": st.one_of(st.sampled_from(["v", "0", ""]), JUNK),
}
KINDS = ("step", "chirp", "multisine", "prbs", "samples")
#: kind -> (required keys, optional keys) of its table.
WAVEFORM_KEYS = {"step": (["level"], ["initial", "delay"]),
                 "chirp": (["amplitude", "f_start", "f_stop"], ["sweep", "offset", "phase"]),
                 "multisine": (["amplitude", "f_min", "f_max"], ["num_tones", "offset"]),
                 "prbs": (["amplitude"], ["order", "bit_rate", "offset", "seed"]),
                 "samples": ([], ["values", "file", "column"])}
WAVEFORM = st.one_of(
    *(_table({"kind": st.just(kind), **{k: WAVEFORM_FIELDS[k] for k in needs}},
             {k: WAVEFORM_FIELDS[k] for k in optional}) for kind, (needs, optional) in WAVEFORM_KEYS.items()),
    _table({"kind": WAVEFORM_FIELDS["kind"]}, {k: v for k, v in WAVEFORM_FIELDS.items() if k != "kind"}),
)
AXIS = st.one_of(VOLTS, VOLTS, WAVEFORM)
SEGMENT = _table({
    "name": _often(st.sampled_from(["a", "b", "c", "d-step"]), st.one_of(st.sampled_from(["", "  ", "a\nb"]), JUNK)),
    "duration": SECONDS,
    "locked": _often(st.booleans(), JUNK),
}, {"v_d": AXIS, "v_q": AXIS, "temperature": _quantity("degC", [20.0, 75.0, 0.0], (-300.0, math.inf))})
PLAN = _table({"segment": _often(st.lists(SEGMENT, min_size=1, max_size=3), st.one_of(st.just([]), JUNK))}, {
    "sample_rate": _quantity("Hz", [20_000.0, 1_000.0, 10_000.0]),
    "v_dc": _quantity("V", [48.0, 300.0]),
    "current_limit": _quantity("A", [30.0, 1.0]),
    "max_speed": _quantity("rad/s", [300.0, 1.0]),
})
PLAN_DOCUMENT = _often(PLAN, JUNK)

PLAN_FIELDS = {"sample_rate", "v_dc", "current_limit", "max_speed", "segment", "name", "duration", "locked", "v_d",
               "v_q", "temperature", *WAVEFORM_FIELDS, "unknown key", "plan"}

# --- motors ------------------------------------------------------------------------------------------------

MOTOR_UNITS = {"R": "ohm", "Ld": "H", "Lq": "H", "lambda_m": "Wb", "J": "kg*m^2", "B": "N*m*s", "T_load": "N*m",
               "v_dead": "V", "i_dead": "A", "offset_d": "A", "offset_q": "A", "offset_a": "A", "offset_b": "A",
               "alpha_R": "1/K", "T_ref": "degC"}
MOTOR = _table({k: _quantity(u, [0.45, 3.2e-3, 0.0533, 1.0, 1e-12]) for k, u in MOTOR_UNITS.items()
                if k in ("R", "Ld", "Lq", "lambda_m")}, {
    **{k: _quantity(u, [0.45, 3.2e-3, 1.0, 0.0, 1e-12]) for k, u in MOTOR_UNITS.items()
       if k not in ("R", "Ld", "Lq", "lambda_m")},
    "pole_pairs": st.one_of(st.integers(-2, 12), st.sampled_from([2**70, 4.0, 4.5]), JUNK),
    "delay_samples": st.one_of(st.integers(-2, 120), JUNK),
    "estimate": st.one_of(st.lists(st.sampled_from(["R", "Ld", "Lq", "lambda_m", "v_dead", "alpha_R", "J", "sat_d",
                                                    "x"]), max_size=4), JUNK),
    # a saturating law: drivecal's per-unit keys, or Hinkkanen's SI table (issue 18)
    **{k: _often(st.sampled_from([0.0, 0.3, 2.0, 1e3]), st.sampled_from([-1.0, math.nan, 1e300, "1 A"]) | JUNK)
       for k in ("sat_d", "sat_q", "sat_dq", "exp_d", "exp_dq_q")},
    "i_ref": _quantity("A", [20.0, 1.0]),
    "hinkkanen": _table({k: st.sampled_from(v) for k, v in {"a_d0": [17.4, 0.0], "a_q0": [52.1, 1e-300]}.items()},
                        {k: st.sampled_from(v) for k, v in {"a_dd": [373.0, -1.0], "S": [5, 0, 11],
                                                            "a_dq": [1120.0, 0.0], "V": [0, 1.5]}.items()}),
})
MOTOR_DOCUMENT = _often(MOTOR, JUNK)
MOTOR_FIELDS = {*MotorSpec.model_fields, *HinkkanenSpec.model_fields, "unknown key", "motor"}


def _check(load, document, fields: set[str]):
    """``load(document)`` is a result or one DrivecalError that names a field; no other exception, no warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning fails the example, naming itself
        try:
            return load(document)
        except dc.DrivecalError as exc:
            message = str(exc)
    assert message.startswith(f"{SOURCE}: "), message
    assert "\n" not in message, message
    assert any(f in message for f in fields), f"names no field: {message}"
    return None


@seed(SEED)
@FUZZ
@given(PLAN_DOCUMENT)
def test_any_plan_document_loads_or_is_refused_naming_a_field(tmp_path_factory, document):
    note(f"fuzz seed {SEED} (DRIVECAL_FUZZ_SEED)")
    plan = _check(lambda d: dc.plan_from_dict(d, SOURCE, tmp_path_factory.getbasetemp()), document, PLAN_FIELDS)
    if plan is not None:
        assert isinstance(plan, dc.Plan) and plan.num_samples >= 2


@seed(SEED)
@FUZZ
@given(MOTOR_DOCUMENT)
def test_any_motor_document_loads_or_is_refused_naming_a_field(document):
    note(f"fuzz seed {SEED} (DRIVECAL_FUZZ_SEED)")
    motor_file = _check(lambda d: dc.motor_from_dict(d, SOURCE), document, MOTOR_FIELDS)
    if motor_file is not None:
        assert isinstance(motor_file, dc.MotorFile)
        assert all(math.isfinite(float(v)) for v in motor_file.motor.as_dict().values())


@pytest.mark.parametrize("document", [{}, {"segment": []}, {"sample_rate": 0}, {"kind": "sine"}])
def test_fuzz_check_accepts_the_plain_refusals(document):
    assert _check(lambda d: dc.plan_from_dict(d, SOURCE), document, PLAN_FIELDS) is None
