"""Core benchmark: drivecal's compiled fit against a seed-style baseline, in one run.

Times, on this machine and in this process (ratios are what to read; the
machines here are noisy):

  (a) seed-style baseline: the tutorial's workflow — per-segment rollout, a
      Python-loop Gauss-Newton that builds and compiles a fresh jacfwd every
      iteration, numpy normal equations;
  (b) drivecal's fit: one jit-compiled optimistix LM solve, warm (single), and
      one jit(vmap) call over 1000 datasets (motors/s);
  (c) the whole demo: `drivecal demo` in a fresh process, against the seed
      workflow (engine bench + baseline fit + identifiability, both designs):
      first on an empty persistent compilation cache, then again with the
      cache that first run left (what every later run on a machine finds);
      the seed workflow both in this process and as a fresh process of its
      own (the speed-up column of the demo rows compares with the latter).

Prints a table and writes benchmarks/results/bench_core.json.

    .venv/bin/python benchmarks/bench_core.py [--batch 1000] [--repeats 20]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import drivecal as dc  # first: it quiets XLA's C++ log lines before JAX loads
from drivecal.model import rk4_step  # noqa: E402

import jax
import jax.numpy as jnp
import numpy as np

RESULTS = Path(__file__).parent / "results" / "bench_core.json"
NAMES = dc.ESTIMATED


# --- (a) the seed-style baseline ---------------------------------------------------


def _seed_forward(theta, plan: dc.Plan, fixed: dc.MotorParams):
    """Per-segment RK4 rollouts stacked like the tutorial (one scan per segment)."""
    motor = fixed.with_vector(NAMES, theta)
    dt = plan.sample_period
    out = []
    for seg in plan.segments:
        v = jnp.asarray(seg.voltages(plan.sample_rate))

        def step(x, vk, locked=seg.locked):
            return rk4_step(x, vk, motor, locked, dt), jnp.stack(x[:2])

        _, i = jax.lax.scan(step, (0.0, 0.0, 0.0, 0.0), v)
        out.append(i[:, 0])
        out.append(i[:, 1])
    return jnp.concatenate(out)


def seed_gauss_newton(theta0, y, plan, fixed, iterations=15):
    """Python-loop Gauss-Newton; each iteration builds and jit-compiles a new jacfwd."""
    theta = np.asarray(theta0, dtype=float)
    for _ in range(iterations):
        jac_fn = jax.jit(jax.jacfwd(lambda th: _seed_forward(th, plan, fixed)))  # re-jit per call
        f_fn = jax.jit(lambda th: _seed_forward(th, plan, fixed))
        jac = np.asarray(jac_fn(jnp.asarray(theta)))
        r = np.asarray(f_fn(jnp.asarray(theta))) - y
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]  # minimum-norm step: dead columns stay put
        theta = theta + step
        if np.max(np.abs(step / theta)) < 1e-9:
            break
    return theta


def seed_bench(plan: dc.Plan, motor: dc.MotorParams, seed: int, sigma: float = 0.02):
    """The tutorial's bench: engine at DT/4 major steps, then interpolation onto the grid."""
    from jaxonomy import DiagramBuilder, SimulatorOptions, simulate
    from jaxonomy.library import Constant
    from jaxonomy.library.drives import PMSM

    rng = np.random.default_rng(seed)
    clean = []
    for seg in plan.segments:
        b = DiagramBuilder()
        src = b.add(Constant(jnp.asarray([float(seg.v_d), float(seg.v_q)]), name="v"))
        m = b.add(PMSM(**{k: float(getattr(motor, k)) for k in ("R", "Ld", "Lq", "lambda_m", "pole_pairs", "J", "B")},
                       locked=seg.locked, name="pmsm"))
        b.connect(src.output_ports[0], m.input_ports[0])
        diagram = b.build()
        res = simulate(diagram, diagram.create_context(), (0.0, seg.duration),
                       options=SimulatorOptions(max_major_step_length=plan.sample_period / 4.0),
                       recorded_signals={"x": m.output_ports[0]})
        t, x = np.asarray(res.time), np.asarray(res.outputs["x"])
        grid = np.arange(seg.num_samples(plan.sample_rate)) * plan.sample_period
        clean += [np.interp(grid, t, x[:, 0]), np.interp(grid, t, x[:, 1])]
    y = np.concatenate(clean)
    return y + rng.normal(0.0, sigma, size=y.shape)


def seed_workflow(truth, guess):
    """Bench, identifiability and Gauss-Newton for both designs, the tutorial's way."""
    with contextlib.redirect_stdout(io.StringIO()):  # MuJoCo prints on import
        from jaxterity.sysid.recipes import identifiability_from_jacobian
    for plan, seed in ((dc.default_plan(), 1), (dc.locked_q_step_plan(), 3)):
        y = seed_bench(plan, truth, seed)
        jac = np.asarray(jax.jacfwd(lambda th: _seed_forward(th, plan, truth))(truth.vector(NAMES)))
        identifiability_from_jacobian(jac, names=NAMES)
        seed_gauss_newton(np.asarray(guess.vector(NAMES)), y, plan, truth)


