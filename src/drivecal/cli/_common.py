"""The ``drivecal`` group, the pieces its commands share, and the entry point.

The commands are registered by name (:data:`COMMANDS`): a command's module is
imported only when the command runs or its help is asked, and each command
imports the numerical sub-packages (JAX, pandas, matplotlib, ...) inside its
body. So ``drivecal --help``, ``drivecal --version`` and ``drivecal COMMAND
--help`` load none of them. Rich is imported where something is printed.

Bad input never shows a traceback: it is one sentence on stderr and exit status 2.
"""

from __future__ import annotations

import atexit
import gc
import importlib
import math
import os
import sys
from typing import TYPE_CHECKING

import click

from .. import _exit
from .._io import check_output_path
from .._version import __version__
from .._status import Status
from ..errors import DrivecalError

if TYPE_CHECKING:
    from rich.console import Console

#: Exit statuses: bad input (the same as a refused file), and `batch` finishing with some motors not calibrated.
#: `drivecal fit` exits with its verdict's `Status.exit_code` (0 only when calibrated).
EXIT_BAD_INPUT = Status.INVALID.exit_code
EXIT_COMPLETED_WITH_FAILURES = 1
#: `batch` stopped because its dask cluster was lost (the scheduler, or every worker) or could not be reached:
#: the run is not finished; the motors saved so far are kept for --resume.
EXIT_CLUSTER_LOST = 8

#: name -> (module in this package, command object in it, the first paragraph of its help).
#: The summary is what ``drivecal --help`` lists without importing the module; a test checks
#: that it is the command's own (tests/test_cli.py).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "batch": ("_batch", "batch", "Calibrate many motors: one bench file per motor, one results table."),
    "demo": ("_demo", "demo", "Calibrate the default motor on the synthetic bench, then show a failed design."),
    "design": ("_design", "design",
               "Judge PLAN.toml before bench time: feasibility, identifiability, predicted intervals."),
    "fit": ("_fit", "fit_command", "Calibrate R, Ld, Lq, lambda_m from a bench file or log (CSV, Parquet, MAT, MDF4, TDMS, HDF5)."),
    "fleet-report": ("_fleet_report", "fleet_report",
                     "Summarise a `drivecal batch` table: counts, outliers, failures, histograms and trends."),
    "inspect": ("_inspect", "inspect",
                "List a bench log's channels and propose a format file: channel names, units, segment windows."),
    "gains": ("_gains", "gains", "Current-loop PI gains per axis from a saved calibration, with their uncertainty."),
    "plan": ("_plan", "plan_command",
             "Design a bench plan for the motor: feasible, identifiable, scaled to it and to the bench's limits."),
    "report": ("_report", "report",
               "Print the calibration report of a saved result JSON; optionally write the HTML report."),
    "simulate": ("_simulate", "simulate", "Run PLAN.toml on the synthetic bench and write a bench file."),
}


