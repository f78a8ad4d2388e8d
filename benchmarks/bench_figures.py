"""The demo's figures plus HTML report, before and after: ``write_demo_outputs`` on one saved demo result.

The demo (bench and fits of both designs) runs once, in a process of its own; its ``DemoResult`` and
result JSON are pickled. Then, for the baseline tree (a commit checked out as a detached worktree under
/tmp) and this one, interleaved (baseline, now, baseline, now, ...), fresh processes load them and time
``write_demo_outputs(result, DIR)``: the 7 PNG files, ``report.json`` and ``report.html`` with its 12
figures. The result JSON is the one built before (``DemoResult.to_dict`` returns it), so only the figures
and the HTML are timed. Each way is a fresh process per run:

  in process   no workers: the first call in the process (matplotlib's import included, as in
               ``benchmarks/demo_phases.py``'s "figures + HTML" phase), and the calls after it, also as
               CPU seconds of the process (its wall time were a core its own: the machine is shared);
  workers      a ``FigureRenderer`` started before and ready (one worker per core, as ``drivecal demo
               --out`` starts them while it fits), the caller drawing too; the first call, and the next;
  command      ``drivecal demo --out DIR`` itself, in one process, on a compilation cache filled by a run
               before: the whole command, its result JSON (the workers draw the 7 files meanwhile), and
               what the figures and the HTML add after it (what a person waits for them).

Where the time goes (one process per tree, after a warm-up pass, median of the runs): per figure the
artists, the layout (``tight_layout``), the PNG (draws and encoding) and its encoding alone; the HTML and
files without the figures (their PNGs replayed); matplotlib's import; a worker's start-up; the jobs pickled.

Prints tables, writes benchmarks/results/bench_figures.json. Seconds throughout; the machine is noisy,
read the ratios.

    .venv/bin/python benchmarks/bench_figures.py [--runs 5] [--calls 3] [--baseline-commit 76b0222]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import pickle
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results" / "bench_figures.json"
#: The commit this round of figure work started from.
BASELINE_COMMIT = "76b0222"
MODES = ("in process", "workers", "command")


# --- in the child processes (PYTHONPATH: the tree timed) --------------------------------------------


def _load(path: str):
    """The saved demo result, its ``to_dict`` answering the saved result JSON (built once, not timed)."""
    from drivecal.demo import _demo

    with open(path, "rb") as f:
        result, doc = pickle.load(f)
    _demo.DemoResult.to_dict = lambda self: doc
    return result, doc


class _Replay:
    """A renderer that records the demo's figure jobs and draws each here, or hands back PNGs drawn before."""

    class _Done:
        def __init__(self, png: bytes):
            self.png = png

        def result(self) -> bytes:
            return self.png

    def __init__(self, draw=None, pngs=None):
        self.draw, self.pngs, self.jobs = draw, list(pngs or ()), []

    def submit(self, name, kwargs, dpi):
        self.jobs.append((name, kwargs, dpi))
        if self.draw:
            return self._Done(self.draw(name, kwargs, dpi))
        return self._Done(self.pngs[(len(self.jobs) - 1) % len(self.pngs)])  # each call submits the same jobs in turn

    def render_all(self, jobs):
        return [self.submit(*job).result() for job in jobs]


def _timed_calls(result, calls: int, renderer=None, cpu: list | None = None) -> list[float]:
    """Wall seconds of ``calls`` calls of ``write_demo_outputs``; this process's CPU seconds of each go to ``cpu``."""
    from drivecal.demo import write_demo_outputs

    out = []
    for _ in range(calls):
        if hasattr(renderer, "forget"):  # a renderer that keeps what it drew (2026-12): each call draws afresh
            renderer.forget()
        with tempfile.TemporaryDirectory(prefix="drivecal-figs-") as tmp:
            t0, c0 = time.perf_counter(), time.process_time()
            write_demo_outputs(result, tmp, renderer)
            out.append(time.perf_counter() - t0)
            if cpu is not None:
                cpu.append(time.process_time() - c0)
    return out