# --- (b) drivecal ---------------------------------------------------------------


def _median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=1000, help="datasets in the batched fit")
    parser.add_argument("--repeats", type=int, default=20, help="repeats of the single warm fit")
    parser.add_argument("--skip-demo", action="store_true", help="skip the fresh-process demo timing")
    parser.add_argument("--seed-workflow-only", action="store_true",
                        help="run only the seed workflow (timed by the main run in a fresh process)")
    args = parser.parse_args()

    truth = dc.DEFAULT_MOTOR
    guess = dc.datasheet_guess(truth)
    if args.seed_workflow_only:
        seed_workflow(truth, guess)
        return
    clean = dc.engine_bench(dc.default_plan(), truth)
    bench = clean.add_noise(0.02, 1)
    experiment = bench.experiment()
    y_seed = np.concatenate([np.concatenate([s.currents[:, 0], s.currents[:, 1]]) for s in bench.segments])
    rows = []

    # (a) baseline fit on the same data
    t0 = time.perf_counter()
    theta_seed = seed_gauss_newton(np.asarray(guess.vector(NAMES)), y_seed, dc.default_plan(), truth)
    t_seed_fit = time.perf_counter() - t0
    rows.append(("seed-style fit (Python GN, re-jit per iteration)", t_seed_fit * 1e3, "ms", 1.0))

    # (b) drivecal single: identifiability computed once, the fit itself timed warm
    ident = dc.assess_identifiability(experiment, guess)
    t0 = time.perf_counter()
    cal = dc.fit_currents(experiment, bench.currents, guess, identifiability=ident)
    t_first = time.perf_counter() - t0
    t_warm, _ = _median_time(lambda: dc.fit_currents(experiment, bench.currents, guess, identifiability=ident),
                             args.repeats)
    assert np.allclose(cal.estimate, theta_seed, rtol=1e-6), (cal.estimate, theta_seed)
    rows.append(("drivecal fit, first call (compile + solve)", t_first * 1e3, "ms", t_seed_fit / t_first))
    rows.append(("drivecal fit, warm (median)", t_warm * 1e3, "ms", t_seed_fit / t_warm))
    # the same fit started at the datasheet guess instead of the equation-error start from the data
    at_guess = dc.FitOptions(start="prior")
    cal_guess = dc.fit_currents(experiment, bench.currents, guess, identifiability=ident, options=at_guess)
    t_warm_guess, _ = _median_time(
        lambda: dc.fit_currents(experiment, bench.currents, guess, identifiability=ident, options=at_guess),
        args.repeats)
    rows.append((f"  same, started at the guess ({int(cal_guess.iterations)} LM steps, not "
                 f"{int(cal.iterations)})", t_warm_guess * 1e3, "ms", t_seed_fit / t_warm_guess))

    # (b) batched: noise realisations from the datasheet guess, and a fleet-like case
    rng = np.random.default_rng(0)
    currents = clean.currents[None] + rng.normal(0.0, 0.02, size=(args.batch,) + clean.currents.shape)
    batch_fit = lambda: dc.fit_currents(experiment, currents, guess, identifiability=ident)  # noqa: E731
    guess_batch = batch_fit()
    t_batch, _ = _median_time(batch_fit, 2)
    rate_guess = args.batch / t_batch
    rows.append((f"drivecal batched fit, {args.batch} datasets, start 30-50 % off", rate_guess, "motors/s",
                 rate_guess * t_seed_fit))
    # the same batch in one vmapped pass (no straggler re-solve), for the same-process ratio
    one_pass = dc.FitOptions(first_pass_steps=None)
    one_fit = lambda: dc.fit_currents(experiment, currents, guess, identifiability=ident, options=one_pass)  # noqa: E731
    one_batch = one_fit()
    t_one, _ = _median_time(one_fit, 2)
    rows.append((f"  same, one vmapped pass (first_pass_steps=None)", args.batch / t_one, "motors/s",
                 args.batch / t_one * t_seed_fit))
    shift = float(np.max(np.abs(guess_batch.estimate - one_batch.estimate) / one_batch.se))

    # fleet: units scattered +-5 % around the nominal motor, fitted from the nominal
    scatter = rng.uniform(0.95, 1.05, size=(args.batch, 4))
    nominal = np.asarray(truth.vector(NAMES))

    def fleet_rate(fleet_experiment, fleet_ident):
        """motors/s of a batched fit of the scattered units on this experiment, and the batch."""
        sim = jax.jit(jax.vmap(lambda th: dc.predict_currents(truth.with_vector(NAMES, th), fleet_experiment)))
        fleet_currents = np.asarray(sim(jnp.asarray(nominal * scatter))) + rng.normal(0.0, 0.02, currents.shape)
        fleet_fit = lambda: dc.fit_currents(fleet_experiment, fleet_currents, truth,  # noqa: E731
                                            identifiability=fleet_ident)
        batch = fleet_fit()
        assert np.all(batch.converged)
        return args.batch / _median_time(fleet_fit, 2)[0], batch

    rate_fleet, fleet_batch = fleet_rate(experiment, ident)
    rows.append((f"drivecal batched fit, {args.batch} units +-5 % around nominal", rate_fleet, "motors/s",
                 rate_fleet * t_seed_fit))
    # fleet benches record the speed: the spin-up is then linear in the currents (J and B drop out)
    spin_experiment = dc.engine_bench(dc.default_plan(), truth, record_speed=True).experiment()
    rate_spin, _ = fleet_rate(spin_experiment, dc.assess_identifiability(spin_experiment, truth))
    rows.append(("  same, speed measured", rate_spin, "motors/s", rate_spin * t_seed_fit))

    # (c) whole workflow
    t0 = time.perf_counter()
    seed_workflow(truth, guess)
    t_seed_wf = time.perf_counter() - t0
    rows.append(("seed workflow (engine bench + GN + identifiability, both designs)", t_seed_wf, "s", 1.0))
    t_seed_wf_fresh = None
    if not args.skip_demo:
        # The same workflow as a script of its own, imports included: the like-for-like
        # comparison with `drivecal demo` in a fresh process.
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--seed-workflow-only"], check=True, capture_output=True)
        t_seed_wf_fresh = time.perf_counter() - t0
        rows.append(("  same, fresh process (imports included)", t_seed_wf_fresh, "s", 1.0))
    t_demo = t_demo_cold = None
    if not args.skip_demo:
        # Twice in fresh processes on an empty persistent cache: the first compiles everything (a
        # machine's first run), the second finds its compiled kernels on disk (every run after it).
        exe = Path(sys.executable).with_name("drivecal")
        with tempfile.TemporaryDirectory(prefix="drivecal-bench-cache-") as cache:
            times = []
            for _ in range(2):
                t0 = time.perf_counter()
                subprocess.run([str(exe), "demo", "--json"], check=True, capture_output=True,
                               env={**os.environ, "DRIVECAL_JAX_CACHE_DIR": cache})
                times.append(time.perf_counter() - t0)
        t_demo_cold, t_demo = times
        rows.append(("`drivecal demo --json`, fresh process, empty compile cache", t_demo_cold, "s",
                     t_seed_wf_fresh / t_demo_cold))
        rows.append(("`drivecal demo --json`, fresh process, cache from the run before", t_demo, "s",
                     t_seed_wf_fresh / t_demo))

    width = max(len(r[0]) for r in rows)
    print(f"\n{'case':<{width}}  {'value':>10}  {'unit':<9}  speed-up vs baseline")
    for name, value, unit, ratio in rows:
        print(f"{name:<{width}}  {value:>10.1f}  {unit:<9}  {ratio:>8.1f}x")
    print(f"\nwarm single fit: {cal.iterations} LM steps; batched iterations median/max "
          f"{int(np.median(fleet_batch.iterations))}/{int(np.max(fleet_batch.iterations))} (fleet case), "
          f"{int(np.median(guess_batch.iterations))}/{int(np.max(guess_batch.iterations))} (from the guess)")
    print(f"two-pass batch vs one pass: {t_one / t_batch:.2f}x faster, estimates differ by at most "
          f"{shift:.1e} standard errors")
    print("targets: warm single fit <= 5 ms; batched >= 1000 motors/s; demo < half the seed workflow")

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                    "jax": jax.__version__, "drivecal": dc.__version__},
        "seed_fit_s": t_seed_fit,
        "drivecal_fit_first_s": t_first,
        "drivecal_fit_warm_s": t_warm,
        "drivecal_fit_iterations": int(cal.iterations),
        "drivecal_fit_warm_started_at_guess_s": t_warm_guess,
        "drivecal_fit_iterations_started_at_guess": int(cal_guess.iterations),
        "batch_size": args.batch,
        "batched_motors_per_s_from_guess": rate_guess,
        "batched_motors_per_s_from_guess_one_pass": args.batch / t_one,
        "two_pass_speedup_same_process": t_one / t_batch,
        "two_pass_max_estimate_shift_in_se": shift,
        "batched_motors_per_s_fleet": rate_fleet,
        "batched_motors_per_s_fleet_measured_speed": rate_spin,
        "seed_workflow_s": t_seed_wf,
        "drivecal_demo_fresh_process_s": t_demo,
        "drivecal_demo_fresh_process_empty_cache_s": t_demo_cold,
        "seed_workflow_fresh_process_s": t_seed_wf_fresh,
        "demo_over_seed_workflow": (t_demo / t_seed_wf) if t_demo else None,
        "demo_over_seed_workflow_both_fresh_processes": (t_demo / t_seed_wf_fresh) if t_demo else None,
        "demo_empty_cache_over_seed_workflow_both_fresh_processes": (t_demo_cold / t_seed_wf_fresh)
        if t_demo else None,
    }, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
