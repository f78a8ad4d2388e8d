"""Where a warm command's time goes into its kernels: loading each kept executable, program by program.

A warm `drivecal fit` runs no compiler: every kernel it needs is a kept executable
(``model._lowered_cache``), deserialised by XLA when first called. This benchmark
runs a command (default: `drivecal fit examples/inverter_bench.csv`) on an empty
compilation cache, then warm, as fresh processes, and reports:

- per kept program: its size on disk, the number of instructions of its
  optimised HLO module, and the median time to load it (``repeats`` loads in
  a fresh process after the imports, one program after the other, no other work),
  with a straight line fitted through load time against instructions;
- per warm run: the seconds spent loading kernels during the command, in the
  main thread and in the helper threads (``compiled_ahead``), against its wall time;
- the same with JAX's Python tracebacks left out of the programs' locations
  (``JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS=0``: smaller programs on disk,
  the same kernels), each variant on a cache of its own, warm runs alternating,
  with their outputs compared.

Prints a table and writes benchmarks/results/bench_kernel_load.json.

    .venv/bin/python benchmarks/bench_kernel_load.py [--repeats 5] [-- fit examples/inverter_bench.csv]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results" / "bench_kernel_load.json"
VARIANTS = {"default": {}, "no tracebacks": {"JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS": "0"}}
#: Runs the CLI with drivecal's executable loader timed per thread; prints the totals to stderr as JSON.
RUN_TIMED = """
import json, sys, threading, time
from drivecal.model import _lowered_cache as cache
spent = {"main": 0.0, "helpers": 0.0, "loads": 0}
load = cache._executable
def timed(*args, **kwargs):
    start = time.perf_counter()
    try:
        return load(*args, **kwargs)
    finally:
        where = "main" if threading.current_thread() is threading.main_thread() else "helpers"
        spent[where] += time.perf_counter() - start
        spent["loads"] += 1
cache._executable = timed
from drivecal.cli import main
sys.argv = ["drivecal"] + sys.argv[1:]
try:
    main()
finally:
    sys.stdout.flush()
    print("KERNEL-LOAD " + json.dumps(spent), file=sys.stderr, flush=True)
"""
#: Loads every kept executable of a cache ``repeats`` times in this process; prints one JSON row per program.
LOAD_EACH = """
import glob, json, os, pickle, statistics, sys, time, zlib
import drivecal._setup  # noqa: F401  (JAX set up as a command sets it up)
from drivecal.model import _lowered_cache as cache
cache._initialize_lapack()
for path in sorted(glob.glob(os.path.join(str(cache.directory()), "*.pkl"))):
    data = open(path, "rb").read()
    if data == cache._UNKEPT:
        continue
    raw = zlib.decompress(data)
    kept = pickle.loads(raw)[2]
    if kept is None:
        continue
    times = []
    for _ in range(int(sys.argv[1])):
        start = time.perf_counter()
        run = cache._executable(kept, b"lapack" in raw)
        times.append(time.perf_counter() - start)
    lines = [line for line in run.as_text().splitlines() if " = " in line]
    print(json.dumps({"program": os.path.basename(path)[:-4][:-24], "bytes": len(data), "instructions": len(lines),
                      "load_ms": 1e3 * statistics.median(times)}))