class _LazyGroup(click.Group):
    """A group whose commands live in :data:`COMMANDS` and are imported on first use."""

    def list_commands(self, ctx: click.Context | None) -> list[str]:
        return sorted({*COMMANDS, *self.commands})

    def get_command(self, ctx: click.Context | None, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            module, attr, _ = COMMANDS[cmd_name]
            command = getattr(importlib.import_module(f"{__package__}.{module}"), attr)
            self.add_command(command, cmd_name)
        return self.commands.get(cmd_name)

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """As click's, from the registered summaries: listing the commands imports none of them."""
        commands = []
        for name in self.list_commands(ctx):
            if name in self.commands:  # already loaded (or added directly): its own help
                command = self.commands[name]
            else:  # a stand-in with the same help text shortens it exactly as the command would
                command = click.Command(name, help=COMMANDS[name][2])
            if not command.hidden:
                commands.append((name, command))
        if not commands:
            return
        limit = formatter.width - 6 - max(len(name) for name, _ in commands)
        rows = [(name, command.get_short_help_str(limit)) for name, command in commands]
        if rows:
            with formatter.section("Commands"):
                formatter.write_dl(rows)


class _Positive(click.ParamType):
    name = "number > 0"

    def convert(self, value, param, ctx):
        try:
            x = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not (x > 0 and math.isfinite(x)):
            self.fail(f"{value!r} must be a positive, finite number", param, ctx)
        return x


class _Quantity(click.ParamType):
    """A number >= 0 (> 0 if ``positive``) in SI units, or a number with a unit of the kind (``1e-6``, ``"1 us"``,
    ``"0.7 V"``)."""

    def __init__(self, kind: str, unit: str, positive: bool = False):
        self.kind, self.unit, self.name, self.positive = kind, unit, f"{kind} [{unit}]", positive

    def convert(self, value, param, ctx):
        if isinstance(value, float):
            return value
        from .._units import parse_quantity

        try:
            x = parse_quantity(value, self.kind)
        except ValueError as exc:
            self.fail(str(exc), param, ctx)
        if not x >= 0 or (self.positive and not x > 0):
            self.fail(f"{value!r} must be {'> 0' if self.positive else '>= 0'} {self.unit}", param, ctx)
        return x


@click.group(cls=_LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="drivecal")
def cli():
    """drivecal: calibrate a PMSM's R, Ld, Lq and lambda_m from bench data.

    It checks that the bench experiment can identify each parameter before
    fitting, fits by Levenberg-Marquardt on the measured currents, and reports
    every estimate with a 95 % confidence interval. SI units throughout.

    Start with `drivecal demo`: a full calibration on the built-in synthetic
    bench (the Jaxonomy engine playing the motor).
    """


def _predicted_cells(nominal: float, half: float, unit: str) -> tuple[str, str, str, str]:
    """A predicted interval's table cells (`plan`, `design`): the unit as shown (mΩ, mH, ...), the nominal value
    and the 95 % half-width in it (two significant digits), and the half-width relative to the nominal [%]."""
    from .._units import display_unit, format_value

    scale, shown = display_unit(nominal if nominal else half, unit)
    relative = format_value(100 * half / abs(nominal), 1.0, 100 * half / abs(nominal)) if nominal else "-"
    return shown or "-", format_value(nominal, scale), format_value(half, scale, half), relative


#: The current-sensor noise [A] `design` and `simulate` assume where neither --noise nor the plan states one.
DEFAULT_NOISE = 0.02


def _plan_noise(plan, noise: float | None) -> tuple[float, str]:
    """The current-sensor noise [A] a command uses for ``plan`` and, in words, where it comes from: --noise,
    else the noise the plan file records (``current_noise``), else :data:`DEFAULT_NOISE`."""
    if noise is not None:
        return float(noise), "from --noise"
    if plan.current_noise is not None:
        return float(plan.current_noise), "the plan's current_noise"
    return DEFAULT_NOISE, "default; no current_noise in the plan"



_MOTOR_HELP = ("Motor file (TOML): nominal R, Ld, Lq, lambda_m (the prior) and fixed pole_pairs, J, B; "
               "optionally a saturating magnetic law (sat_d, sat_q, sat_dq or a [hinkkanen] table, "
               "examples/syrm_motor.toml). Default: the 48 V demo motor.")


def _motor_option(f):
    return click.option("--motor", "motor_path", type=click.Path(dir_okay=False), default=None, help=_MOTOR_HELP)(f)


_FORMAT_HELP = ("Bench format file (TOML): the log's channel names, units and segment windows (see `drivecal "
                "inspect LOG`). Default: the file has drivecal's own columns in SI units.")


def _format_option(f):
    return click.option("--format", "format_path", type=click.Path(dir_okay=False), default=None,
                        metavar="FORMAT.toml", help=_FORMAT_HELP)(f)


#: Warnings of the running command, printed on stderr after it ends (see :func:`main`): a refused input
#: stays one line on stderr. None outside :func:`main` (a warning is then printed at once).
_WARNINGS: list[str] | None = None


def _warn(message: str) -> None:
    """A warning line for stderr, ``drivecal: warning: ...``: after the command's output, or at once."""
    line = f"drivecal: warning: {message}"
    if _WARNINGS is None:
        click.echo(line, err=True)
    else:
        _WARNINGS.append(line)


def _load_motor(motor_path):
    """The motor of --motor (None: the built-in default motor); warns when the file leaves out a key that
    matters, which then takes the default motor's value."""
    from ..data import load_motor

    motor_file = load_motor(motor_path)
    if motor_file.defaulted:
        keys = ", ".join(motor_file.defaulted)
        _warn(f"--motor {motor_path}: {keys} not in the file; the built-in 48 V demo motor's value"
              f"{'s are' if len(motor_file.defaulted) > 1 else ' is'} used (add {keys} to the file to calibrate "
              "your own motor).")
    return motor_file


def _check_out(path, option: str, *, directory: bool = False, example: str | None = None):
    """An output path checked before any work (the one rule: :func:`drivecal._io.check_output_path`)."""
    return check_output_path(path, option, directory=directory, example=example)


def _console(as_json: bool) -> Console:
    """Rich console: stderr when stdout carries JSON; a pipe or a log file gets a fixed width wide enough
    for the tables."""
    from rich.console import Console

    return Console(stderr=as_json, width=None if sys.stdout.isatty() else 120)


#: The exit status the ``drivecal`` program ends with (:func:`_end_without_teardown`), set as :func:`main` ends.
_STATUS = 1


#: Objects the ``drivecal`` program lets the garbage collector's youngest generation hold (Python's default: 700).
#: Tracing JAX programs allocates hundreds of thousands of objects that live on (traced programs, caches); with
#: the default, they pushed the collector into full collections over every object of the imported libraries
#: (JAX, NumPy, SciPy, ...): 8 in a cold ``fit examples/bench.csv``, 1.4 s of it (``gc.callbacks``, under load),
#: 2 in a warm one (0.06 s). With 10 000, neither has a full collection (0.38 s and 0.07 s of collecting in
#: all), and garbage cycles are still collected as the process goes on (every 10 000 surviving objects).
YOUNG_GENERATION = 10_000

#: Variables any of which sets how many threads OpenBLAS (NumPy's and SciPy's linear algebra) starts.
#: The ``drivecal`` program sets the first to 1 where none is set, before NumPy loads (see :func:`main`).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "GOTO_NUM_THREADS", "OMP_NUM_THREADS")


def main(argv: list[str] | None = None) -> int:
    """Entry point: run the CLI, turning bad input into one line and exit status 2.

    Warnings (e.g. motor-file keys taken from the default motor) are printed on stderr after the
    command's output, unless the input was refused: then the one error line is all stderr holds.

    ``argv``: the arguments, returning the exit status (a caller in Python). None: this is the
    ``drivecal`` program (``sys.argv``): its garbage collector's youngest generation holds
    :data:`YOUNG_GENERATION` objects, its linear algebra runs in the thread that calls it (OpenBLAS
    with one thread, unless :data:`BLAS_THREAD_VARIABLES` say otherwise), and the process, once it has
    done what Python does at exit (its threads joined, the ``atexit`` callbacks run, output flushed),
    ends with this status without the interpreter's teardown (:func:`_end_without_teardown`).

    drivecal's matrices are small (a fit's normal equations, a few columns by a few thousand
    samples): OpenBLAS's second thread had nothing to gain there, but it spun waiting for work after
    each call, ~15 % of a warm ``fit examples/inverter_bench.csv``'s CPU samples on a 2-core machine
    (the command 7 % faster, 16 % less CPU without it). One thread gives the same numbers (``fit
    --json``, the demo's files and a batch's results the same to the byte).
    """
    global _WARNINGS, _STATUS
    if argv is None:
        if not any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES) and "numpy" not in sys.modules:
            os.environ[BLAS_THREAD_VARIABLES[0]] = "1"  # read by OpenBLAS as NumPy loads it (and by helpers)
        atexit.register(_end_without_teardown)  # before any other: the last to run
        _exit.WITHOUT_TEARDOWN = True
        gc.set_threshold(YOUNG_GENERATION, *gc.get_threshold()[1:])
    _WARNINGS = []
    refused = False
    try:
        _STATUS = _run(argv)
        return _STATUS
    except SystemExit as exc:
        refused = exc.code == EXIT_BAD_INPUT
        _STATUS = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        raise
    except KeyboardInterrupt:
        _STATUS = 130  # as a shell reports a program ended by Ctrl-C
        raise
    finally:
        pending, _WARNINGS = _WARNINGS, None
        if not refused:
            for line in pending:
                click.echo(line, err=True)


