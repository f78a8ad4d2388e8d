"""What the bench-effect selection costs: `--effects auto` (the default) against `--effects none`.

Each command runs as a fresh process, as a person or a test station waits for
it, after one untimed run so that its compiled functions come from the
persistent cache (the first run of a new installation is bench_startup's
subject). Timed ``--repeats`` times each, alternating the two settings so that
the machine's drift hits both alike; the median and the ratio auto/none are
reported.

* single fit: ``drivecal fit FILE --json`` on the ideal bench
  (examples/bench.csv: nothing to find, so auto adds its score tests only)
  and on the realistic inverter (examples/inverter_bench.csv: a one-sample
  delay, dead time and sensor offsets, so auto adds three refits);
* batch: ``drivecal batch DIR --workers 2`` on ``--motors`` synthetic motors of
  the default plan (fleet.synthetic_fleet), where only the motors whose
  residuals are not white go through the selection.

Prints a table and writes benchmarks/results/bench_effects.json.

    .venv/bin/python benchmarks/bench_effects.py [--repeats 3] [--motors 1000]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = Path(__file__).parent / "results" / "bench_effects.json"
DRIVECAL = Path(sys.executable).with_name("drivecal")


def _timed(args: list[str]) -> float:
    t0 = time.perf_counter()
    done = subprocess.run([str(DRIVECAL), *args], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    if done.returncode not in (0, 1, 3, 4):
        raise SystemExit(f"drivecal {' '.join(args)} failed ({done.returncode}): {done.stderr[-2000:]}")
    return elapsed


def _compare(label: str, make_args, repeats: int) -> dict:
    times: dict[str, list[float]] = {"none": [], "auto": []}
    for mode in times:  # untimed: fills the compilation cache
        _timed(make_args(mode, "warm-up"))
    for r in range(repeats):
        for mode in times:
            times[mode].append(_timed(make_args(mode, r)))
    row = {"case": label, **{f"{m}_median_s": statistics.median(t) for m, t in times.items()},
           **{f"{m}_runs_s": t for m, t in times.items()}}
    row["ratio_auto_over_none"] = row["auto_median_s"] / row["none_median_s"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--motors", type=int, default=1000)
    opts = parser.parse_args()
    rows = []
    for name in ("bench.csv", "inverter_bench.csv"):
        path = str(ROOT / "examples" / name)
        rows.append(_compare(f"fit {name}", lambda mode, _r, path=path: ["fit", path, "--json", "--effects", mode],
                             opts.repeats))
    with tempfile.TemporaryDirectory() as tmp:
        from drivecal import fleet

        directory = Path(tmp) / "fleet"
        fleet.synthetic_fleet(directory, opts.motors, seed=opts.motors)

        def batch_args(mode, r):
            out = Path(tmp) / f"out_{mode}_{r}.parquet"
            return ["batch", str(directory), "--out", str(out), "--json", "--workers", "2", "--effects", mode]

        row = _compare(f"batch {opts.motors} motors, 2 workers", batch_args, opts.repeats)
        for mode in ("none", "auto"):
            row[f"{mode}_motors_per_s"] = opts.motors / row[f"{mode}_median_s"]
        rows.append(row)
    print(f"{'case':<38} {'none [s]':>9} {'auto [s]':>9} {'auto/none':>9}")
    for row in rows:
        extra = (f"   {row['auto_motors_per_s']:.0f} motors/s with auto" if "auto_motors_per_s" in row else "")
        print(f"{row['case']:<38} {row['none_median_s']:>9.2f} {row['auto_median_s']:>9.2f} "
              f"{row['ratio_auto_over_none']:>9.2f}{extra}")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({"repeats": opts.repeats, "rows": rows}, indent=2))
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
