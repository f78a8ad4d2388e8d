"""Bench data: the BenchData type, file readers, the checks every bench file passes, and motor files."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._bench_data import BenchData, SegmentData, stacked_experiment
from ._checks import AT_REST_NOISE_SAMPLES, DQ_COLUMNS, bench_from_frame, benches_from_frames, load_bench
from ._motor_file import MotorFile, MotorSpec, load_motor, motor_from_dict
from ._readers import FORMATS, TEXT_COLUMNS, columns_of, read_table

__all__ = ["AT_REST_NOISE_SAMPLES", "BenchData", "DQ_COLUMNS", "FORMATS", "MotorFile", "MotorSpec", "SegmentData",
           "TEXT_COLUMNS", "bench_from_frame", "benches_from_frames", "columns_of", "load_bench", "load_motor",
           "motor_from_dict", "read_table", "stacked_experiment"]
