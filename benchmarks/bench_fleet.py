"""Fleet benchmark: `drivecal batch` end to end on synthetic production runs.

For 10, 100, 1 000 and 10 000 motors of the default plan (one bench file each,
Parquet or CSV: ``--formats``; 2 % manufacturing spread, 20 mA noise, measured
speed), runs `drivecal batch DIR --out ... --json` as a fresh process in four
ways (``--placements``):

- default options: no placement flag, as a user runs it (the batch picks its own);
- `--workers 1`: everything in that process;
- `--workers 2`: two helpers forked from that process, each pinned to one of this
  machine's 2 cores (that process hands out the chunks and saves their rows);
- `--scheduler ADDRESS`: chunks sent to a 2-worker dask LocalCluster that the
  benchmark starts once, after the local runs (an idle cluster takes ~12 % of
  a core here), and keeps for every count (as a production cluster runs
  between batches: its workers compile on their first chunk and keep the fit).

It records wall time, motors/s, the marginal motors/s (from the next smaller
count run the same way: what each further motor costs, start-up cancelled out)
and the peak resident memory of the largest process (chunking must keep it flat as the count grows); each is run
``--repeats`` times and the median and best are reported, since this
machine's speed drifts by tens of percent from one minute to the next (a
pure-Python CPU probe, timed before and after, records how fast it ran). Then
it runs the same 100-motor batch twice with an empty persistent compilation
cache to show what the cache saves on the second invocation.

Times include start-up and file reading. Before each timed run the bench files
are put in the page cache (``--page-cache warm``: as just written by the test
benches) or dropped from it (``cold``: a backlog on disk; Linux, root), so
every run starts alike. Each count is run once untimed first
so that the compiled fit comes from the persistent cache, as it does for every
batch after a line's first one (the cold start is measured separately).
Prints a table and writes benchmarks/results/bench_fleet.json.

    .venv/bin/python benchmarks/bench_fleet.py [--counts 10 100 1000 10000] [--chunk 256] [--repeats 3]
        [--page-cache warm|cold|both] [--formats parquet csv] [--placements default 1 2 dask] [--skip-cache-runs]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).parent / "results" / "bench_fleet.json"
DRIVECAL = Path(sys.executable).with_name("drivecal")


def _generate(root: Path, count: int, fmt: str = "parquet") -> Path:
    from drivecal import fleet

    directory = root / (f"fleet_{count}" if fmt == "parquet" else f"fleet_{count}_{fmt}")
    if not directory.exists():
        fleet.synthetic_fleet(directory, count, seed=count, suffix=f".{fmt}")
    return directory


def _cpu_probe() -> float:
    """Seconds for a fixed pure-Python loop (best of three): how fast this machine runs right now.

    Its speed drifts by tens of percent over a day; the probe, taken before and after the runs, lets
    figures of different days be compared.
    """
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        sum(range(30_000_000))
        best = min(best, time.perf_counter() - start)
    return best


def _set_page_cache(directory: Path, state: str) -> None:
    """Put the fleet's bench files in the page cache (``"warm"``: as just written by the benches) or out of it
    (``"cold"``: as on a backlog or a network share; drops the whole system's page cache, Linux and root only)."""
    if state == "warm":
        for entry in os.scandir(directory):
            with open(entry.path, "rb") as f:
                while f.read(1 << 20):
                    pass
        return
    os.sync()
    try:
        Path("/proc/sys/vm/drop_caches").write_text("3\n")
    except OSError as exc:
        sys.exit(f"--page-cache cold: cannot drop the page cache ({exc}); it needs Linux and root. Use "
                 "--page-cache warm.")


def _add_marginal(rows: list[dict]) -> None:
    """Add to each row the marginal throughput from the next smaller count run the same way (format, placement,
    page cache): ``(count - smaller) / (wall - its wall)``, motors/s once the batch runs, start-up (imports,
    loading the compiled fit, helpers) and the last chunk's tail cancelled out. Issue 21's targets are of
    this kind."""
    def way(r: dict) -> tuple:
        return r["format"], r["placement"], r["page_cache"]

    for key in dict.fromkeys(map(way, rows)):
        same = sorted((r for r in rows if way(r) == key), key=lambda r: r["count"])
        for smaller, r in zip(same, same[1:]):
            extra = r["wall_s"] - smaller["wall_s"]
            r["marginal_from"] = smaller["count"]
            r["marginal_motors_per_s"] = (r["count"] - smaller["count"]) / extra if extra > 0 else float("inf")


def _where(mode: str) -> list[str]:
    """The CLI options that place the chunks: none (``""``: the defaults), ``"1"``/``"2"`` local processes, else
    a scheduler address."""
    if not mode:
        return []
    return ["--workers", mode] if mode.isdigit() else ["--scheduler", mode]


def _run_batch(directory: Path, out: Path, mode: str, chunk: int, env: dict | None = None) -> dict:
    """One `drivecal batch` in a fresh process: wall time and motors/s."""
    cmd = [str(DRIVECAL), "batch", str(directory), "--out", str(out), "--chunk", str(chunk), *_where(mode),
           "--json"]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, **(env or {})})
    stdout, stderr = proc.communicate()
    wall = time.perf_counter() - start
    if proc.returncode not in (0, 1):
        raise RuntimeError(f"{cmd} failed: {stderr[-2000:]}")
    summary = json.loads(stdout)
    return {"wall_s": wall, "motors": summary["total"], "motors_per_s": summary["total"] / wall}


