"""Bench data: the BenchData type, file readers and the checks every bench file passes."""

from .. import _setup  # noqa: F401  (float64 and the compilation cache, before any JAX work)
from ._bench_data import (AT_REST_NOISE_SAMPLES, BenchData, DQ_COLUMNS, FORMATS, SegmentData, TEXT_COLUMNS, bench_from_frame, benches_from_frames, columns_of, load_bench, read_table, stacked_experiment)

__all__ = ["AT_REST_NOISE_SAMPLES", "BenchData", "DQ_COLUMNS", "FORMATS", "SegmentData", "TEXT_COLUMNS", "bench_from_frame", "benches_from_frames", "columns_of", "load_bench", "read_table", "stacked_experiment"]
