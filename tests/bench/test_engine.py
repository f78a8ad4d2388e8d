"""The engine bench kept on disk (_engine.py): a later run with the same inputs reads the engine's bench, bit for bit."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np

import drivecal as dc
from drivecal.bench import _engine

#: A process with the caches on (as a user's): the bench of the locked q-step, its arrays saved to argv[2];
#: with argv[1] == "kept", running the engine fails the process.
_RUN = """
import sys
import numpy as np
import drivecal as dc
from drivecal.bench import _engine

if sys.argv[1] == "kept":
    _engine._plan_states = lambda *a: sys.exit("ran the engine again")
bench = _engine.engine_bench(dc.locked_q_step_plan(), dc.DEFAULT_MOTOR, record_speed=True)
(segment,) = bench.segments
np.savez(sys.argv[2], t=segment.t, voltages=segment.voltages, currents=segment.currents, w_m=segment.w_m,
         theta_e=segment.theta_e, sample_rate=bench.sample_rate)
from pathlib import Path
print(sorted(p.name for p in Path(sys.argv[3]).glob("*/drivecal-engine-*/*.pkl")))
"""


def _run(tmp_path, how: str, out: str) -> str:
    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-c", _RUN, how, str(tmp_path / out), str(tmp_path / "cache")], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    return done.stdout


def test_a_later_process_reads_the_engine_s_bench_bit_for_bit_and_a_damaged_one_runs_the_engine(tmp_path):
    """Kept by the first run (one entry), read by the next without running the engine; where the entry is
    damaged the engine runs again, with the same result, and the entry is replaced."""
    first = _run(tmp_path, "engine", "engine.npz")
    assert first.count(".pkl") == 1
    assert _run(tmp_path, "kept", "kept.npz") == first
    (entry,) = (tmp_path / "cache").glob("*/drivecal-engine-*/*.pkl")
    entry.write_bytes(b"not a bench")
    assert _run(tmp_path, "engine", "again.npz") == first
    assert entry.read_bytes() != b"not a bench"
    engine = np.load(tmp_path / "engine.npz")
    for other in ("kept.npz", "again.npz"):
        loaded = np.load(tmp_path / other)
        for name in engine.files:
            np.testing.assert_array_equal(loaded[name], engine[name], err_msg=f"{other}: {name}")
            assert loaded[name].dtype == engine[name].dtype


def test_the_key_names_every_input():
    plan, motor = dc.default_plan(), dc.DEFAULT_MOTOR
    key = _engine._key_of(plan, motor, False, 0.0)
    assert key == _engine._key_of(dc.default_plan(), motor.replace(), False, 0.0)  # equal inputs, equal key
    others = [
        _engine._key_of(dc.locked_q_step_plan(), motor, False, 0.0),
        _engine._key_of(dataclasses.replace(plan, sample_rate=2 * plan.sample_rate), motor, False, 0.0),
        _engine._key_of(plan, motor.replace(R=float(motor.R) * (1 + 2**-40)), False, 0.0),
        _engine._key_of(plan, motor.replace(v_dead=0.3), False, 0.0),
        _engine._key_of(plan, motor, True, 0.0),
        _engine._key_of(plan, motor, False, 1.0),
    ]
    assert len({key, *others}) == 1 + len(others)


def test_nothing_is_kept_with_the_caches_off(monkeypatch):
    """With DRIVECAL_JAX_CACHE=0 (as the suite runs) there is no key: the engine always runs."""
    monkeypatch.setenv("DRIVECAL_JAX_CACHE", "0")
    assert _engine._bench_key(dc.default_plan(), dc.DEFAULT_MOTOR, False, 0.0) is None
    assert _engine._kept_bench(None) is None


_KEPT = """
import numpy as np
import drivecal as dc
from drivecal.bench import engine_bench, kept_engine_bench

plan, motor = dc.locked_q_step_plan(), dc.DEFAULT_MOTOR
before = kept_engine_bench(plan, motor)
bench = engine_bench(plan, motor)
after = kept_engine_bench(plan, motor)
print(before is None, after is not None and np.array_equal(after.currents, bench.currents),
      kept_engine_bench(plan, motor, delay_samples=1.0) is None)
"""


def test_kept_engine_bench_is_the_bench_engine_bench_kept_and_nothing_else(tmp_path):
    """What a caller (the demo) asks before it runs the engine: None until ``engine_bench`` has kept these inputs'
    bench, then that bench; other inputs are still not kept."""
    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-c", _KEPT], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.split() == ["True", "True", "True"]


def test_segments_of_one_length_and_kind_share_the_engine_s_kernel_each_with_its_own_voltages():
    """The default plan's locked d- and q-steps (200 samples each) run on one diagram, their voltages a parameter
    of its context: the engine compiles once for both. Each step's currents are its own: those of a diagram built
    for that step alone, to the bit (the hold holds the step's first voltage from the start, not another's), and
    those of a locked rotor with the step's voltage on one axis (i = V/R (1 - exp(-R t / L)), the other at zero)."""
    from jaxonomy.simulation.simulator import clear_simulate_cache, simulate_cache_info

    from drivecal.bench import pmsm_block, run_held_voltages

    _engine._pmsm_setup.cache_clear()
    clear_simulate_cache()
    motor = dc.DEFAULT_MOTOR
    plan = dc.Plan(segments=tuple(s for s in dc.default_plan().segments if s.locked))
    d_step, q_step = _engine.engine_bench(plan, motor).segments
    assert simulate_cache_info()["misses"] == 1 and simulate_cache_info()["hits"] == 1
    R, t = float(motor.R), d_step.t
    for segment, axis, inductance in ((d_step, 0, float(motor.Ld)), (q_step, 1, float(motor.Lq))):
        alone = run_held_voltages(pmsm_block(motor, locked=True), segment.voltages, plan.sample_rate)[1]
        np.testing.assert_array_equal(segment.currents, alone[:, :2], err_msg=segment.name)
        volts = segment.voltages[0, axis]
        assert volts == 8.0 and np.all(segment.voltages[:, 1 - axis] == 0.0)
        expected = volts / R * (1.0 - np.exp(-R * t / inductance))
        np.testing.assert_allclose(segment.currents[:, axis], expected, rtol=0, atol=1e-9, err_msg=segment.name)
        np.testing.assert_allclose(segment.currents[:, 1 - axis], 0.0, rtol=0, atol=1e-12, err_msg=segment.name)
