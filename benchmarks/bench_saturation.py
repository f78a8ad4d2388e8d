"""Saturation benchmark: the saturating fit against the linear fit, on the same data, in one run.

Per motor, on the Jaxonomy engine with 20 mA noise, the saturating fit against the same motor without
saturation fitted with the linear model:

- Hinkkanen's 6.7-kW SyRM (published coefficients) on the multi-level locked plan of
  tests/selection/test_magnetics_selection.py (three levels per axis and two combined d+q steps, 800
  samples at 10 kHz); the saturating fit is R, Ld, Lq, sat_d, sat_q, sat_dq at the published exponents;
- Lelli et al.'s 5.5-kW PM-SyRM (examples/pm_syrm_motor.toml: its iron bridge) on the locked plan of
  tests/fitting/test_bridge_fit.py (several levels on each axis, both signs on d, d+q steps, 1 800
  samples); the saturating fit is all eleven coefficients of its law (lambda_m and the bridge's shape
  included), from a start far off.

Times, in this process (read the ratios; the machines here are noisy):

  (a) the linear fit and the saturating fit: first call (compile and solve) and warm single fits
      (median of --repeats);
  (b) both fits batched over --batch noise seeds in one call: motors per second.

Prints a table and writes benchmarks/results/bench_saturation.json.

    .venv/bin/python benchmarks/bench_saturation.py [--batch 64] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import drivecal as dc  # first: it quiets XLA's C++ log lines before JAX loads

import numpy as np

from drivecal.bench import SATURATION_LEVELS_PLAN as PLAN
from drivecal.bench import engine_bench, hinkkanen_syrm
from drivecal.physics import BRIDGE, MAGNETIC

RESULTS = Path(__file__).parent / "results" / "bench_saturation.json"
LINEAR = ("R", "Ld", "Lq")
SATURATING = LINEAR + ("sat_d", "sat_q", "sat_dq")
#: The PM-SyRM's locked levels (tests/fitting/test_bridge_fit.py): 10 ms each at 10 kHz, up to 18 A.
PM_LEVELS = dc.Plan(tuple(dc.Segment(n, 0.01, True, v_d=v_d, v_q=v_q) for n, v_d, v_q in (
    ("d 15 V", 15.0, 0.0), ("d 30 V", 30.0, 0.0), ("d 45 V", 45.0, 0.0), ("d -30 V", -30.0, 0.0),
    ("q 40 V", 0.0, 40.0), ("q 80 V", 0.0, 80.0), ("q 120 V", 0.0, 120.0),
    ("d+q", 30.0, 80.0), ("d-q", 30.0, -80.0))), sample_rate=10000.0, v_dc=540.0, current_limit=40.0)


def _motors():
    """Per motor: ``(name, plan, saturating truth, linear truth, linear start, saturating start, linear names,
    saturating names)``."""
    syrm = hinkkanen_syrm(i_ref=40.0)
    linear = syrm.replace(sat_d=0.0, sat_q=0.0, sat_dq=0.0)  # the same small-signal motor without saturation
    # The same start for both: the small-signal values 10 % off, no saturation known; the saturating fit
    # starts from the law's exponents with zero coefficients.
    start = linear.replace(R=0.5, Ld=1.1 * float(linear.Ld), Lq=0.9 * float(linear.Lq))
    yield "SyRM", PLAN, syrm, linear, start, start, LINEAR, SATURATING
    pm = dc.load_motor(Path(__file__).parents[1] / "examples" / "pm_syrm_motor.toml").motor
    pm_linear = pm.replace(**{n: 0.0 for n in MAGNETIC + BRIDGE}, sat_at_zero=0.0)
    # The start of tests/fitting/test_bridge_fit.py: 5-30 % off, the bridge's shape far off.
    pm_start = pm.replace(R=0.55, Ld=0.033, Lq=0.135, lambda_m=0.45, sat_d=0.003, sat_q=2.0, sat_dq=0.3, sat_b=0.3,
                          sat_bp=0.2, k_q=0.2, psi_n=1.0)
    pm_linear_start = pm_linear.replace(R=0.55, Ld=0.033, Lq=0.135)
    yield ("PM-SyRM", PM_LEVELS, pm, pm_linear, pm_linear_start, pm_start, LINEAR,
           ("R", "Ld", "Lq", "lambda_m") + MAGNETIC + BRIDGE)


def _timed(f):
    t0 = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    rows = []
    for motor, plan, truth_sat, truth_lin, start_lin, start_sat, names_lin, names_sat in _motors():
        for label, truth, start, names in (("linear", truth_lin, start_lin, names_lin),
                                           ("saturating", truth_sat, start_sat, names_sat)):
            clean = engine_bench(plan, truth)
            experiment = clean.experiment()
            rng = np.random.default_rng(0)
            single = clean.currents + rng.normal(0.0, 0.02, clean.currents.shape)
            batch = clean.currents[None] + rng.normal(0.0, 0.02, (args.batch,) + clean.currents.shape)

            def fit(currents, names=names, experiment=experiment, start=start):
                return dc.fit_currents(experiment, currents, start, names=names)

            first, t_first = _timed(lambda: fit(single))
            warm = [_timed(lambda: fit(single))[1] for _ in range(args.repeats)]
            fit(batch)  # compile the batched program
            out, t_batch = _timed(lambda: fit(batch))
            rows.append({"motor": motor, "model": label, "names": list(names), "samples": int(clean.currents.shape[0]),
                         "first_s": t_first, "warm_s": float(np.median(warm)), "batch": args.batch,
                         "batch_s": t_batch, "motors_per_s": args.batch / t_batch,
                         "converged": int(np.sum(out.converged)), "rss_single": float(first.rss)})
    print(f"{'motor':<8} {'model':<11} {'first call [s]':>15} {'warm fit [s]':>13} {'x linear':>9} "
          f"{'batch of ' + str(args.batch) + ' [s]':>16} {'motors/s':>9} {'x linear':>9} {'converged':>10}")
    for r in rows:
        base = next(b for b in rows if b["motor"] == r["motor"] and b["model"] == "linear")
        print(f"{r['motor']:<8} {r['model']:<11} {r['first_s']:>15.2f} {r['warm_s']:>13.3f} "
              f"{r['warm_s'] / base['warm_s']:>9.1f} {r['batch_s']:>16.2f} {r['motors_per_s']:>9.1f} "
              f"{base['motors_per_s'] / r['motors_per_s']:>9.1f} {r['converged']:>6}/{r['batch']}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"rows": rows, "samples": rows[0]["samples"],
                                   "machine": platform.platform(), "python": platform.python_version()}, indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
