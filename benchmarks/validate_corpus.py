"""Auto-plan across the real-motor corpus: plan -> Jaxonomy engine -> fit -> within 4 SE?

For every motor of ../shared/data/motors.csv (566 real PMSMs; see
shared/data/README.md): a datasheet 10 % off the truth, an auto-plan on it
(bench limits: the motor's V_dc, 1.5 x rated current, rated speed), the plan
run on the Jaxonomy engine with the true motor plus sensor noise of 0.2 % of
the current limit, a fit from the datasheet, and each of R, Ld, Lq, lambda_m
compared with the truth in standard errors (tests/helpers/corpus.py has the details).

Prints how many motors and estimates pass and the worst cases, and writes
benchmarks/results/validate_corpus.json.

    .venv/bin/python benchmarks/validate_corpus.py [--limit N] [--motors m000,m001] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

import drivecal as dc
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import corpus  # noqa: E402

CORPUS = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "motors.csv"
RESULTS = Path(__file__).parent / "results" / "validate_corpus.json"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--corpus", type=Path, default=CORPUS, help="corpus CSV (default ../shared/data/motors.csv)")
    parser.add_argument("--limit", type=int, default=None, help="only the first N motors")
    parser.add_argument("--motors", default=None, help="comma-separated motor ids, e.g. m000,m001")
    parser.add_argument("--seed", type=int, default=0, help="seed of datasheet errors and noise")
    parser.add_argument("--out", type=Path, default=RESULTS, help="JSON results file")
    args = parser.parse_args(argv)

    console = Console(width=120)
    if not args.corpus.is_file():
        console.print(f"corpus not found: {args.corpus}")
        return 2
    motors = corpus.load_corpus(args.corpus)
    if args.motors:
        wanted = [m.strip() for m in args.motors.split(",") if m.strip()]
        unknown = sorted(set(wanted) - {m.name for m in motors})
        if unknown:
            console.print(f"unknown motor id(s): {', '.join(unknown)}")
            return 2
        motors = [m for m in motors if m.name in wanted]
    if args.limit is not None:
        motors = motors[: args.limit]

    started = time.perf_counter()
    with console.status("") as status:
        def progress(result):
            done = progress.count = getattr(progress, "count", 0) + 1
            status.update(f"{done}/{len(motors)} motors, {time.perf_counter() - started:.0f} s")

        results = corpus.validate(motors, seed=args.seed, progress=progress)
    wall = time.perf_counter() - started

    summary = _summary(results, wall)
    _print(results, summary, console)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    doc = {
        "corpus": str(args.corpus),
        "seed": args.seed,
        "settings": {"current_limit": f"{corpus.CURRENT_LIMIT_FACTOR} x i_rated",
                     "noise_sigma": f"{dc.autoplan.NOISE_FRACTION} x current limit",
                     "prior": f"truth x U(1 - {corpus.PRIOR_SPREAD}, 1 + {corpus.PRIOR_SPREAD}) per parameter",
                     "pass": f"|estimate - truth| <= {corpus.PASS_SE} SE", "max_speed": "w_rated"},
        "summary": summary,
        "machine": {"platform": platform.platform(), "python": sys.version.split()[0], "cpus": os.cpu_count()},
        "motors": [r.to_dict() for r in results],
    }
    tmp = args.out.with_suffix(".json.part")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(args.out)
    console.print(f"wrote {args.out}")
    return 0 if summary["motors_passed"] == summary["motors"] else 1


def _summary(results, wall: float) -> dict:
    planned = [r for r in results if r.error is None]
    passes = np.array([r.passes for r in planned]) if planned else np.zeros((0, 4), bool)
    z = np.array([r.z for r in planned]) if planned else np.zeros((0, 4))
    seconds = {k: float(sum(r.seconds.get(k, 0.0) for r in planned)) for k in ("plan", "engine", "fit")}
    names = list(dc.ESTIMATED)
    return {
        "motors": len(results),
        "planned": len(planned),
        "no_plan": [{"motor": r.name, "error": r.error} for r in results if r.error is not None],
        "converged": int(sum(r.converged for r in planned)),
        "motors_passed": int(sum(r.passed for r in results)),
        "estimates": int(passes.size),
        "estimates_passed": int(passes.sum()),
        "per_parameter_passed": {n: int(passes[:, i].sum()) for i, n in enumerate(names)},
        "within_1.96_se": float(np.mean(np.abs(z) <= 1.96)) if z.size else None,
        "rms_z": {n: float(np.sqrt(np.mean(z[:, i] ** 2))) for i, n in enumerate(names)} if z.size else None,
        "max_abs_z": float(np.nanmax(np.abs(z))) if z.size else None,
        "sample_rate_hz": [float(min(r.sample_rate for r in planned)), float(max(r.sample_rate for r in planned))]
        if planned else None,
        "num_samples": sorted({r.num_samples for r in planned}),
        "seconds": {"wall": wall, **seconds},
    }


def _print(results, summary: dict, console: Console) -> None:
    s = summary
    console.print(f"[bold]auto-plan across {s['motors']} corpus motors[/bold]: {s['planned']} planned, "
                  f"{s['converged']} converged, {s['motors_passed']} motors pass (all four estimates within "
                  f"{corpus.PASS_SE:g} SE); estimates within {corpus.PASS_SE:g} SE: {s['estimates_passed']}/"
                  f"{s['estimates']}")
    if s["rms_z"]:
        console.print("per parameter: " + ", ".join(f"{n} {s['per_parameter_passed'][n]} pass, RMS z "
                                                    f"{s['rms_z'][n]:.3f}" for n in dc.ESTIMATED)
                      + f"; within 1.96 SE: {100 * s['within_1.96_se']:.2f} % (nominal 95 %)")
    t = s["seconds"]
    console.print(f"time: {t['wall']:.1f} s wall; plan {t['plan']:.1f} s, engine {t['engine']:.1f} s, fit "
                  f"{t['fit']:.1f} s (compiles included); plan sizes {s['num_samples']} samples")
    planned = [r for r in results if r.error is None]
    worst = sorted(planned, key=lambda r: -float(np.nanmax(np.abs(r.z))))[:10]
    table = Table(title="worst cases (largest |error| in SE)", title_justify="left")
    for col in ("motor", "pass", "fs [Hz]", "samples", "cond", *(f"z {n}" for n in dc.ESTIMATED)):
        table.add_column(col, justify="left" if col in ("motor", "pass") else "right", no_wrap=True)
    for r in worst:
        table.add_row(r.name, "yes" if r.passed else "[red]NO[/red]", f"{r.sample_rate:g}", str(r.num_samples),
                      f"{r.condition_number:.3g}", *(f"{z:+.2f}" for z in r.z))
    console.print(table)
    for item in s["no_plan"]:
        console.print(f"  [red]{item['motor']}[/red]: {item['error']}")


if __name__ == "__main__":
    sys.exit(main())
