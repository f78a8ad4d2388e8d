"""``drivecal simulate``: run a plan on the synthetic bench and write a bench file."""

from __future__ import annotations

import click

from ..errors import DrivecalError
from ._common import _check_out, _console, _load_motor, _motor_option, _plan_noise, _Positive

#: RK4 steps per carrier period on the switching plant: its step grid holds every switching edge, so 16
#: already agrees with 64 to ~1e-13 A (tests/bench/test_pwm.py), at a quarter of the run time.
SUBSTEPS = 16
#: Motor-file bench effects the switching plant leaves to its own inverter model or does not have.
_AVERAGED_ONLY = ("v_dead", "offset_d", "offset_q", "offset_a", "offset_b")


class _Quantity(click.ParamType):
    """A number >= 0 in SI units, or a number with a unit of the kind (``1e-6``, ``"1 us"``, ``"0.7 V"``)."""

    def __init__(self, kind: str, unit: str):
        self.kind, self.unit, self.name = kind, unit, f"{kind} [{unit}]"

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            return value
        from .._units import parse_quantity

        try:
            x = parse_quantity(value, self.kind)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)
        if not x >= 0:
            self.fail(f"{value!r} must be >= 0 {self.unit}", param, ctx)
        return x


def _describe(model: str, modulation: str, dead_time: float, device_drop: float, delay: float) -> str:
    """What ran, in words: "switching SVPWM inverter, 1 µs dead time, 0.7 V device drop, delay 1 sample"."""
    delay_words = f"delay {delay:g} sample{'' if delay == 1 else 's'}"
    if model == "averaged":
        return f"averaged inverter (Jaxonomy engine), {delay_words}"
    dead = f"{dead_time * 1e6:g} µs dead time" if dead_time else "no dead time"
    drop = f"{device_drop:g} V device drop" if device_drop else "no device drop"
    return f"switching {modulation.upper() if modulation == 'svpwm' else modulation} inverter, {dead}, {drop}, " \
           f"{delay_words}"


@click.command("simulate")
@click.argument("plan_path", metavar="PLAN.toml", type=click.Path(dir_okay=False))
@_motor_option
@click.option("--noise", type=_Positive(), default=None,
              help="Current-sensor noise standard deviation [A] added to i_d and i_q. Default: the plan's "
                   "current_noise (the noise it was designed for), else 0.02.")
@click.option("--seed", type=click.IntRange(min=0), default=1, show_default=True, help="Seed of the sensor noise.")
@click.option("--speed/--no-speed", "record_speed", default=True, show_default=True,
              help="Also write the measured mechanical speed w_m [rad/s] (an encoder; noise-free).")
@click.option("--encoder-counts", "encoder_counts", type=click.IntRange(min=1), default=None, metavar="N",
              help="Record w_m and theta_e as an N-count incremental encoder does: the angle in whole counts, the "
                   "speed the difference of two counts over one sample (steps of 2*pi/N * sample rate). "
                   "Default: exact.")
@click.option("--inverter", "model", type=click.Choice(["averaged", "switching"]), default=None,
              help="The inverter: 'averaged' (the commanded dq voltage held over each sample, on the Jaxonomy "
                   "engine) or 'switching' (center-aligned carrier-comparison PWM, one carrier period per "
                   "sample, currents sampled at the carrier peak). Default: the plan's [inverter] model, "
                   "else averaged.")
@click.option("--modulation", type=click.Choice(["svpwm", "sine"]), default=None,
              help="Switching inverter's modulation: 'svpwm' (min-max zero sequence) or 'sine' (sine-triangle). "
                   "Default: the plan's [inverter] modulation, else svpwm.")
@click.option("--dead-time", "dead_time", type=_Quantity("time", "s"), default=None, metavar="SECONDS",
              help="Switching inverter's dead time per switching edge [s] (e.g. 1e-6 or '1 us'); the leg's "
                   "voltage then follows the current's sign. Default: the plan's [inverter] dead_time, else 0.")
@click.option("--device-drop", "device_drop", type=_Quantity("voltage", "V"), default=None, metavar="VOLTS",
              help="Switching inverter's forward drop of a conducting switch or diode [V] (e.g. 0.7). Default: "
                   "the plan's [inverter] device_drop, else 0.")
@click.option("--out", "out_path", required=True, type=click.Path(),
              help="Bench file to write: .csv, .parquet or .mat (format from the suffix).")