def child_run(path: str, mode: str, calls: int) -> dict:
    """``calls`` timed calls of ``write_demo_outputs`` in this process, ``mode`` of :data:`MODES`."""
    result, _ = _load(path)
    if mode == "in process":
        cpu: list[float] = []
        return {"mode": mode, "matplotlib_loaded_before": "matplotlib" in sys.modules,
                "calls_s": _timed_calls(result, calls, cpu=cpu), "cpu_s": cpu}
    from drivecal._figures import FigureRenderer  # loaded at the command's start, as `drivecal demo --out` does

    with FigureRenderer() as renderer:
        for job in [renderer.submit("correlation", {"names": ("R",), "corr": [[1.0]]}, 20)
                    for _ in range(renderer.processes)]:
            job.result()
        time.sleep(1.0)  # every worker up (the fit takes longer than this)
        return {"mode": mode, "processes": renderer.processes, "calls_s": _timed_calls(result, calls, renderer)}


def child_command() -> dict:
    """``drivecal demo --out DIR`` in this process: the whole command, its result JSON, and what comes after it."""
    t0 = time.perf_counter()
    from drivecal import demo
    from drivecal.cli import main

    marks = {}
    to_dict, write = demo._demo.DemoResult.to_dict, demo.write_demo_outputs

    def timed_to_dict(self):
        start = time.perf_counter()
        doc = to_dict(self)
        marks["json_end"] = time.perf_counter()
        marks["result_json_s"] = marks["json_end"] - start
        return doc

    def timed_write(*args, **kwargs):
        out = write(*args, **kwargs)
        marks["after_result_json_s"] = time.perf_counter() - marks["json_end"]
        return out

    demo._demo.DemoResult.to_dict, demo.write_demo_outputs = timed_to_dict, timed_write
    with tempfile.TemporaryDirectory(prefix="drivecal-figs-") as tmp, contextlib.redirect_stdout(io.StringIO()):
        main(["demo", "--out", str(Path(tmp) / "out")])
    return {"command_s": time.perf_counter() - t0, **{k: v for k, v in marks.items() if k.endswith("_s")}}