"""


def _run(args: list[str], env: dict[str, str]) -> tuple[float, str, dict]:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", RUN_TIMED, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - start
    line = next((x for x in done.stderr.splitlines() if x.startswith("KERNEL-LOAD ")), None)
    if line is None:
        sys.exit(f"the command failed:\n{done.stderr[-2000:]}")
    return wall, done.stdout, json.loads(line.split(" ", 1)[1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="warm runs of each variant, and loads of each program")
    parser.add_argument("command", nargs="*", default=["fit", "examples/inverter_bench.csv"])
    options = parser.parse_args()
    from rich.console import Console
    from rich.markup import escape

    from drivecal.cli._common import BLAS_THREAD_VARIABLES
    from rich.table import Table

    console = Console(width=150)
    with tempfile.TemporaryDirectory() as root:
        # The drivecal program sets OpenBLAS to one thread where no variable does (cli._common.main); the timed
        # runs import drivecal before main() runs, so the variable is set for them here.
        blas = {} if any(os.environ.get(n) for n in BLAS_THREAD_VARIABLES) else {BLAS_THREAD_VARIABLES[0]: "1"}
        envs = {v: {**os.environ, **blas, **extra, "DRIVECAL_JAX_CACHE_DIR": str(Path(root) / str(i))}
                for i, (v, extra) in enumerate(VARIANTS.items())}
        cold = {v: _run(options.command, env)[0] for v, env in envs.items()}
        warm: dict[str, list] = {v: [] for v in envs}
        for _ in range(options.repeats):
            for v, env in envs.items():
                warm[v].append(_run(options.command, env))
        outputs = {v: {run[1] for run in runs} for v, runs in warm.items()}
        same = len(set().union(*outputs.values())) == 1
        programs = {}
        for v, env in envs.items():
            done = subprocess.run([sys.executable, "-c", LOAD_EACH, str(options.repeats)], cwd=ROOT, env=env,
                                  capture_output=True, text=True, check=True)
            programs[v] = {row["program"]: row for row in map(json.loads, done.stdout.splitlines())}
    table = Table(title=f"kept programs of `drivecal {' '.join(options.command)}`, median of {options.repeats} loads")
    for header in ("program", "HLO instructions", "KiB (default)", "load [ms] (default)", "KiB (no tracebacks)",
                   "load [ms] (no tracebacks)"):
        table.add_column(escape(header), justify="left" if header == "program" else "right")
    base, other = programs["default"], programs["no tracebacks"]
    for name in sorted(base):
        row, alt = base[name], other.get(name, {})
        table.add_row(name, str(row["instructions"]), f"{row['bytes'] / 1024:.0f}", f"{row['load_ms']:.0f}",
                      f"{alt['bytes'] / 1024:.0f}" if alt else "-", f"{alt['load_ms']:.0f}" if alt else "-")
    table.add_row("all", str(sum(r["instructions"] for r in base.values())),
                  f"{sum(r['bytes'] for r in base.values()) / 1024:.0f}",
                  f"{sum(r['load_ms'] for r in base.values()):.0f}",
                  f"{sum(r['bytes'] for r in other.values()) / 1024:.0f}",
                  f"{sum(r['load_ms'] for r in other.values()):.0f}")
    console.print(table)
    import numpy as np

    rows = list(base.values())
    per_instruction, fixed = np.polyfit([r["instructions"] for r in rows], [r["load_ms"] for r in rows], 1)
    console.print(f"load time against size (default, least squares): {fixed:.1f} ms + "
                  f"{1e3 * per_instruction:.1f} us per HLO instruction")
    summary = {}
    for v, runs in warm.items():
        summary[v] = {"cold_wall_s": cold[v], "warm_wall_s": [r[0] for r in runs],
                      "warm_wall_median_s": statistics.median(r[0] for r in runs),
                      "loading_main_s": statistics.median(r[2]["main"] for r in runs),
                      "loading_helpers_s": statistics.median(r[2]["helpers"] for r in runs),
                      "loads": runs[0][2]["loads"]}
    commands = Table(title=f"the command, fresh processes, median of {options.repeats} warm runs (alternating)")
    for header in ("variant", "cold [s]", "warm [s]", "kernels loaded", "loading, main thread [s]",
                   "loading, helper threads [s]"):
        commands.add_column(escape(header), justify="left" if header == "variant" else "right")
    for v, s in summary.items():
        commands.add_row(v, f"{s['cold_wall_s']:.2f}", f"{s['warm_wall_median_s']:.2f}", str(s["loads"]),
                         f"{s['loading_main_s']:.2f}", f"{s['loading_helpers_s']:.2f}")
    console.print(commands)
    ratio = summary["default"]["warm_wall_median_s"] / summary["no tracebacks"]["warm_wall_median_s"]
    console.print(f"warm, default / no tracebacks: {ratio:.2f}x; outputs {'the same' if same else 'DIFFER'}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"command": options.command, "repeats": options.repeats, "same_output": same,
                                   "load_ms_fixed": fixed, "load_us_per_instruction": 1e3 * per_instruction,
                                   "commands": summary, "programs": programs}, indent=2) + "\n")
    console.print(f"wrote {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
