"""Saturation benchmark: the saturating fit against the linear fit, on the same data, in one run.

Hinkkanen's 6.7-kW SyRM (published coefficients) on the Jaxonomy engine, fitted
with the saturating law, against the same motor without saturation fitted
with the linear model; both on the
multi-level locked plan of tests/selection/test_magnetics_selection.py (three
levels per axis and two combined d+q steps, 800 samples at 10 kHz), 20 mA noise.
Times, in this process (read the ratios; the machines here are noisy):

  (a) the linear fit (R, Ld, Lq) and the saturating fit (R, Ld, Lq, sat_d,
      sat_q, sat_dq at the published exponents): first call (compile and
      solve) and warm single fits (median of --repeats);
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

RESULTS = Path(__file__).parent / "results" / "bench_saturation.json"
LINEAR = ("R", "Ld", "Lq")
SATURATING = LINEAR + ("sat_d", "sat_q", "sat_dq")


def _timed(f):
    t0 = time.perf_counter()
    out = f()
    return out, time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    syrm = hinkkanen_syrm(i_ref=40.0)
    linear = syrm.replace(sat_d=0.0, sat_q=0.0, sat_dq=0.0)  # the same small-signal motor without saturation
    # The same start for both: the small-signal values 10 % off, no saturation known; the saturating fit
    # starts from the law's exponents with zero coefficients.
    start = linear.replace(R=0.5, Ld=1.1 * float(linear.Ld), Lq=0.9 * float(linear.Lq))
    rows = []
    for label, truth, names in (("linear", linear, LINEAR), ("saturating", syrm, SATURATING)):
        clean = engine_bench(PLAN, truth)
        experiment = clean.experiment()
        rng = np.random.default_rng(0)
        single = clean.currents + rng.normal(0.0, 0.02, clean.currents.shape)
        batch = clean.currents[None] + rng.normal(0.0, 0.02, (args.batch,) + clean.currents.shape)

        def fit(currents, names=names, experiment=experiment):
            return dc.fit_currents(experiment, currents, start, names=names)

        first, t_first = _timed(lambda: fit(single))
        warm = [_timed(lambda: fit(single))[1] for _ in range(args.repeats)]
        fit(batch)  # compile the batched program
        out, t_batch = _timed(lambda: fit(batch))
        rows.append({"model": label, "names": list(names), "first_s": t_first, "warm_s": float(np.median(warm)),
                     "batch": args.batch, "batch_s": t_batch, "motors_per_s": args.batch / t_batch,
                     "converged": int(np.sum(out.converged)), "rss_single": float(first.rss)})
    base = rows[0]
    print(f"{'model':<11} {'first call [s]':>15} {'warm fit [s]':>13} {'x linear':>9} "
          f"{'batch of ' + str(args.batch) + ' [s]':>16} {'motors/s':>9} {'x linear':>9}")
    for r in rows:
        print(f"{r['model']:<11} {r['first_s']:>15.2f} {r['warm_s']:>13.3f} {r['warm_s'] / base['warm_s']:>9.1f} "
              f"{r['batch_s']:>16.2f} {r['motors_per_s']:>9.1f} {base['motors_per_s'] / r['motors_per_s']:>9.1f}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"rows": rows, "samples": int(clean.currents.shape[0]),
                                   "machine": platform.platform(), "python": platform.python_version()}, indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
