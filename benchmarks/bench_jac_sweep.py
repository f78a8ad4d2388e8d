"""The LM fit's Jacobian sweep, before and after, in one process.

Times exactly what each Levenberg-Marquardt step of the batched fit computes:
the residual ``predict_currents(...).reshape(-1)`` and its Jacobian along the 4
search directions in one forward sweep (``fit._jacobian_in_one_pass``), vmapped
over B motors (``linearised_tangents=False``, as ``fit._solve_batch`` picks),
and for one motor with ``linearised_tangents=True``. The baseline is
``forward.py`` at commit ``BASELINE`` (read with ``git show``), run alternately
with the current one; each figure is the median of several rounds. Checks that
values and Jacobians agree (max relative difference).

    PYTHONPATH=src .venv/bin/python benchmarks/bench_jac_sweep.py [--batch 1000] [--rounds 7]
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import time
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import drivecal as dc
from drivecal.model import _rollout as forward
from drivecal.physics import from_search

BASELINE = "af609d1"
NAMES = dc.ESTIMATED
ROOT = Path(__file__).resolve().parent.parent


def baseline_module() -> types.ModuleType:
    """``drivecal.forward`` as of ``BASELINE``."""
    source = subprocess.run(["git", "-C", str(ROOT), "show", f"{BASELINE}:src/drivecal/forward.py"],
                            check=True, capture_output=True, text=True).stdout
    module = types.ModuleType("drivecal._forward_baseline")
    module.__package__ = "drivecal"
    sys.modules[module.__name__] = module
    exec(compile(source, "forward_baseline.py", "exec"), module.__dict__)
    return module


def sweep(predict, prior, names=NAMES):
    """``z -> (residual, Jacobian)`` of one motor, as ``fit._jacobian_in_one_pass`` sweeps it."""
    def predicted(z, experiment):
        motor = prior.with_vector(names, from_search(prior, names, z)[0])
        return predict(motor, experiment).reshape(-1)

    def one(z, experiment):
        basis = jnp.eye(z.shape[-1], dtype=z.dtype)
        return jax.vmap(lambda t: jax.jvp(lambda x: predicted(x, experiment), (z,), (t,)),
                        out_axes=(None, -1))(basis)

    return one


def time_alternating(fns: dict, rounds: int, inner: int) -> dict:
    """Median seconds per call of each argument-less function, run alternately round by round."""
    for f in fns.values():
        jax.block_until_ready(f())
    times = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(inner):
                out = f()
            jax.block_until_ready(out)
            times[k].append((time.perf_counter() - t0) / inner)
    return {k: float(np.median(v)) for k, v in times.items()}


def max_rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / np.max(np.abs(a)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--case", default="all")
    args = parser.parse_args()

    old_forward = baseline_module()
    prior = dc.DEFAULT_MOTOR
    plan_exp = dc.Experiment.from_plan(dc.default_plan())
    bench = dc.engine_bench(dc.default_plan(), prior, record_speed=True)
    cases = {"default plan": plan_exp, "measured speed": bench.experiment(measured_speed=True)}
    if args.case != "all":
        cases = {args.case: cases[args.case]}
    z = 0.03 * jax.random.normal(jax.random.PRNGKey(0), (args.batch, len(NAMES)))
    for case, experiment in cases.items():
        batch_exp = dataclasses.replace(experiment, linearised_tangents=False)
        one_exp = dataclasses.replace(experiment, linearised_tangents=True)
        fns = {}
        for label, predict in (("old", old_forward.predict_currents), ("new", forward.predict_currents)):
            one = sweep(predict, prior)
            fns[label, "B"] = jax.jit(jax.vmap(one, in_axes=(0, None)))
            fns[label, "1"] = jax.jit(one)
        ob, nb = fns["old", "B"](z, batch_exp), fns["new", "B"](z, batch_exp)
        o1, n1 = fns["old", "1"](z[0], one_exp), fns["new", "1"](z[0], one_exp)
        print(f"{case}: agreement B={args.batch}: value {max_rel(ob[0], nb[0]):.1e}, "
              f"jacobian {max_rel(ob[1], nb[1]):.1e}; B=1: value {max_rel(o1[0], n1[0]):.1e}, "
              f"jacobian {max_rel(o1[1], n1[1]):.1e}", flush=True)
        tb = time_alternating({k: (lambda f=fns[k, "B"]: f(z, batch_exp)) for k in ("old", "new")},
                              args.rounds, 1)
        print(f"{case}: B={args.batch} sweep  old {tb['old'] * 1e3:8.1f} ms  new {tb['new'] * 1e3:8.1f} ms  "
              f"x{tb['old'] / tb['new']:.2f}", flush=True)
        t1 = time_alternating({k: (lambda f=fns[k, "1"]: f(z[0], one_exp)) for k in ("old", "new")},
                              args.rounds, 20)
        print(f"{case}: B=1 sweep     old {t1['old'] * 1e3:8.3f} ms  new {t1['new'] * 1e3:8.3f} ms  "
              f"x{t1['old'] / t1['new']:.2f}", flush=True)


if __name__ == "__main__":
    main()
