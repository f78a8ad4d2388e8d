"""Issue 23: every input a bench can produce refused in one sentence (file, column, fix), exit 2, nothing written."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.io import savemat

import drivecal as dc

from helpers.cli import assert_one_sentence, run_cli
from test_data import small_frame


def _fit(path, tmp_path, capsys, *needles):
    out = tmp_path / "results"
    code, err = run_cli(["fit", path, "--out", out], capsys)
    assert_one_sentence(code, err, str(path), *needles)
    assert not out.exists()


def _mat_columns(frame):
    columns = {c: frame[c].to_numpy() for c in frame.columns if c != "segment"}
    columns["segment"] = np.array(frame["segment"].tolist(), dtype=object)
    return columns


@pytest.mark.parametrize("kind", ["timestamp", "duration"])
def test_parquet_time_as_timestamp_or_duration_reads_as_seconds(kind, tmp_path):
    frame = small_frame(200)
    delta = pd.to_timedelta(np.round(frame["t"] * 1e6), unit="us")
    frame["t"] = pd.Timestamp("2024-05-01 12:00", tz="UTC") + delta if kind == "timestamp" else delta
    path = tmp_path / "bench.parquet"
    frame.to_parquet(path, index=False)
    bench = dc.load_bench(path)
    assert bench.sample_rate == pytest.approx(20_000.0, rel=1e-9)
    np.testing.assert_allclose(bench.segments[0].t, np.arange(200) / 20_000.0, atol=1e-12)
    assert dc.bench_from_frame(frame, "frame").sample_rate == pytest.approx(20_000.0, rel=1e-9)


def test_csv_time_as_date_text_refused(tmp_path, capsys):
    frame = small_frame()
    frame["t"] = (pd.Timestamp("2024-05-01") + pd.to_timedelta(frame["t"], unit="s")).astype(str)
    path = tmp_path / "bench.csv"
    frame.to_csv(path, index=False)
    _fit(path, tmp_path, capsys, "column 't' holds date-times as text", "give t in seconds")


def test_complex_currents_in_mat_refused(tmp_path, capsys):
    columns = _mat_columns(small_frame())
    columns["i_q"] = columns["i_q"] + 0.5j
    path = tmp_path / "bench.mat"
    savemat(path, columns, oned_as="column")
    _fit(path, tmp_path, capsys, "column 'i_q' holds complex numbers", "real numbers")


@pytest.mark.parametrize("kind", ["bool", "category", "text"])
def test_booleans_or_text_where_numbers_belong_refused(kind, tmp_path, capsys):
    frame = small_frame()
    frame["locked"] = frame["locked"].astype(bool)  # a flag may be boolean
    if kind == "bool":
        frame["v_d"] = frame["v_d"] > 1
    elif kind == "category":
        frame["v_d"] = frame["v_d"].astype(str).astype("category")
    else:
        frame["v_d"] = frame["v_d"].astype(str)
    path = tmp_path / "bench.parquet"
    frame.to_parquet(path, index=False)
    _fit(path, tmp_path, capsys, "column 'v_d' holds", "booleans" if kind == "bool" else "text", "not numbers")


def _phase_frame(clean_default, theta_e):
    return clean_default.add_noise(0.02, 5).to_phase_frame(theta_e)


def test_angle_in_degrees_refused_but_radians_accepted(clean_default, tmp_path, capsys):
    n = clean_default.num_samples
    spin = 4.0 * np.linspace(0.0, 70.0, n)  # unwrapped radians, far beyond 2 pi
    for theta in (spin, np.mod(spin, 2 * np.pi), np.mod(spin + np.pi, 2 * np.pi) - np.pi):
        dc.bench_from_frame(_phase_frame(clean_default, theta), "radians.csv")
    frame = _phase_frame(clean_default, np.mod(spin, 2 * np.pi)).assign(theta_e=lambda f: np.degrees(f["theta_e"]))
    path = tmp_path / "bench.csv"
    frame.to_csv(path, index=False)
    _fit(path, tmp_path, capsys, "column 'theta_e' looks like degrees", "multiply by pi/180")
    by_m = frame.drop(columns="theta_e").assign(theta_m=np.mod(np.degrees(spin / 4.0), 360.0))
    with pytest.raises(dc.DataError, match="column 'theta_m' looks like degrees"):
        dc.bench_from_frame(by_m, "m.csv")


@pytest.mark.parametrize("prefix, how", [("i", "sign"), ("i", "offset"), ("v", "sign")])
def test_third_phase_contradicting_the_others_refused(prefix, how, clean_default, tmp_path, capsys):
    n = clean_default.num_samples
    frame = _phase_frame(clean_default, 4.0 * np.linspace(0.0, 7.0, n))
    c = f"{prefix}_c"
    frame[c] = -frame[c] if how == "sign" else frame[c] + 0.5 * frame[c].abs().max()
    path = tmp_path / "bench.csv"
    frame.to_csv(path, index=False)
    _fit(path, tmp_path, capsys, f"column '{c}' contradicts", f"drop column '{c}'", "sign and scaling")
    frame[f"v_c"] = frame["v_c"] + 50.0 if prefix == "i" else frame["v_c"]  # a common-mode voltage is fine ...
    frame[c] = -frame[f"{prefix}_a"] - frame[f"{prefix}_b"]
    dc.bench_from_frame(frame, "ok.csv")  # ... and so is a consistent third phase


def test_mat_matrix_variable_is_named(tmp_path, capsys):
    columns = _mat_columns(small_frame())
    columns["i_d"] = columns["i_d"].reshape(-1, 2)
    path = tmp_path / "bench.mat"
    savemat(path, columns, oned_as="column")
    _fit(path, tmp_path, capsys, "variable 'i_d' is a 60 x 2 matrix", "save each column as a vector")


def test_mat_file_of_one_struct_reads_its_fields(tmp_path, capsys):
    frame = small_frame()
    path = tmp_path / "bench.mat"
    savemat(path, {"run": _mat_columns(frame)})
    bench = dc.load_bench(path)
    np.testing.assert_array_equal(bench.currents, dc.bench_from_frame(frame, "f").currents)
    savemat(path, {"run": _mat_columns(frame), "other": np.zeros(3)})
    _fit(path, tmp_path, capsys, "variable 'run' is a struct", "save each column as a variable")


def test_truncated_or_corrupted_mat_file(tmp_path, capsys):
    path = tmp_path / "bench.mat"
    savemat(path, _mat_columns(small_frame()), oned_as="column")
    content = path.read_bytes()
    path.write_bytes(content[: len(content) // 2])
    _fit(path, tmp_path, capsys, "truncated", "save it again")
    bad = bytearray(content)
    bad[content.index(b"segment") + 56] = 180  # a cell's small element of an unknown type: crashed scipy
    path.write_bytes(bytes(bad))
    with pytest.raises(dc.DataError, match="truncated or corrupted"):
        dc.load_bench(path)


def test_parquet_list_column_is_named(tmp_path, capsys):
    frame = small_frame()
    frame["i_d"] = [[v] for v in frame["i_d"]]
    path = tmp_path / "bench.parquet"
    frame.to_parquet(path, index=False)
    _fit(path, tmp_path, capsys, "column 'i_d' holds lists", "not numbers")
