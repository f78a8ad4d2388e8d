"""Bench data: the BenchData type, file readers, the checks every bench file passes, and motor files.

Bench logs as a bench writes them (MDF4, TDMS, HDF5, any CSV dialect) are read through a format file
(:func:`load_format`): channel names, units and segment windows onto drivecal's columns.

pandas and pyarrow (~0.4 s to import) are imported where a table is read or written, not with this
package: the commands that read none (``design``, ``plan``, ``report``, ``gains``) never load them. The names
below are loaded from their modules on first use: a motor file's values and limits (:func:`motor_nominal`, what
``drivecal fleet-report --motor`` reads) load no JAX; the bench data's modules load it (through the
sub-packages they import, which set up JAX first).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import lazy_names as _lazy_names

if TYPE_CHECKING:  # the names' origins, for type checkers and the API reference; loaded at run time by __getattr__
    from ._bench_data import BenchData, SegmentData, stacked_experiment
    from ._checks import AT_REST_NOISE_SAMPLES, DQ_COLUMNS, bench_from_frame, benches_from_frames, load_bench
    from ._format_file import BenchFormat, Window, format_from_dict, load_format
    from ._inspect import ChannelInfo, Inspection, guess_columns, inspect_log
    from ._log_units import COLUMN_QUANTITY, LOG_UNITS, MAPPABLE, SI_UNIT, canonical_unit
    from ._logs import LOG_FORMATS, LogChannel, is_log, read_log
    from ._mapping import check_mapped, log_channels, read_columns
    from ._motor_file import MotorFile, load_motor, motor_from_dict
    from ._motor_spec import HinkkanenSpec, MotorSpec
    from ._nominal import MotorNominal, motor_nominal
    from ._tolerance import Tolerance, tolerance_of, tolerances_of
    from ._readers import FORMATS, TABLE_FORMATS, TEXT_COLUMNS, columns_of, csv_dialect, read_table
    from ._windows import Proposal, propose_windows
    from ._speed import (INPUT_ERROR_RATIO_MAX, SpeedChoice, SpeedResolution, choose_speed, input_error_ratio,
                         speed_lattice, speed_resolution, update_period)

# The module of this package that defines each name (loaded on first access), as imported above.
_MODULES: dict[str, tuple[str, ...]] = {
    "_bench_data": ("BenchData", "SegmentData", "stacked_experiment"),
    "_checks": ("AT_REST_NOISE_SAMPLES", "DQ_COLUMNS", "bench_from_frame", "benches_from_frames", "load_bench"),
    "_format_file": ("BenchFormat", "Window", "format_from_dict", "load_format"),
    "_inspect": ("ChannelInfo", "Inspection", "guess_columns", "inspect_log"),
    "_log_units": ("COLUMN_QUANTITY", "LOG_UNITS", "MAPPABLE", "SI_UNIT", "canonical_unit"),
    "_logs": ("LOG_FORMATS", "LogChannel", "is_log", "read_log"),
    "_mapping": ("check_mapped", "log_channels", "read_columns"),
    "_motor_file": ("MotorFile", "load_motor", "motor_from_dict"),
    "_motor_spec": ("HinkkanenSpec", "MotorSpec"),
    "_nominal": ("MotorNominal", "motor_nominal"),
    "_tolerance": ("Tolerance", "tolerance_of", "tolerances_of"),
    "_readers": ("FORMATS", "TABLE_FORMATS", "TEXT_COLUMNS", "columns_of", "csv_dialect", "read_table"),
    "_windows": ("Proposal", "propose_windows"),
    "_speed": ("INPUT_ERROR_RATIO_MAX", "SpeedChoice", "SpeedResolution", "choose_speed", "input_error_ratio",
               "speed_lattice", "speed_resolution", "update_period"),
}

__all__ = ["AT_REST_NOISE_SAMPLES", "BenchData", "BenchFormat", "COLUMN_QUANTITY", "ChannelInfo", "DQ_COLUMNS",
           "FORMATS", "INPUT_ERROR_RATIO_MAX", "Inspection", "LOG_FORMATS", "LOG_UNITS", "LogChannel", "MAPPABLE",
           "HinkkanenSpec", "MotorFile", "MotorNominal", "MotorSpec", "Proposal", "SI_UNIT", "SegmentData",
           "SpeedChoice", "SpeedResolution", "TABLE_FORMATS", "TEXT_COLUMNS", "Tolerance", "Window",
           "bench_from_frame", "benches_from_frames", "canonical_unit", "check_mapped", "choose_speed", "columns_of",
           "csv_dialect", "format_from_dict", "guess_columns", "input_error_ratio", "inspect_log", "is_log",
           "load_bench", "load_format", "load_motor", "log_channels", "motor_from_dict", "motor_nominal",
           "propose_windows", "read_columns", "read_log", "read_table", "speed_lattice", "speed_resolution",
           "stacked_experiment", "tolerance_of", "tolerances_of", "update_period"]

__getattr__, __dir__ = _lazy_names(__name__, _MODULES)
