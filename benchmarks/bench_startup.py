"""Startup benchmark: how fast the CLI answers `--help`, `--version` and `COMMAND --help`, and what each
command spends importing before it starts its work.

Each case runs as a fresh process, N times (the first run is discarded as a warm-up:
it fills the OS file cache and writes the .pyc files), and the median wall time is
reported, for

  (a) the baseline before the package was reorganised (commit c2334e8, checked out
      as a detached worktree in /tmp/drivecal-baseline, created if missing), run
      with this venv's python and PYTHONPATH=/tmp/drivecal-baseline/src;
  (b) this working tree (src/ of this checkout, the same way).

Both run ``python -c "import sys; from drivecal.cli import main; sys.exit(main())" ARGS``,
so neither pays for the console-script wrapper; before timing, each side checks that
``drivecal`` really is imported from its own tree.

Imports before work: for each command, a fresh process imports what the command imports before
its first computation (:data:`BEFORE_WORK`: its module, the imports at the top of its body and
those of the helpers it calls first, such as ``--motor``'s loader) and reports that wall time,
timed inside the process (the interpreter's own start-up left out), with the garbage collector
set as the ``drivecal`` program sets it before its imports. What the work itself
imports later (pandas inside the bench loader, scipy.special at the first interval) is not in
it: for that, time whole commands (bench_workflow.py). The baseline here is the tree before the
imports were made lazy (commit 76b0222, a detached worktree in /tmp/drivecal-imports-baseline;
``--imports-baseline-commit`` names another, e.g. a stop's start); the two trees' runs alternate.
``fleet-report`` is the command without ``--motor`` (the page alone), ``fleet-report --motor``
with it (it reads the motor file's values and limits).

Prints two tables and writes benchmarks/results/bench_startup.json.

    .venv/bin/python benchmarks/bench_startup.py [--runs 7] [--baseline-commit c2334e8]
        [--imports-baseline-commit 76b0222]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results" / "bench_startup.json"
BASELINE_DIR = Path("/tmp/drivecal-baseline")
BASELINE_COMMIT = "c2334e8"
RUN_CLI = "import sys; from drivecal.cli import main; sys.exit(main())"
#: The commands of the CLI (the same in the baseline and now).
COMMANDS = ("batch", "demo", "design", "fit", "fleet-report", "gains", "plan", "report", "simulate")
IMPORTS_BASELINE_DIR = Path("/tmp/drivecal-imports-baseline")
IMPORTS_BASELINE_COMMIT = "76b0222"
#: Per command, the modules it imports before its first computation, in order (src/drivecal/cli/_COMMAND.py:
#: the command's module, the imports at the top of its body, then those of the helpers it calls first).
BEFORE_WORK: dict[str, tuple[str, ...]] = {
    "batch": ("drivecal.cli._batch", "rich.progress", "drivecal.errors", "drivecal.fleet", "drivecal.fleet._batch",
              "drivecal.fleet._runners", "drivecal.selection", "drivecal.data"),
    "demo": ("drivecal.cli._demo", "drivecal.demo"),
    "design": ("drivecal.cli._design", "drivecal.design", "drivecal.identify", "drivecal.model", "drivecal.plan",
               "drivecal.data"),
    "fit": ("drivecal.cli._fit", "rich.markup", "drivecal.data", "drivecal.diagnose", "drivecal.identify",
            "drivecal.report", "drivecal.results", "drivecal.selection"),
    "fleet-report": ("drivecal.cli._fleet_report", "drivecal.fleet", "drivecal.fleet._report"),
    "fleet-report --motor": ("drivecal.cli._fleet_report", "drivecal.fleet", "drivecal.fleet._report",
                             "drivecal.data"),
    "gains": ("drivecal.cli._gains", "drivecal.errors", "drivecal._io", "drivecal.fitting", "drivecal.report",
              "drivecal.results"),
    "inspect": ("drivecal.cli._inspect", "rich.markup", "rich.table", "drivecal._io", "drivecal.data"),
    "plan": ("drivecal.cli._plan", "drivecal.design", "drivecal.plan", "drivecal.data"),
    "report": ("drivecal.cli._report", "drivecal.report", "drivecal.results"),
    "simulate": ("drivecal.cli._simulate", "drivecal.errors", "drivecal.plan", "drivecal.data"),
}
#: What the default imports baseline (76b0222) imported before the work besides: `demo` loaded the figure module
#: (matplotlib) with or without --out. Another baseline (``--imports-baseline-commit``) imports the lists as they are.
BASELINE_ONLY: dict[str, tuple[str, ...]] = {"demo": ("drivecal._figures",)}
#: What this tree imports before the work besides, and a baseline too where its tree has the module: `fleet-report
#: --motor` reads the motor file's values and limits through ``data._nominal`` (stop 64); before, ``drivecal.data``
#: itself loaded the motor's loader, ``physics`` and JAX.
NOW_ONLY: dict[str, tuple[str, ...]] = {"fleet-report --motor": ("drivecal.data._nominal",)}
#: Heavy libraries: which of them a command has loaded when its work starts (a column of the table).
HEAVY = ("jax", "equinox", "optimistix", "pydantic", "pandas", "pyarrow", "scipy.special", "matplotlib", "jaxonomy")
IMPORT_TIMER = ("import gc, importlib, json, sys, time\n"
                "gc.set_threshold(int(sys.argv.pop(1)), *gc.get_threshold()[1:])\n"
                "t0 = time.perf_counter()\n"
                "for name in sys.argv[1:]:\n"
                "    importlib.import_module(name)\n"
                "seconds = time.perf_counter() - t0\n"
                f"print(json.dumps([seconds, [m for m in {HEAVY!r} if m in sys.modules]]))\n")


def ensure_baseline(path: Path, commit: str) -> None:
    """Check out ``commit`` as a detached worktree at ``path`` unless it is there already."""
    if (path / "src" / "drivecal").is_dir():
        head = subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True,
                              check=True).stdout.strip()
        want = subprocess.run(["git", "-C", str(ROOT), "rev-parse", commit], capture_output=True, text=True,
                              check=True).stdout.strip()
        if head != want:
            raise SystemExit(f"{path} holds {head[:10]}, not {commit}: remove it (git worktree remove {path}) "
                             "and run again")
        return
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(path), commit], check=True,
                   capture_output=True)


def env_for(src: Path) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(src), "PYTHONWARNINGS": "ignore"}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as on a user's machine: compiled modules kept (bench_workflow)
    return env


def check_origin(src: Path) -> str:
    """The file ``drivecal`` is imported from with PYTHONPATH=src; it must lie under src."""
    out = subprocess.run([sys.executable, "-c", "import drivecal.cli; print(drivecal.cli.__file__)"],
                         capture_output=True, text=True, check=True, env=env_for(src)).stdout.strip()
    if not Path(out).resolve().is_relative_to(src.resolve()):
        raise SystemExit(f"PYTHONPATH={src}: drivecal.cli came from {out}, not from that tree")
    return out


def time_runs(src: Path, args: list[str], runs: int) -> list[float]:
    """Wall times of ``runs`` fresh processes (the first, a warm-up, dropped); each must exit 0."""
    env = env_for(src)
    times = []
    for _ in range(runs + 1):
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-c", RUN_CLI, *args], capture_output=True, text=True, env=env)
        times.append(time.perf_counter() - t0)
        if proc.returncode != 0:
            raise SystemExit(f"PYTHONPATH={src} drivecal {' '.join(args)}: exit {proc.returncode}\n{proc.stderr}")
    return times[1:]


def time_imports(src: Path, modules: tuple[str, ...]) -> tuple[float, list[str]]:
    """Wall time [s] of importing ``modules`` in a fresh process, and the heavy libraries then loaded."""
    # The drivecal program imports with the garbage collector's youngest generation raised (cli._common.main; this
    # tree's setting for both trees): without it, the full collections it avoids were ~0.1 s of a command's imports.
    from drivecal.cli._common import YOUNG_GENERATION

    proc = subprocess.run([sys.executable, "-c", IMPORT_TIMER, str(YOUNG_GENERATION), *modules], capture_output=True,
                          text=True, env=env_for(src))
    if proc.returncode != 0:
        raise SystemExit(f"PYTHONPATH={src}: importing {', '.join(modules)} failed\n{proc.stderr}")
    seconds, loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    return seconds, loaded


def imports_before_work(trees: dict[str, Path], runs: int, status, baseline_only: dict[str, tuple[str, ...]]
                        ) -> list[dict]:
    """Per command: each tree's import time before work, ``runs`` fresh processes each (after one
    warm-up), the trees alternating run by run; the medians, their ratio and what each had loaded.
    ``baseline_only``: per command, what the baseline imported besides (:data:`BASELINE_ONLY`, or none)."""
    rows = []
    for command, modules in BEFORE_WORK.items():
        samples: dict[str, list[float]] = {name: [] for name in trees}
        loaded: dict[str, list[str]] = {}
        later = NOW_ONLY.get(command, ())
        had = tuple(m for m in later if (trees["baseline"] / Path(*m.split("."))).with_suffix(".py").exists())
        lists = {"baseline": modules[:1] + baseline_only.get(command, ()) + modules[1:] + had,
                 "now": modules + later}
        for k in range(runs + 1):
            for name, src in trees.items():
                status.update(f"imports before work: {command} ({name}, run {k + 1} of {runs + 1})")
                seconds, loaded[name] = time_imports(src, lists[name])
                if k:  # the first run of each tree is the warm-up
                    samples[name].append(seconds)
        base, now = (statistics.median(samples[n]) for n in ("baseline", "now"))
        rows.append({"command": command, "baseline_modules": list(lists["baseline"]), "now_modules": list(modules),
                     "baseline_median_s": base, "now_median_s": now,
                     "ratio_baseline_over_now": base / now, "baseline_loaded": loaded["baseline"],
                     "now_loaded": loaded["now"], "baseline_samples_s": samples["baseline"],
                     "now_samples_s": samples["now"]})
    return rows


def imports_table(rows: list[dict], runs: int, commit: str) -> Table:
    table = Table(title=f"Imports before work, fresh processes: median of {runs} runs (after one warm-up)",
                  title_justify="left")
    table.add_column("command", justify="left", no_wrap=True)
    table.add_column(escape(f"baseline {commit} [s]"), justify="right")
    table.add_column(escape("now [s]"), justify="right")
    table.add_column("baseline / now", justify="right")
    table.add_column("no longer loaded before work", justify="left")
    for r in rows:
        gone = [m for m in r["baseline_loaded"] if m not in r["now_loaded"]]
        table.add_row(r["command"], f"{r['baseline_median_s']:.3f}", f"{r['now_median_s']:.3f}",
                      f"{r['ratio_baseline_over_now']:.2f}x", ", ".join(gone) or "-")
    return table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="timed runs per case (after one warm-up run)")
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT, help="the commit timed as the baseline")
    parser.add_argument("--baseline-dir", type=Path, default=BASELINE_DIR, help="where its worktree lives")
    parser.add_argument("--imports-baseline-commit", default=IMPORTS_BASELINE_COMMIT,
                        help="the commit whose imports before work are timed as the baseline")
    parser.add_argument("--imports-baseline-dir", type=Path, default=IMPORTS_BASELINE_DIR,
                        help="where its worktree lives")
    args = parser.parse_args()

    ensure_baseline(args.baseline_dir, args.baseline_commit)
    ensure_baseline(args.imports_baseline_dir, args.imports_baseline_commit)
    trees = {"baseline": args.baseline_dir / "src", "now": ROOT / "src"}
    import_trees = {"baseline": args.imports_baseline_dir / "src", "now": ROOT / "src"}
    origins = {name: check_origin(src) for name, src in {**trees, "imports_baseline": import_trees["baseline"]}.items()}
    cases = [["--help"], ["--version"]] + [[c, "--help"] for c in COMMANDS]

    console = Console()
    rows = []
    with console.status("timing...") as status:
        for case in cases:
            label = "drivecal " + " ".join(case)
            samples = {}
            for name, src in trees.items():
                status.update(f"{label} ({name})")
                samples[name] = time_runs(src, case, args.runs)
            base, now = (statistics.median(samples[n]) for n in ("baseline", "now"))
            rows.append({"command": label, "baseline_median_s": base, "now_median_s": now,
                         "ratio_baseline_over_now": base / now,
                         "baseline_samples_s": samples["baseline"], "now_samples_s": samples["now"]})
        baseline_only = BASELINE_ONLY if args.imports_baseline_commit == IMPORTS_BASELINE_COMMIT else {}
        import_rows = imports_before_work(import_trees, args.runs, status, baseline_only)

    table = Table(title=f"CLI startup, fresh processes: median of {args.runs} runs (after one warm-up)",
                  title_justify="left")
    table.add_column("command", justify="left", no_wrap=True)
    table.add_column(escape(f"baseline {args.baseline_commit} [s]"), justify="right")  # "[s]" is not a style
    table.add_column(escape("now [s]"), justify="right")
    table.add_column("baseline / now", justify="right")
    for r in rows:
        table.add_row(r["command"], f"{r['baseline_median_s']:.3f}", f"{r['now_median_s']:.3f}",
                      f"{r['ratio_baseline_over_now']:.1f}x")
    console.print(table)
    console.print(imports_table(import_rows, args.runs, args.imports_baseline_commit))

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
                    "executable": sys.executable},
        "runs": args.runs,
        "warmup_runs_discarded": 1,
        "baseline": {"commit": args.baseline_commit, "src": str(trees["baseline"]),
                     "drivecal_cli": origins["baseline"]},
        "now": {"src": str(trees["now"]), "drivecal_cli": origins["now"]},
        "invocation": f"{sys.executable} -c {RUN_CLI!r} ARGS",
        "rows": rows,
        "imports_before_work": {
            "baseline": {"commit": args.imports_baseline_commit, "src": str(import_trees["baseline"]),
                         "drivecal_cli": origins["imports_baseline"]},
            "invocation": f"{sys.executable} -c IMPORT_TIMER MODULES (benchmarks/bench_startup.py)",
            "rows": import_rows,
        },
    }, indent=2) + "\n")
    console.print(f"wrote {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
