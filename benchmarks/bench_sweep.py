"""Forward-model sweep benchmark: the rollout before and after the segment-wise rewrite, in one process.

Times the value and the value+Jacobian (``jax.jacfwd`` over R, Ld, Lq,
lambda_m) of ``predict_currents``, for one motor and for a ``vmap`` over B
motors, on the default plan (simulated spin-up) and on the same bench with the
speed measured (every segment linear in the currents). The baseline is the
rollout as it was before (one ``jax.lax.scan`` over all samples, the dq
equations divided by Ld, Lq, J at every stage), copied below. "new" is
``predict_currents`` with the tangent mode the fit picks: linearised steps for
one motor, forward mode through the scans for the batch
(``Experiment.linearised_tangents``). Old and new run alternately in the same
process; each figure is the median of several rounds. Also checks that both
agree (max |difference| of currents and Jacobian).

Prints a table and writes benchmarks/results/bench_sweep.json.

    PYTHONPATH=src .venv/bin/python benchmarks/bench_sweep.py [--batch 256] [--rounds 7]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import drivecal as dc
from drivecal.model import _rollout as forward

RESULTS = Path(__file__).parent / "results" / "bench_sweep.json"
NAMES = dc.ESTIMATED


# --- the baseline: the rollout before the rewrite (verbatim but for names) ----------------


def _baseline_derivatives(state, v_dq, motor, locked):
    i_d, i_q, w_m = state[0], state[1], state[2]
    v_d, v_q = v_dq[0], v_dq[1]
    w_e = motor.pole_pairs * w_m
    di_d = (v_d - motor.R * i_d + w_e * motor.Lq * i_q) / motor.Ld
    di_q = (v_q - motor.R * i_q - w_e * (motor.Ld * i_d + motor.lambda_m)) / motor.Lq
    torque = 1.5 * motor.pole_pairs * (motor.lambda_m * i_q + (motor.Ld - motor.Lq) * i_d * i_q)
    free = 1.0 - jnp.asarray(locked, dtype=float)
    dw_m = free * (torque - motor.B * w_m - motor.T_load) / motor.J
    return di_d, di_q, dw_m, free * w_m


def _baseline_rk4_step(state, v_dq, motor, locked, dt, speed=None, speed_input=0.0, *, theta_e_start=0.0,
                       dead_time=False):
    if speed is None:
        speed = (state[2], state[2], state[2])
    w_mid = speed[1]

    def f(x, w_measured):
        x = (x[0], x[1], jnp.where(speed_input > 0, w_measured, x[2]), x[3])
        v = v_dq
        if dead_time:
            e_d, e_q = dc.inverter.dead_time_error(x[0], x[1], theta_e_start + motor.pole_pairs * x[3],
                                                   motor.v_dead, motor.i_dead)
            v = (v_dq[0] + e_d, v_dq[1] + e_q)
        d = _baseline_derivatives(x, v, motor, locked)
        return d[0], d[1], (1.0 - speed_input) * d[2], d[3]

    def axpy(x, k, h):
        return tuple(xi + h * ki for xi, ki in zip(x, k))

    k1 = f(state, speed[0])
    k2 = f(axpy(state, k1, 0.5 * dt), w_mid)
    k3 = f(axpy(state, k2, 0.5 * dt), w_mid)
    k4 = f(axpy(state, k3, dt), speed[2])
    out = tuple(x + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d) for x, a, b, c, d in zip(state, k1, k2, k3, k4))
    return out[0], out[1], jnp.where(speed_input > 0, speed[2], out[2]), out[3]


def baseline_rollout(motor, experiment, keep):
    dt = experiment.sample_period

    def step(x, sample):
        v_dq, locked, start, x0, speed, speed_input, temperature, theta_e_start = sample
        x = tuple(jnp.where(start, x0[i], x[i]) for i in range(4))
        warm = motor.replace(R=dc.motor.resistance_at(motor, temperature)) if experiment.thermal else motor
        substeps = experiment.dead_time_substeps if experiment.dead_time else 1
        x_next = x
        for j in range(substeps):
            a, b = j / substeps, (j + 1) / substeps
            stages = tuple(forward._quadratic(speed, u) for u in (a, 0.5 * (a + b), b))
            x_next = _baseline_rk4_step(x_next, v_dq, warm, locked, dt / substeps, stages, speed_input,
                                        theta_e_start=theta_e_start, dead_time=experiment.dead_time)
        return x_next, jnp.stack(x[:keep])

    inputs = (experiment.voltages, experiment.locked, experiment.segment_start, experiment.initial_state,
              experiment.speed, experiment.speed_input, experiment.temperature, experiment.theta_e_start)
    x_init = tuple(experiment.initial_state[0, i] for i in range(4))
    return jax.lax.scan(step, x_init, inputs)[1]


def baseline_predict_currents(motor, experiment):
    keep = 4 if experiment.phase_offsets else 2
    return forward.measured_currents(baseline_rollout(motor, experiment, keep), motor, experiment)


# --- timing -----------------------------------------------------------------------------


def _functions(predict, experiment, nominal):
    """jit-compiled value, Jacobian, batched value and batched Jacobian of ``predict``."""
    def currents(theta, exp):
        return predict(nominal.with_vector(NAMES, theta), exp)

    jac = jax.jacfwd(currents)
    return {
        "value": jax.jit(currents),
        "jacobian": jax.jit(jac),
        "batched value": jax.jit(jax.vmap(currents, in_axes=(0, None))),
        "batched jacobian": jax.jit(jax.vmap(jac, in_axes=(0, None))),
    }


def time_pair(fns: dict, args: tuple, rounds: int, inner: int) -> dict:
    """Median seconds per call of each function, the functions run alternately round by round."""
    for f in fns.values():
        jax.block_until_ready(f(*args))
    times = {k: [] for k in fns}
    for _ in range(rounds):
        for k, f in fns.items():
            t0 = time.perf_counter()
            for _ in range(inner):
                out = f(*args)
            jax.block_until_ready(out)
            times[k].append((time.perf_counter() - t0) / inner)
    return {k: float(np.median(v)) for k, v in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()

    nominal = dc.DEFAULT_MOTOR
    bench = dc.engine_bench(dc.default_plan(), nominal, record_speed=True)
    cases = {
        "default plan": bench.experiment(measured_speed=False),
        "measured speed": bench.experiment(measured_speed=True),
    }
    theta = nominal.vector(NAMES)
    spread = 1.0 + 0.02 * jax.random.normal(jax.random.PRNGKey(0), (args.batch, len(NAMES)))
    thetas = theta[None, :] * spread

    rows, report = [], {}
    for case, experiment in cases.items():
        old = _functions(baseline_predict_currents, experiment, nominal)
        new = _functions(dc.predict_currents, experiment, nominal)
        agree = {
            "currents_A": float(jnp.max(jnp.abs(old["value"](theta, experiment) - new["value"](theta, experiment)))),
            "jacobian_rel": float(jnp.max(jnp.abs(old["jacobian"](theta, experiment)
                                                  - new["jacobian"](theta, experiment)) * theta)
                                  / jnp.max(jnp.abs(old["jacobian"](theta, experiment)) * theta)),
        }
        report[case] = {"samples": experiment.num_samples, "segments": [list(s) for s in experiment.segments],
                        "agreement": agree, "timings_s": {}}
        for what in old:
            batched = what.startswith("batched")
            x = thetas if batched else theta
            # the tangent mode the fit picks for this batch size (fit.LINEARISED_TANGENTS_MAX_BATCH)
            mode = dataclasses.replace(experiment, linearised_tangents=not batched)
            t = time_pair({"old": lambda *a: old[what](x, experiment), "new": lambda *a: new[what](x, mode)}, (),
                          args.rounds, inner=2 if batched else 10)
            per = args.batch if batched else 1
            report[case]["timings_s"][what] = {"old": t["old"], "new": t["new"], "per": per}
            unit = "us/motor" if batched else "ms"
            scale = 1e6 / per if batched else 1e3
            rows.append((case, what, t["old"] * scale, t["new"] * scale, unit, t["old"] / t["new"]))
            print(f"{case:15s} {what:17s} old {rows[-1][2]:9.3f}  new {rows[-1][3]:9.3f} {unit:8s} x{rows[-1][5]:5.2f}",
                  flush=True)
        print(f"{case:15s} agreement: currents {agree['currents_A']:.1e} A, Jacobian {agree['jacobian_rel']:.1e} "
              "(relative, in ln(theta))", flush=True)

    report["machine"] = {"platform": platform.platform(), "processor": platform.processor(),
                         "jax": jax.__version__, "batch": args.batch, "rounds": args.rounds}
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
