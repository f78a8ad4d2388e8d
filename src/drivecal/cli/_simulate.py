"""``drivecal simulate``: run a plan on the synthetic bench and write a bench file."""

from __future__ import annotations

import click

from ..errors import DrivecalError
from ._common import _check_out, _console, _load_motor, _motor_option, _Positive


@click.command("simulate")
@click.argument("plan_path", metavar="PLAN.toml", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--noise", type=_Positive(), default=0.02, show_default=True,
              help="Current-sensor noise standard deviation [A] added to i_d and i_q.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True, help="Seed of the sensor noise.")
@click.option("--speed/--no-speed", "record_speed", default=True, show_default=True,
              help="Also write the measured mechanical speed w_m [rad/s] (an encoder; noise-free).")
@click.option("--out", "out_path", required=True, type=click.Path(),
              help="Bench file to write: .csv, .parquet or .mat (format from the suffix).")
def simulate(plan_path, motor_path, noise, seed, record_speed, out_path):
    """Run PLAN.toml on the synthetic bench and write a bench file.

    The plan runs on the Jaxonomy engine (its PMSM block and adaptive solver)
    with the motor of --motor, currents are sampled at the plan's sample rate
    and seeded Gaussian noise is added. The file has the bench-file columns
    (segment, locked, t, v_d, v_q, i_d, i_q, w_m; temperature when the plan
    sets one) and can be fitted with `drivecal fit`. Bench effects set in the
    motor file (v_dead, offsets, delay_samples, alpha_R with segment
    temperatures) are part of the simulated truth.
    """
    out = _check_out(out_path, "--out", example="out/bench.csv")
    if out.suffix.lower() not in (".csv", ".parquet", ".mat"):
        raise DrivecalError(f"--out {out}: unknown format '{out.suffix}'; use a .csv, .parquet or .mat name.")
    from ..bench import engine_bench
    from ..plan import load_plan

    plan = load_plan(plan_path)
    motor_file = _load_motor(motor_path)
    console = _console(False)
    with console.status(f"running {len(plan.segments)} segment(s) on the Jaxonomy engine..."):
        bench = engine_bench(plan, motor_file.motor, record_speed=record_speed,
                             delay_samples=motor_file.delay_samples).add_noise(noise, seed)
        bench.save(out)
    console.print(f"wrote {out}: {bench.num_samples} samples in {len(bench.segments)} segment(s) at "
                  f"{bench.sample_rate:g} Hz, noise {noise * 1e3:g} mA (seed {seed})")