def simulate(plan_path, motor_path, noise, seed, record_speed, encoder_counts, model, modulation, dead_time, device_drop,
             out_path):
    """Run PLAN.toml on the synthetic bench and write a bench file.

    The plan runs on the inverter of the plan's [inverter] table, or of
    --inverter. Averaged (the default): the Jaxonomy engine (its PMSM block and
    adaptive solver) with the motor of --motor; the motor file's bench effects
    (v_dead, offsets, delay_samples, alpha_R with segment temperatures) are part
    of the simulated truth. Switching: drivecal's independent switching-level
    plant, center-aligned SVPWM or sine PWM with dead time per edge (--dead-time
    [s]) and device drops (--device-drop [V]), currents sampled at the carrier
    peak, and the motor file's delay_samples (a multiple of 0.5) as the
    computation delay; the motor file must then leave v_dead and the offsets at
    0 (the dead time is physical there).

    Currents are sampled at the plan's sample rate and seeded Gaussian noise is
    added: --noise, else the plan's current_noise (the noise it was designed
    for), else 20 mA; the output says which. The file has the bench-file columns (segment, locked, t, v_d, v_q,
    i_d, i_q, w_m; temperature when the plan sets one) and can be fitted with
    `drivecal fit`.
    """
    out = _check_out(out_path, "--out", example="out/bench.csv")
    if out.suffix.lower() not in (".csv", ".parquet", ".mat"):
        raise DrivecalError(f"--out {out}: unknown format '{out.suffix}'; use a .csv, .parquet or .mat name.")
    if encoder_counts is not None and not record_speed:
        raise DrivecalError("--encoder-counts records the speed; leave out --no-speed.")
    from ..errors import PlanError
    from ..plan import load_plan

    plan = load_plan(plan_path)
    noise, noise_source = _plan_noise(plan, noise)
    motor_file = _load_motor(motor_path)
    table = plan.inverter
    model = model or table.model
    given = {"--modulation": modulation, "--dead-time": dead_time, "--device-drop": device_drop}
    modulation = modulation or table.modulation
    dead_time = table.dead_time if dead_time is None else dead_time
    device_drop = table.device_drop if device_drop is None else device_drop
    if model == "averaged":
        if dead_time or device_drop or given["--modulation"]:
            where = ", ".join(k for k, v in given.items() if v) or f"{plan_path}'s [inverter] table"
            raise DrivecalError(f"{where}: the averaged inverter has no modulation, dead time or device drop; "
                                "choose --inverter switching, or give the averaged dead-time voltage as the "
                                "motor file's v_dead.")
    else:
        motor = motor_file.motor
        for name in _AVERAGED_ONLY:
            if float(getattr(motor, name)) != 0.0:
                raise DrivecalError(f"--motor {motor_path}: {name} = {float(getattr(motor, name)):g} is an averaged "
                                    "bench effect the switching inverter does not take (its dead time is physical, "
                                    "its sensors ideal); set it to 0 in the motor file and give --dead-time instead, "
                                    "or choose --inverter averaged.")
    ran = _describe(model, modulation, dead_time, device_drop, motor_file.delay_samples)
    console = _console(False)
    with console.status(f"running {len(plan.segments)} segment(s) on the {ran}..."):
        if model == "averaged":
            from ..bench import engine_bench

            bench = engine_bench(plan, motor_file.motor, record_speed=record_speed,
                                 delay_samples=motor_file.delay_samples)
        else:
            from ..bench import pwm_bench

            try:
                bench = pwm_bench(plan, motor_file.motor, delay_samples=motor_file.delay_samples, t_dead=dead_time,
                                  v_f=device_drop, modulation=modulation, substeps=SUBSTEPS,
                                  record_speed=record_speed)
            except PlanError as exc:
                raise DrivecalError(f"--inverter switching: {exc}") from None
        if encoder_counts is not None:
            from ..bench import encoder_readings

            bench = encoder_readings(bench, encoder_counts, float(motor_file.motor.pole_pairs))
        bench = bench.add_noise(noise, seed)
        bench.save(out)
    console.print(f"wrote {out}: {bench.num_samples} samples in {len(bench.segments)} segment(s) at "
                  f"{bench.sample_rate:g} Hz, noise {noise * 1e3:.4g} mA ({noise_source}; seed {seed})")
    if model == "switching":
        console.print(f"ran on the {ran}")
