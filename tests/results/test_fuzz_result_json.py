"""Fuzz the result JSON schema: any mutation of a valid result is read, or refused in one sentence naming a field.

Valid documents (a well-identified fit, a partial fit whose non-identifiable parameters have null SE and
CI, and a demo document holding both) are mutated at random: keys dropped, values set to null, NaN, Inf,
huge or wrong-typed numbers, lists cut short or lengthened, nested junk put in place of anything. Each
goes through ``load_result`` (from a file) and ``Calibration.from_dict``, and what they accept through
``str(cal)`` and ``design_current_loop``. Nothing but a :class:`DrivecalError` naming the file and a field
may come out, and no warning (warnings are errors here). ``DRIVECAL_FUZZ_EXAMPLES`` sets the number of
documents (default 2000), ``DRIVECAL_FUZZ_SEED`` the seed (printed with a failing example).
"""

from __future__ import annotations

import copy
import json
import math
import os
import warnings

import pytest
from hypothesis import HealthCheck, given, note, seed, settings
from hypothesis import strategies as st

from conftest import NOISE
from drivecal.errors import DrivecalError
from drivecal.report import build_result, design_current_loop
from drivecal.results import Calibration, load_result, result_fits

EXAMPLES = int(os.environ.get("DRIVECAL_FUZZ_EXAMPLES", "2000"))
SEED = int(os.environ.get("DRIVECAL_FUZZ_SEED", "20231"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None, print_blob=False,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much, HealthCheck.function_scoped_fixture])

KEEP_SAMPLES = 3  # samples per trace kept in the base documents: small files, the same schema

SCALARS = st.one_of(
    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0, -1.0, 1.0, 1e-300, 5e-324, 1e300, -1e300, 3.0]),
    st.floats(-10.0, 10.0),
    st.integers(-3, 3),
    st.sampled_from([2**63, -(2**63) - 1, 10**400, 2**53 + 1]),
    st.booleans(),
    st.none(),
    st.text(max_size=6),
    st.sampled_from(["R", "Ld", "Lq", "lambda_m", "pole_pairs", "bogus", "designs", "\n"]),
)
JUNK = st.recursive(SCALARS, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                     st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                    max_leaves=6)


def _trim(doc: dict) -> dict:
    """A fit's document with short traces and history: the same schema, fast to write and read."""
    doc = copy.deepcopy(doc)
    for seg in doc.get("segments") or []:
        for k, v in seg.items():
            if isinstance(v, list):
                seg[k] = v[:KEEP_SAMPLES]
    if doc.get("history"):
        doc["history"]["values"] = doc["history"]["values"][:3]
    return doc


@pytest.fixture(scope="module")
def bases(default_fit, default_bench, poor_fit, poor_bench):
    good = _trim(build_result(default_fit, default_bench, noise_sigma=NOISE))
    partial = _trim(build_result(poor_fit, poor_bench, noise_sigma=NOISE))
    demo = {"drivecal_version": "0", "noise_sigma": NOISE, "seed": 1, "truth": {}, "initial": {},
            "designs": {"default": good, "locked_q_step": partial}, "versions": {}}
    docs = [json.loads(json.dumps(d)) for d in (good, partial, demo)]
    return [(json.dumps(d), _paths(d)) for d in docs]


def _paths(node, prefix=()) -> list[tuple]:
    """Every key / index path into a document."""
    out = []
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else []
    for k, v in items:
        out.append(prefix + (k,))
        out += _paths(v, prefix + (k,))
    return out


def _mutate(doc, path: tuple, op: str, junk):
    parent = doc
    for k in path[:-1]:
        parent = parent[k]
    key = path[-1]
    value = parent[key]
    if op == "drop":
        if isinstance(parent, dict):
            del parent[key]
        else:
            parent.pop(key)
    elif op == "shorten" and isinstance(value, list) and value:
        value.pop()
    elif op == "lengthen" and isinstance(value, list):
        value.append(copy.deepcopy(value[-1]) if value else junk)
    elif op == "wrap":
        parent[key] = [value]
    elif op == "stringify":
        parent[key] = json.dumps(value)
    elif op == "scale" and isinstance(value, (int, float)) and not isinstance(value, bool):
        parent[key] = value * -3  # an int stays an int (a huge one would overflow a float)
    else:  # "junk", or an op that does not apply to this value
        parent[key] = junk


