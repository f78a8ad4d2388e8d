"""Where the demo's time goes: `drivecal demo --out DIR` taken apart in one process, phase by phase.

Run with PYTHONPATH pointing at the drivecal tree to measure (``bench_workflow.py`` runs it for
the baseline tree and this one, each on an empty compilation cache). Prints one JSON object:

  phases_s    import (drivecal, JAX, jaxonomy), engine bench (both designs; where the demo compiles its
              fits' and result documents' kernels beside the engine, that too), fit (both designs:
              identifiability, solve), result JSON (diagnostics), figures + HTML (what the command waits for once the
              result JSON is built: the page's figures and the PNG files' rest; as the command does,
              the figure workers start at the beginning and the files are queued to them before the
              result JSON is built), wall (the sum);
  figures_here_s  the same figures and page drawn again in this process alone, no workers (their CPU
              work; not in the wall);
  compile_s   compile and trace seconds by kernel: the drivecal function that asked for it (the
              innermost drivecal frame of the stack) and JAX's event (backend compile, trace,
              lowering to MLIR);
  compiles    the number of XLA compilations (backend), and cache hits.

    PYTHONPATH=src DRIVECAL_JAX_CACHE_DIR=$(mktemp -d) .venv/bin/python benchmarks/demo_phases.py
"""

from __future__ import annotations

import collections
import json
import shutil
import sys
import tempfile
import time
import traceback

T0 = time.perf_counter()

import jax.monitoring as monitoring  # noqa: E402

COMPILE: dict[str, float] = collections.defaultdict(float)
EVENTS: collections.Counter = collections.Counter()
WHAT = {"backend_compile_duration": "compile", "jaxpr_trace_duration": "trace",
        "jaxpr_to_mlir_module_duration": "lower"}


def _asker() -> str:
    """The two innermost drivecal frames (the trace cache's plumbing and the Jacobian's ``_compiled`` left out): who
    asked for the kernel, for what."""
    frames = [f for f in traceback.extract_stack()
              if "/drivecal/" in f.filename.replace("\\", "/") and "_lowered_cache" not in f.filename
              and not (f.name == "_compiled" and f.filename.endswith("_jacobian.py"))]
    if not frames:
        return "(outside drivecal)"
    return " > ".join(f"{f.filename.replace(chr(92), '/').split('/drivecal/')[-1][:-3]}.{f.name}" for f in frames[-2:])


def _on_duration(event: str, seconds: float, **_) -> None:
    kind = WHAT.get(event.rsplit("/", 1)[-1])
    if kind is not None:
        COMPILE[f"{kind} {_asker()}"] += seconds
        if kind == "compile":
            EVENTS["compiles"] += 1


monitoring.register_event_duration_secs_listener(_on_duration)
monitoring.register_event_listener(lambda event, **_: EVENTS.update([event.rsplit("/", 1)[-1]]))


def main() -> None:
    import gc
    import inspect

    import drivecal.cli._common as program

    # The garbage collector as the tree's `drivecal` program sets it (older trees left Python's default).
    if hasattr(program, "YOUNG_GENERATION"):
        gc.set_threshold(program.YOUNG_GENERATION, *gc.get_threshold()[1:])
    phases = {}
    t = time.perf_counter()

    def mark(name: str) -> None:
        nonlocal t
        now = time.perf_counter()
        phases[name] = phases.get(name, 0.0) + now - t
        t = now

    import drivecal.bench  # noqa: F401
    from drivecal.demo import _demo as demo

    import jaxonomy  # noqa: F401  (the engine's import, paid by every demo)
    from drivecal._figures import FigureRenderer

    # `drivecal demo --out` starts its figure workers first: they load matplotlib while it computes.
    renderer = FigureRenderer().start()
    phases["import"] = time.perf_counter() - T0
    t = time.perf_counter()
    # The demo itself (``run_demo``), its stages marked by its progress messages: the engine's runs (and, where
    # the demo compiles ahead, what the fits and result documents compile beside them), then the two fits.
    stages = iter(["engine bench", "fit"])
    entered = []

    def progress(message: str) -> None:
        if entered:
            mark(entered[-1])
        entered.append(next(stages))

    result = demo.run_demo(noise=0.02, seed=1, progress=progress)
    mark(entered[-1])
    # As `drivecal demo --out` writes its outputs: the figure files queued, the result JSON built (timed apart:
    # the files are drawn meanwhile), then the page and the files' wait.
    build, built = demo.DemoResult.to_dict, []

    def to_dict(self):
        if not built:
            start = time.perf_counter()
            built.append(build(self))
            phases["result JSON"] = time.perf_counter() - start
        return built[0]

    demo.DemoResult.to_dict = to_dict
    out = tempfile.mkdtemp(prefix="drivecal-phases-")
    import drivecal.cli._demo as command

    if "gc.freeze()" in inspect.getsource(command):  # as the tree's `drivecal demo --out` does before it writes
        gc.freeze()
    try:
        demo.write_demo_outputs(result, out, renderer)
        renderer.close()
        mark("figures + HTML")
        phases["figures + HTML"] -= phases["result JSON"]
        phases["wall"] = time.perf_counter() - T0
        here = time.perf_counter()
        demo.write_demo_outputs(result, out, FigureRenderer(0))
        here = time.perf_counter() - here
    finally:
        shutil.rmtree(out, ignore_errors=True)
    print(json.dumps({"phases_s": phases, "figures_here_s": here,
                      "compile_s": dict(sorted(COMPILE.items(), key=lambda kv: -kv[1])),
                      "compiles": EVENTS["compiles"], "cache_hits": EVENTS["cache_hits"]}))


if __name__ == "__main__":
    sys.exit(main())