def _peak_rss_of(directory: Path, out: Path, mode: str, chunk: int) -> dict:
    """Run the batch in a child Python that reports its own children's peak RSS (isolated from earlier runs)."""
    code = (
        "import json, resource, sys, time, subprocess, os\n"
        f"cmd = {[str(DRIVECAL), 'batch', str(directory), '--out', str(out), '--chunk', str(chunk), *_where(mode), '--json']!r}\n"  # noqa: E501
        "t = time.perf_counter(); p = subprocess.run(cmd, capture_output=True, text=True)\n"
        "wall = time.perf_counter() - t\n"
        "if p.returncode not in (0, 1): sys.exit(p.stderr[-2000:])\n"
        "s = json.loads(p.stdout)\n"
        "print(json.dumps({'wall_s': wall, 'motors': s['total'], 'failed': s['failed'],"
        " 'peak_rss_mib': resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024}))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-3000:] or proc.stdout[-3000:])
    row = json.loads(proc.stdout)
    row["motors_per_s"] = row["motors"] / row["wall_s"]
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--counts", type=int, nargs="+", default=[10, 100, 1000, 10000])
    parser.add_argument("--chunk", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=3, help="timed runs of each count and placement")
    parser.add_argument("--warm-up-max", type=int, default=1000,
                        help="run counts up to this once untimed first (warm persistent cache)")
    parser.add_argument("--page-cache", choices=("warm", "cold", "both"), default="warm",
                        help="bench files read into the page cache before each timed run (warm), dropped from it "
                             "(cold: Linux, root), or both in turn")
    parser.add_argument("--workdir", type=Path, default=None, help="keep generated fleets here (default: a temp dir)")
    parser.add_argument("--formats", nargs="+", choices=("parquet", "csv"), default=["parquet", "csv"],
                        help="bench-file formats of the fleets")
    parser.add_argument("--placements", nargs="+", choices=("default", "1", "2", "dask"),
                        default=["default", "1", "2", "dask"],
                        help="default options, --workers 1, --workers 2, a 2-worker dask cluster")
    parser.add_argument("--skip-cache-runs", action="store_true", help="skip the empty-cache runs of 100 motors")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args()

    import statistics

    from distributed import LocalCluster

    import drivecal

    probe_before = _cpu_probe()
    root = args.workdir or Path(tempfile.mkdtemp(prefix="drivecal-fleet-bench-"))
    root.mkdir(parents=True, exist_ok=True)
    rows = []
    directories = {}
    for count in args.counts:
        for fmt in args.formats:
            t = time.perf_counter()
            directories[count, fmt] = _generate(root, count, fmt), time.perf_counter() - t
            if count <= args.warm_up_max:
                # One untimed invocation first, so the timed ones find the compiled fit for this count's
                # batch shape in the persistent cache, as every batch after the first one on a line does
                # (chunks are of equal size: 10 000 motors use the shape of 1 000, 256). The cold start
                # is measured below.
                warm = root / f"results_{count}_warm.parquet"
                subprocess.run(["rm", "-rf", str(warm), str(warm) + ".parts"], check=True)
                _run_batch(directories[count, fmt][0], warm, "1", args.chunk)

    def measure(label: str, mode: str) -> None:
        for count, fmt in directories:
            directory, generated = directories[count, fmt]
            for cache_state in (("warm", "cold") if args.page_cache == "both" else (args.page_cache,)):
                runs = []
                for _ in range(args.repeats):
                    out = root / f"results_{count}.parquet"
                    subprocess.run(["rm", "-rf", str(out), str(out) + ".parts"], check=True)
                    _set_page_cache(directory, cache_state)
                    runs.append(_peak_rss_of(directory, out, mode, args.chunk))
                walls = [r["wall_s"] for r in runs]
                row = {"count": count, "format": fmt, "placement": label, "page_cache": cache_state,
                       "wall_s": statistics.median(walls), "best_s": min(walls), "walls_s": walls,
                       "motors_per_s": count / statistics.median(walls), "best_motors_per_s": count / min(walls),
                       "peak_rss_mib": max(r["peak_rss_mib"] for r in runs), "generate_s": generated}
                rows.append(row)
                print(f"{count:>6} motors, {fmt:>7}, {label:>15}, {cache_state} files: median {row['wall_s']:6.1f} s "
                      f"({row['motors_per_s']:7.1f} motors/s), best {row['best_s']:6.1f} s "
                      f"({row['best_motors_per_s']:7.1f} motors/s), peak RSS {row['peak_rss_mib']:5.0f} MiB",
                      flush=True)

    # The local placements first, with no cluster up: an idle LocalCluster (scheduler, nannies,
    # workers) takes ~12 % of a core here, which would be charged to the local runs.
    for placement, label in (("default", "default options"), ("1", "1 process"), ("2", "2 processes")):
        if placement in args.placements:
            measure(label, "" if placement == "default" else placement)
    if "dask" in args.placements:
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=40)
        try:
            measure("dask, 2 workers", cluster.scheduler_address)
        finally:
            cluster.close()

    # The persistent compilation cache: the same batch twice, starting from an empty cache.
    cache_rows = []
    directory = None if args.skip_cache_runs else _generate(root, 100)
    with tempfile.TemporaryDirectory(prefix="drivecal-jax-cache-") as cache:
        for label, env in () if args.skip_cache_runs else (("cache off", {"DRIVECAL_JAX_CACHE": "0"}),
                           ("first, empty cache", {"DRIVECAL_JAX_CACHE_DIR": cache}),
                           ("second, warm cache", {"DRIVECAL_JAX_CACHE_DIR": cache})):
            out = root / "results_cache.parquet"
            subprocess.run(["rm", "-rf", str(out), str(out) + ".parts"], check=True)
            r = _run_batch(directory, out, "1", args.chunk, env)
            cache_rows.append({"run": label, "wall_s": r["wall_s"]})
            print(f"100 motors, {label:>20}: {r['wall_s']:6.1f} s", flush=True)

    probe_after = _cpu_probe()
    _add_marginal(rows)
    print()
    print(f"CPU probe (sum(range(3e7)), best of 3): {probe_before:.2f} s before the runs, {probe_after:.2f} s after")
    print(f"{'motors':>8} {'format':>8} {'placement':>16} {'files':>6} {'median [s]':>11} {'motors/s':>10} {'best [s]':>9} "
          f"{'motors/s':>10} {'peak RSS [MiB]':>15} {'marginal motors/s':>22}")
    for r in rows:
        marginal = (f"{r['marginal_motors_per_s']:8.1f} (from {r['marginal_from']})"
                    if "marginal_from" in r else "")
        print(f"{r['count']:>8} {r['format']:>8} {r['placement']:>16} {r['page_cache']:>6} {r['wall_s']:>11.1f} "
              f"{r['motors_per_s']:>10.1f} {r['best_s']:>9.1f} {r['best_motors_per_s']:>10.1f} "
              f"{r['peak_rss_mib']:>15.0f} {marginal:>22}")
    print()
    for r in cache_rows:
        print(f"  100 motors, {r['run']:>20}: {r['wall_s']:.1f} s")
    payload = {
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "drivecal": drivecal.__version__,
                    "cpu_probe_s": {"before": probe_before, "after": probe_after}},
        "chunk": args.chunk,
        "runs": rows,
        "compile_cache": cache_rows,
        "repeats": args.repeats,
        "note": ("fresh `drivecal batch` process per run: times include start-up and file reading (not the dask "
                 "cluster's start: it is up for the dask runs only, all counts); counts up to "
                 f"{args.warm_up_max} ran once untimed first, "
                 "so the compiled fit came from the persistent cache (compile_cache: the same batch from an "
                 "empty cache); wall_s is the median of the repeats, best_s the fastest; marginal_motors_per_s: "
                 "(count - marginal_from) / (wall_s - that count's wall_s), run the same way; page_cache: the bench "
                 "files were read into the page cache before each run (warm) or dropped from it (cold)"),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=2) + "\n")
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