OPS = st.sampled_from(["drop", "junk", "junk", "shorten", "lengthen", "wrap", "stringify", "scale"])


@st.composite
def mutated(draw, bases):
    """(which base, the mutated document, the paths mutated); paths come from the base (one that a former
    mutation removed is skipped)."""
    which = draw(st.integers(0, len(bases) - 1))
    text, paths = bases[which]
    doc = json.loads(text)
    touched = []
    for _ in range(draw(st.integers(1, 3))):
        path = draw(st.sampled_from(paths))
        try:
            _mutate(doc, path, draw(OPS), draw(JUNK))
        except (KeyError, IndexError, TypeError, AttributeError):  # gone or replaced by an earlier mutation
            continue
        touched.append(path)
    return which, doc, touched


def _named(message: str, source: str) -> bool:
    """One sentence, on one line, naming the file and a field (or saying it is no drivecal result)."""
    if "\n" in message or not message.startswith(f"{source}: "):
        return False
    rest = message[len(source) + 2:]
    fields = ("parameters", "names", "covariance", "correlation", "sigma_hat", "converged", "identifiability",
              "num_residuals", "iterations", "rss", "message", "result_code", "t_factor", "dof", "prior", "fixed",
              "history", "source", "delay_samples", "segments", "residuals", "verdict", "plan", "motor_file",
              "input", "versions", "saturation", "truth", "designs", "noise_sigma", "seed")
    return any(rest.startswith(f) for f in fields) or "not a drivecal result" in rest \
        or "not valid JSON" in rest or "not a readable JSON" in rest


def _check(doc, tmp_path) -> None:
    path = tmp_path / "result.json"
    path.write_text(json.dumps(doc), encoding="utf-8")
    source = str(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # In memory, the Python API: from_dict checks what it reads.
        if isinstance(doc, dict) and "designs" not in doc:
            try:
                Calibration.from_dict(doc, source)
            except DrivecalError as exc:
                assert _named(str(exc), source), str(exc)
        try:
            loaded = load_result(path)
        except DrivecalError as exc:
            assert _named(str(exc), source), str(exc)
            return
        for label, fit_doc in result_fits(loaded).items():
            cal = Calibration.from_dict(fit_doc, source)  # load_result accepted it: so must from_dict
            str(cal)
            cal.warnings()
            try:
                design_current_loop(cal, 1000.0, num_samples=100, source=source)
            except DrivecalError as exc:
                assert _named(str(exc), source) or str(exc).startswith(f"{source}: the result"), str(exc)


def test_the_base_documents_are_valid(bases, tmp_path):
    for text, _ in bases:
        doc = json.loads(text)
        _check(doc, tmp_path)
        loaded = load_result(tmp_path / "result.json")
        assert loaded == doc


def test_mutated_results_are_read_or_refused_naming_a_field(bases, tmp_path):
    counts = {"accepted": 0, "refused": 0}

    @seed(SEED)
    @FUZZ
    @given(case=mutated(bases))
    def run(case):
        which, doc, touched = case
        note(f"DRIVECAL_FUZZ_SEED={SEED}; base {which}; mutated {touched}")
        _check(doc, tmp_path)
        try:
            load_result(tmp_path / "result.json")
            counts["accepted"] += 1
        except DrivecalError:
            counts["refused"] += 1

    try:
        run()
    except BaseException:
        print(f"result JSON fuzz failed with DRIVECAL_FUZZ_SEED={SEED}, DRIVECAL_FUZZ_EXAMPLES={EXAMPLES}")
        raise
    print(f"result JSON fuzz: {sum(counts.values())} documents, {counts}")
    assert counts["refused"] > 0 and counts["accepted"] > 0