def _end_without_teardown() -> None:
    """End the ``drivecal`` process with :data:`_STATUS` now, skipping the interpreter's teardown (``atexit``).

    Registered first, it runs last: Python has joined the threads and run every other ``atexit``
    callback (files closed, temporary directories removed, logging shut down). What is left, freeing
    every module and object (the XLA client with its loaded executables among them), took 0.4-0.8 s
    of every command that ran JAX, and frees nothing the operating system does not free at exit.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be written to it
            pass
    os._exit(_STATUS)


def _run(argv: list[str] | None) -> int:
    try:
        rv = cli.main(args=argv, prog_name="drivecal", standalone_mode=False)
        return rv if isinstance(rv, int) else 0
    except click.UsageError as exc:
        command = exc.ctx.command_path if exc.ctx else "drivecal"
        click.echo(f"drivecal: error: {exc.format_message()} (see '{command} --help')", err=True)
        raise SystemExit(EXIT_BAD_INPUT)
    except click.Abort:
        click.echo("drivecal: aborted", err=True)
        raise SystemExit(1)
    except DrivecalError as exc:
        click.echo(f"drivecal: error: {exc}", err=True)
        raise SystemExit(EXIT_BAD_INPUT)
    except click.exceptions.Exit as exc:
        raise SystemExit(exc.exit_code)
