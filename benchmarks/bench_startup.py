"""Startup benchmark: how fast the CLI answers `--help`, `--version` and `COMMAND --help`.

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

Prints a table and writes benchmarks/results/bench_startup.json.

    .venv/bin/python benchmarks/bench_startup.py [--runs 7] [--baseline-commit c2334e8]
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
    return {**os.environ, "PYTHONPATH": str(src), "PYTHONWARNINGS": "ignore"}


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7, help="timed runs per case (after one warm-up run)")
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT, help="the commit timed as the baseline")
    parser.add_argument("--baseline-dir", type=Path, default=BASELINE_DIR, help="where its worktree lives")
    args = parser.parse_args()

    ensure_baseline(args.baseline_dir, args.baseline_commit)
    trees = {"baseline": args.baseline_dir / "src", "now": ROOT / "src"}
    origins = {name: check_origin(src) for name, src in trees.items()}
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
    }, indent=2) + "\n")
    console.print(f"wrote {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