def child_phases(path: str, runs: int) -> dict:
    """Where the time goes in this tree, in one process: see the module's docstring."""
    import numpy  # noqa: F401  (loaded before matplotlib in a drivecal process)

    t0 = time.perf_counter()
    import matplotlib.pyplot  # noqa: F401

    mpl_import = time.perf_counter() - t0
    import PIL.Image
    from matplotlib.figure import Figure

    from drivecal import _figures
    from drivecal.demo import write_demo_outputs

    result, _ = _load(path)
    clock = {"artists": 0.0, "layout": 0.0, "encode": 0.0}

    def timer(fn, key):
        def wrapped(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                clock[key] += time.perf_counter() - start
        return wrapped

    recorder = _Replay(draw=_figures.render)
    with tempfile.TemporaryDirectory() as tmp:
        write_demo_outputs(result, tmp, recorder)  # the jobs, and a warm-up pass
    Figure.tight_layout = timer(Figure.tight_layout, "layout")
    PIL.Image.Image.save = timer(PIL.Image.Image.save, "encode")
    for name in list(_figures.FIGURES):
        _figures.FIGURES[name] = timer(_figures.FIGURES[name], "artists")
    figures: dict[str, list[dict]] = {}
    # The figures the tree draws: a job asked for twice (a page's figure that is also a file) once where the tree's
    # renderer draws it once (``_figures.job_key``).
    key = getattr(_figures, "job_key", None)
    drawn = list({(key(*job) if key else None) or k: job for k, job in enumerate(recorder.jobs)}.values())
    seen: dict[tuple, int] = {}
    for name, kwargs, dpi in drawn:
        seen[name, dpi] = seen.get((name, dpi), 0) + 1
        for _ in range(runs):
            clock.update(artists=0.0, layout=0.0, encode=0.0)
            start = time.perf_counter()
            png = _figures.render(name, kwargs, dpi)
            total = time.perf_counter() - start
            figures.setdefault(f"{name} @{dpi} #{seen[name, dpi]}", []).append({
                "artists": clock["artists"] - clock["layout"], "layout": clock["layout"],
                "png": total - clock["artists"], "encode": clock["encode"], "total": total, "bytes": len(png)})
    pngs = [_figures.render(*job) for job in recorder.jobs]
    rest = _timed_calls(result, runs, _Replay(pngs=pngs))  # the JSON, HTML and files without drawing a figure
    start = time.perf_counter()
    with _figures.FigureRenderer(1) as renderer:
        renderer.submit("correlation", {"names": ("R",), "corr": [[1.0]]}, 20).result()
    worker_start = time.perf_counter() - start
    start = time.perf_counter()
    payload = [pickle.dumps(job) for job in recorder.jobs]
    return {"figures": {k: {f: statistics.median(r[f] for r in rs) for f in rs[0]} for k, rs in figures.items()},
            "html_and_files_without_figures_s": statistics.median(rest), "matplotlib_import_s": mpl_import,
            "worker_start_s": worker_start, "jobs_pickled_s": time.perf_counter() - start,
            "jobs_pickled_bytes": sum(map(len, payload)), "png_bytes": sum(map(len, pngs))}


# --- the parent -------------------------------------------------------------------------------------


def _child(src: Path, *args: str) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "PYTHONWARNINGS": "ignore"}
    proc = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"PYTHONPATH={src} {' '.join(args)}: exit {proc.returncode}\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _save_demo(path: Path) -> None:
    """Run the demo once (this tree) and pickle its result with its result JSON."""
    code = ("import json, pickle, sys; from drivecal.demo import run_demo; r = run_demo(); "
            "d = json.loads(json.dumps(r.to_dict(), allow_nan=False)); pickle.dump((r, d), open(sys.argv[1], 'wb'))")
    subprocess.run([sys.executable, "-c", code, str(path)], check=True, capture_output=True,
                   env={**os.environ, "PYTHONPATH": str(ROOT / "src")})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="fresh processes per tree and way (interleaved)")
    parser.add_argument("--calls", type=int, default=3, help="calls per process (the first reported apart)")
    parser.add_argument("--baseline-commit", default=BASELINE_COMMIT)
    parser.add_argument("--result", type=Path, default=None,
                        help="a pickled (DemoResult, result JSON) to reuse (default: run the demo once, save it here)")
    parser.add_argument("--child", nargs="+", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        kind, *rest = args.child
        out = (child_command() if kind == "command" else child_run(rest[0], kind, int(rest[1])) if kind in MODES
               else child_phases(rest[0], int(rest[1])))
        print(json.dumps(out))
        return

    sys.path.insert(0, str(Path(__file__).parent))
    from bench_startup import check_origin, ensure_baseline
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    base_dir = Path(f"/tmp/drivecal-figs-{args.baseline_commit}")
    ensure_baseline(base_dir, args.baseline_commit)
    trees = {"baseline": base_dir / "src", "now": ROOT / "src"}
    for src in trees.values():
        check_origin(src)
    console = Console(width=150)
    pkl = args.result or Path(tempfile.gettempdir()) / "drivecal-bench-figures-demo.pkl"
    if not pkl.exists():
        with console.status("running the demo once..."):
            _save_demo(pkl)
    #: (way, what): samples per tree
    labels = {("in process", "first"): "in process, first call (matplotlib import included)",
              ("in process", "next"): "in process, next calls",
              ("in process", "cpu"): "in process, next calls: CPU seconds (the wall time on an idle core)",
              ("workers", "first"): "workers ready, first call", ("workers", "next"): "workers ready, next calls",
              ("command", "after_result_json_s"): "`drivecal demo --out`: after the result JSON (figures + HTML)",
              ("command", "result_json_s"): "`drivecal demo --out`: the result JSON (the 7 files drawn meanwhile)",
              ("command", "command_s"): "`drivecal demo --out`: whole command (in one process, warm cache)"}
    samples = {(tree, key): [] for tree in trees for key in labels}
    with tempfile.TemporaryDirectory(prefix="drivecal-figs-cache-") as cache, console.status("timing...") as status:
        os.environ["DRIVECAL_JAX_CACHE_DIR"] = cache  # the children's compilation cache: filled by a run first
        for tree, src in trees.items():
            status.update(f"filling the compilation cache: {tree}")
            _child(src, "command")
        for run in range(args.runs):
            for mode in MODES:
                for tree, src in trees.items():
                    status.update(f"run {run + 1}/{args.runs}: {mode}, {tree}")
                    if mode == "command":
                        for key, value in _child(src, mode).items():
                            samples[tree, (mode, key)].append(value)
                        continue
                    out = _child(src, mode, str(pkl), str(args.calls))
                    samples[tree, (mode, "first")].append(out["calls_s"][0])
                    samples[tree, (mode, "next")].append(statistics.median(out["calls_s"][1:]))
                    if "cpu_s" in out:
                        samples[tree, (mode, "cpu")].append(statistics.median(out["cpu_s"][1:]))
        phases = {}
        for tree, src in trees.items():
            status.update(f"where the time goes: {tree}")
            phases[tree] = _child(src, "phases", str(pkl), str(args.runs))

    rows = [(labels[key], statistics.median(samples["baseline", key]), statistics.median(samples["now", key]))
            for key in labels]
    table = Table(title=f"The demo's figures + HTML (write_demo_outputs, result JSON built before; and the command), "
                        f"median of {args.runs} runs, {os.cpu_count()} cores", title_justify="left")
    for col in ("way", escape(f"baseline {args.baseline_commit} [s]"), "now [s]", "baseline / now"):
        table.add_column(col, justify="left" if col == "way" else "right")
    for way, base, now in rows:
        table.add_row(escape(way), f"{base:.2f}", f"{now:.2f}", f"{base / now:.2f}x")
    console.print(table)
    fig = Table(title="Where the time goes, per figure (one process, after a warm-up) [ms]: baseline / now",
                title_justify="left")
    parts = ("artists", "layout", "png", "encode", "total")
    for col in ("figure",) + parts + ("kB",):
        fig.add_column(col, justify="left" if col == "figure" else "right")
    base, now = phases["baseline"]["figures"], phases["now"]["figures"]

    def cell(figures: dict, key: str, part: str, scale: float) -> str:
        return f"{scale * figures[key][part]:.0f}" if key in figures else "-"  # "-": not drawn by that tree

    for key in sorted(set(base) | set(now)):
        fig.add_row(key, *(f"{cell(base, key, p, 1e3)} / {cell(now, key, p, 1e3)}" for p in parts),
                    f"{cell(base, key, 'bytes', 1e-3)} / {cell(now, key, 'bytes', 1e-3)}")
    fig.add_row("sum", *(f"{1e3 * sum(v[p] for v in base.values()):.0f} / {1e3 * sum(v[p] for v in now.values()):.0f}"
                         for p in parts),
                f"{phases['baseline']['png_bytes'] / 1e3:.0f} / {phases['now']['png_bytes'] / 1e3:.0f}")
    console.print(fig)
    for key in ("html_and_files_without_figures_s", "matplotlib_import_s", "worker_start_s", "jobs_pickled_s"):
        console.print(f"{key}: baseline {phases['baseline'][key]:.3f}, now {phases['now'][key]:.3f}")
    console.print(f"jobs pickled for the workers: {phases['now']['jobs_pickled_bytes'] / 1e3:.0f} kB")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(json.dumps({
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "load_average": os.getloadavg()},
        "baseline_commit": args.baseline_commit, "runs": args.runs, "calls": args.calls,
        "rows": [{"way": w, "baseline_median_s": b, "now_median_s": n, "baseline_over_now": b / n} for w, b, n in rows],
        "samples_s": {f"{tree} | {labels[key]}": v for (tree, key), v in samples.items()}, "phases": phases},
        indent=2) + "\n")
    console.print(f"wrote {RESULTS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
