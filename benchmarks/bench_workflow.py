"""What a person waits for: whole drivecal commands as fresh processes, before and after, against the tutorial.

Every row is a fresh process (`python -c "from drivecal.cli import main; ..." ARGS`), timed for

  (a) the baseline tree (a commit checked out as a detached worktree under /tmp, created if
      missing; default: the commit this round of speed work started from), and
  (b) this working tree,

with the tutorial workflow (the seed's own code: its bench, Jacobian, identifiability and
Gauss-Newton for both designs; `bench_core.py --seed-workflow-only`, no compilation cache, as
the tutorial has none) timed in the same run. "cold" rows start each run on an empty compilation
cache (a machine's first run, what `make demo` does); "warm" rows run on a cache filled by one
discarded run of the same command. Medians are reported, of the wall time and of the CPU time
(user + system of the process and its children: less disturbed by other load on a shared
machine); the ratio columns are what to read (the machines here are noisy).

It also takes the cold demo apart phase by phase (`demo_phases.py`: import, engine bench, fit,
result JSON, figures + HTML, and compile/trace seconds by kernel) for both trees.

Prints tables and writes benchmarks/results/bench_workflow.json.

    .venv/bin/python benchmarks/bench_workflow.py [--runs 3] [--cold-runs 2] [--baseline-commit 76b0222]
        [--only TEXT] [--cache cold|warm|both] [--skip-phases] [--results FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

sys.path.insert(0, str(Path(__file__).parent))
from bench_startup import RUN_CLI, check_origin, ensure_baseline  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results" / "bench_workflow.json"
BASELINE_COMMIT = "76b0222"
EXAMPLES = ROOT / "examples"

#: (label, arguments, cache): "cold" = empty compilation cache each run, "warm" = cache from a run before.
#: "{out}" is replaced by a fresh temporary directory or file name each run.
CASES = (
    ("drivecal demo --out DIR", ["demo", "--out", "{out}"], "cold"),
    ("drivecal demo --out DIR", ["demo", "--out", "{out}"], "warm"),
    ("drivecal demo", ["demo"], "warm"),
    ("drivecal fit examples/bench.csv", ["fit", str(EXAMPLES / "bench.csv")], "cold"),
    ("drivecal fit examples/bench.csv", ["fit", str(EXAMPLES / "bench.csv")], "warm"),
    ("drivecal fit examples/bench.csv --out DIR", ["fit", str(EXAMPLES / "bench.csv"), "--out", "{out}"], "warm"),
    # a realistic bench: a switching inverter's delay and dead time, found by the effect selection
    ("drivecal fit examples/inverter_bench.csv", ["fit", str(EXAMPLES / "inverter_bench.csv")], "cold"),
    ("drivecal fit examples/inverter_bench.csv", ["fit", str(EXAMPLES / "inverter_bench.csv")], "warm"),
    ("drivecal simulate default_plan.toml", ["simulate", str(EXAMPLES / "default_plan.toml"), "--out",
                                             "{out}.csv"], "warm"),
    ("drivecal design default_plan.toml", ["design", str(EXAMPLES / "default_plan.toml")], "warm"),
    ("drivecal plan --motor motor.toml", ["plan", "--motor", str(EXAMPLES / "motor.toml"), "--vdc", "48", "--imax", "30",
                                          "--out", "{out}.toml"], "warm"),
    ("drivecal --help", ["--help"], "warm"),
    ("drivecal --version", ["--version"], "warm"),
)


def _env(src: Path, cache: str | None) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(src), "PYTHONWARNINGS": "ignore"}
    # as on a user's machine: Python keeps the compiled modules (a shell here sets PYTHONDONTWRITEBYTECODE,
    # which would make every process compile drivecal's ~200 modules from source again)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    if cache is None:
        env["DRIVECAL_JAX_CACHE"] = "0"
    else:
        env["DRIVECAL_JAX_CACHE"] = "1"
        env["DRIVECAL_JAX_CACHE_DIR"] = cache
    return env


def _cpu_of_children() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


#: CPU seconds (user + system) of each timed run, in the order of the runs (``_run`` appends).
CPU: list[float] = []


def _run(cmd: list[str], env: dict[str, str]) -> float:
    """Wall seconds of one fresh process running ``cmd``; its CPU seconds go to :data:`CPU`."""
    with tempfile.TemporaryDirectory(prefix="drivecal-wf-") as tmp:
        out = str(Path(tmp) / "out")
        args = [a.replace("{out}", out) for a in cmd]
        c0 = _cpu_of_children()
        t0 = time.perf_counter()
        proc = subprocess.run(args, capture_output=True, text=True, env=env)
        elapsed = time.perf_counter() - t0
        CPU.append(_cpu_of_children() - c0)
    # fit's exit status is its verdict's (0 calibrated); anything but a crash counts as a run
    if proc.returncode not in (0, 3, 4, 5, 6, 7):
        raise SystemExit(f"{' '.join(args)}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return elapsed


def time_case(src: Path, args: list[str], cache_kind: str, runs: int,
              warm_cache: str) -> tuple[list[float], list[float]]:
    """Wall and CPU seconds of ``runs`` fresh processes (each on an empty cache where ``cache_kind`` is cold)."""
    cmd = [sys.executable, "-c", RUN_CLI, *args]
    if cache_kind == "warm":
        _run(cmd, _env(src, warm_cache))  # fills the cache; discarded
        times = [_run(cmd, _env(src, warm_cache)) for _ in range(runs)]
        return times, CPU[-runs:]
    times = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory(prefix="drivecal-cold-cache-") as cache:
            times.append(_run(cmd, _env(src, cache)))
    return times, CPU[-runs:]


def time_tutorial(src: Path, runs: int) -> list[float]:
    cmd = [sys.executable, str(Path(__file__).parent / "bench_core.py"), "--seed-workflow-only"]
    return [_run(cmd, _env(src, None)) for _ in range(runs)]


def phases(src: Path) -> dict:
    with tempfile.TemporaryDirectory(prefix="drivecal-phases-cache-") as cache:
        proc = subprocess.run([sys.executable, str(Path(__file__).parent / "demo_phases.py")], capture_output=True,
                              text=True, env=_env(src, cache), check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="timed runs of each warm case (after one discarded)")
    parser.add_argument("--cold-runs", type=int, default=2, help="timed runs of each cold case")
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT)
    parser.add_argument("--baseline-dir", type=Path, default=None, help="its worktree (default /tmp/drivecal-wf-COMMIT)")
    parser.add_argument("--only", default=None, help="time only the cases whose label contains this text")
    parser.add_argument("--results", type=Path, default=RESULTS, help="the JSON file to write")
    parser.add_argument("--skip-phases", action="store_true", help="skip the cold demo's phase breakdown")
    parser.add_argument("--cache", choices=("cold", "warm", "both"), default="both",
                        help="time only the cold cases, only the warm ones, or both")
    args = parser.parse_args()

    base_dir = args.baseline_dir or Path(f"/tmp/drivecal-wf-{args.baseline_commit}")
    ensure_baseline(base_dir, args.baseline_commit)
    trees = {"baseline": base_dir / "src", "now": ROOT / "src"}
    for src in trees.values():
        check_origin(src)
    console = Console(width=150)
    rows = []
    caches = {name: tempfile.mkdtemp(prefix=f"drivecal-wf-cache-{name}-") for name in trees}
    with console.status("timing...") as status:
        status.update("the tutorial workflow")
        tutorial = time_tutorial(trees["now"], args.runs)
        t_tutorial = statistics.median(tutorial)
        for label, case, kind in CASES:
            if (args.only and args.only not in label) or args.cache not in ("both", kind):
                continue
            samples, cpu = {}, {}
            try:
                for name, src in trees.items():
                    status.update(f"{label} ({kind}, {name})")
                    samples[name], cpu[name] = time_case(src, case, kind,
                                                         args.cold_runs if kind == "cold" else args.runs, caches[name])
            except SystemExit as exc:  # one command failing costs its row, not the run
                console.print(f"[red]{escape(label)} ({kind}) failed[/red]: {escape(str(exc))[:300]}")
                continue
            base, now = (statistics.median(samples[n]) for n in trees)
            base_cpu, now_cpu = (statistics.median(cpu[n]) for n in trees)
            rows.append({"command": label, "cache": kind, "baseline_median_s": base, "now_median_s": now,
                         "baseline_over_now": base / now, "now_over_tutorial": now / t_tutorial,
                         "baseline_samples_s": samples["baseline"], "now_samples_s": samples["now"],
                         "baseline_cpu_median_s": base_cpu, "now_cpu_median_s": now_cpu,
                         "baseline_cpu_over_now": base_cpu / max(now_cpu, 1e-9),
                         "baseline_cpu_samples_s": cpu["baseline"], "now_cpu_samples_s": cpu["now"]})
        status.update("the cold demo, phase by phase")
        breakdown = {} if args.skip_phases else {name: phases(src) for name, src in trees.items()}

    table = Table(title=f"Whole commands, fresh processes: median of {args.runs} warm / {args.cold_runs} cold runs; "
                        f"tutorial workflow {t_tutorial:.1f} s", title_justify="left")
    table.add_column("command", justify="left", no_wrap=True)
    table.add_column("cache")
    table.add_column(escape(f"baseline {args.baseline_commit} [s]"), justify="right")
    table.add_column(escape("now [s]"), justify="right")
    table.add_column("baseline / now", justify="right")
    table.add_column("now / tutorial", justify="right")
    table.add_column(escape("CPU baseline [s]"), justify="right")
    table.add_column(escape("CPU now [s]"), justify="right")
    table.add_column("CPU baseline / now", justify="right")
    for r in rows:
        table.add_row(r["command"], r["cache"], f"{r['baseline_median_s']:.2f}", f"{r['now_median_s']:.2f}",
                      f"{r['baseline_over_now']:.2f}x", f"{r['now_over_tutorial']:.2f}",
                      f"{r['baseline_cpu_median_s']:.2f}", f"{r['now_cpu_median_s']:.2f}",
                      f"{r['baseline_cpu_over_now']:.2f}x")
    console.print(table)
    if breakdown:
        _print_phases(console, breakdown)

    args.results.parent.mkdir(parents=True, exist_ok=True)
    args.results.write_text(json.dumps({
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": sys.version.split()[0]},
        "baseline_commit": args.baseline_commit, "runs": args.runs, "cold_runs": args.cold_runs,
        "tutorial_workflow_s": tutorial, "tutorial_workflow_median_s": t_tutorial,
        "rows": rows, "cold_demo_phases": breakdown,
    }, indent=2) + "\n")
    console.print(f"wrote {args.results}")


def _print_phases(console: Console, breakdown: dict) -> None:
    ph = Table(title="The cold demo (`demo --out`, empty cache) phase by phase, one process", title_justify="left")
    ph.add_column("phase", justify="left")
    ph.add_column(escape("baseline [s]"), justify="right")
    ph.add_column(escape("now [s]"), justify="right")
    for key in breakdown["now"]["phases_s"]:
        ph.add_row(key, f"{breakdown['baseline']['phases_s'].get(key, float('nan')):.2f}",
                   f"{breakdown['now']['phases_s'][key]:.2f}")
    ph.add_row("(figures + HTML drawn in one process, no workers: their CPU work, not in the wall)",
               f"{breakdown['baseline'].get('figures_here_s', float('nan')):.2f}",
               f"{breakdown['now'].get('figures_here_s', float('nan')):.2f}")
    console.print(ph)
    kern = Table(title="Compile and trace seconds by kernel (now; baseline beside it), largest first", title_justify="left")
    kern.add_column("event", justify="left")
    kern.add_column("asked by > kernel", justify="left", no_wrap=True)
    kern.add_column(escape("baseline [s]"), justify="right")
    kern.add_column(escape("now [s]"), justify="right")
    for key, value in list(breakdown["now"]["compile_s"].items())[:14]:
        event, asker = key.split(" ", 1)
        kern.add_row(event, escape(asker), f"{breakdown['baseline']['compile_s'].get(key, 0.0):.2f}", f"{value:.2f}")
    console.print(kern)
    console.print(f"XLA compilations in the cold demo: baseline {breakdown['baseline']['compiles']}, "
                  f"now {breakdown['now']['compiles']}")


if __name__ == "__main__":
    main()
