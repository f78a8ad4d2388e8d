"""Issue 19: bench logs as they come off a bench (MDF4, TDMS, HDF5, CSV exports) read through a format file.

Each log is written with its format's own library as a bench writes it: one continuous recording of the
default plan with short rests between the segments, currents in mA, speed in rpm, the angle in degrees,
no segment column. Read with a format file it gives the bench (to 1e-12) and the calibration (to 1e-9)
of the equivalent drivecal CSV.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from drivecal import data

from helpers.bench_logs import (assert_same_bench, continuous_recording, format_toml, small_frame, speed_bench,
                                write_hdf5, write_mdf4, write_tdms)

WRITERS = {"mf4": write_mdf4, "tdms": write_tdms, "h5": write_hdf5}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """(the logged channels, the true windows, the equivalent drivecal CSV read back, the directory)."""
    bench = speed_bench()
    root = tmp_path_factory.mktemp("logs")
    logged, windows = continuous_recording(bench)
    csv_bench = dc.load_bench(bench.save(root / "bench.csv"))
    return logged, windows, csv_bench, root


@pytest.fixture(scope="module")
def csv_fit(recording, guess):
    return dc.fit(recording[2], guess)


def _write(kind, recording):
    logged, windows, _, root = recording
    path = WRITERS[kind](root / f"bench.{kind}", logged)
    fmt = root / f"{kind}.toml"
    # TDMS: the channels are waveforms (wf_increment) and carry their own clock: no time channel to map.
    fmt.write_text(format_toml(windows, t_name=None if kind == "tdms" else "time"))
    return path, fmt


@pytest.mark.parametrize("kind", list(WRITERS))
def test_a_bench_log_gives_the_calibration_of_the_equivalent_csv(kind, recording, csv_fit, guess):
    path, fmt = _write(kind, recording)
    bench = dc.load_bench(path, format=fmt)
    assert [s.name for s in bench.segments] == ["locked d-step", "locked q-step", "free spin-up"]
    assert_same_bench(bench, recording[2])
    assert bench.source == str(path)
    cal = dc.fit(bench, guess)
    np.testing.assert_allclose(cal.estimate, csv_fit.estimate, rtol=1e-9)
    np.testing.assert_allclose(cal.se, csv_fit.se, rtol=1e-6)


def test_a_tdms_channel_named_by_group_and_a_hdf5_dataset_by_path(recording):
    logged, windows, csv_bench, root = recording
    tdms = write_tdms(root / "grouped.tdms", logged, group="Messung")
    names = {"v_d": "Messung/Ud_ref", "v_q": "/Messung/Uq_ref", "i_d": "Id", "i_q": "Iq", "w_m": "n_mech",
             "theta_e": "phi_el"}
    assert_same_bench(dc.load_bench(tdms, format=data.format_from_dict(
        _toml(format_toml(windows, t_name=None, names=names)), "f.toml")), csv_bench)
    h5 = write_hdf5(root / "nested.h5", logged, group="run1/drive")
    names = {"t": "/run1/drive/time", "v_d": "run1/drive/Ud_ref", "v_q": "Uq_ref", "i_d": "Id", "i_q": "Iq",
             "w_m": "n_mech", "theta_e": "phi_el"}
    assert_same_bench(dc.load_bench(h5, format=data.format_from_dict(_toml(format_toml(windows, names=names)))),
                      csv_bench)


def _toml(text):
    import tomllib

    return tomllib.loads(text)


@pytest.mark.parametrize("stated", [False, True])
def test_a_semicolon_decimal_comma_csv_export_reads_the_same(stated, recording):
    logged, windows, csv_bench, root = recording
    path = root / f"export_{stated}.csv"
    pd.DataFrame(logged).to_csv(path, sep=";", decimal=",", index=False, float_format="%.17g")
    lines = path.read_text().splitlines()
    assert ";" in lines[0] and "," not in lines[0] and "," in lines[100]  # a decimal comma
    extra = '\n[csv]\ndelimiter = ";"\ndecimal = ","\n' if stated else ""
    fmt = root / f"export_{stated}.toml"
    fmt.write_text(format_toml(windows, extra=extra))
    assert_same_bench(dc.load_bench(path, format=fmt), csv_bench)


def test_a_drivecal_csv_with_semicolons_and_decimal_commas_needs_no_format_file(tmp_path):
    bench = dc.bench_from_frame(small_frame())
    bench.to_frame().to_csv(tmp_path / "b.csv", sep=";", decimal=",", index=False, float_format="%.17g")
    assert data.csv_dialect((tmp_path / "b.csv").read_bytes()) == (";", ",")
    assert_same_bench(dc.load_bench(tmp_path / "b.csv"), bench)
    bench.to_frame().to_csv(tmp_path / "tab.csv", sep="\t", index=False, float_format="%.17g")
    assert data.csv_dialect((tmp_path / "tab.csv").read_bytes()) == ("\t", ".")
    assert_same_bench(dc.load_bench(tmp_path / "tab.csv"), bench)
    assert data.csv_dialect(b"segment,t,v_d\nd,0.5,1\n") == (",", ".")




@pytest.mark.parametrize("unit, value, si", [
    ("A", 2.0, 2.0), ("mA", 2.0, 2e-3), ("kA", 2.0, 2e3), ("V", 3.0, 3.0), ("mV", 3.0, 3e-3), ("kV", 3.0, 3e3),
    ("s", 5.0, 5.0), ("ms", 5.0, 5e-3), ("us", 5.0, 5e-6), ("µs", 5.0, 5e-6), ("rad/s", 7.0, 7.0),
    ("rpm", 60.0, 2 * math.pi), ("Hz", 1.0, 2 * math.pi), ("rad", 1.0, 1.0), ("deg", 180.0, math.pi),
    ("°C", 20.0, 20.0), ("degC", 20.0, 20.0), ("K", 293.15, 20.0)])
def test_units_convert_to_si(unit, value, si):
    from drivecal.data import LOG_UNITS, canonical_unit

    assert canonical_unit(unit) in LOG_UNITS
    quantity, scale, offset = LOG_UNITS[canonical_unit(unit)]
    assert value * scale + offset == pytest.approx(si, rel=1e-12)


def test_windows_leave_out_the_samples_between_them_and_a_late_start_is_the_initial_state(recording):
    """Samples outside every window are ignored; a window that starts mid-step starts from its first sample."""
    logged, windows, csv_bench, root = recording
    path = write_mdf4(root / "late.mf4", logged)
    late = [dict(w) for w in windows]
    fs = csv_bench.sample_rate
    start_ms = float(late[0]["start"].split()[0])
    late[0]["start"] = f"{start_ms + 50 / fs * 1e3:.10g} ms"  # 50 samples into the d-step
    bench = dc.load_bench(path, format=data.format_from_dict(_toml(format_toml(late))))
    first = bench.segments[0]
    assert first.num_samples == csv_bench.segments[0].num_samples - 50
    assert not first.at_rest
    np.testing.assert_allclose(first.initial_state()[:2], csv_bench.segments[0].currents[50], rtol=1e-12)
    assert_same_bench(dc.BenchData(bench.segments[1:], bench.sample_rate),
                      dc.BenchData(csv_bench.segments[1:], csv_bench.sample_rate))


def test_phase_channels_map_the_same_way(tmp_path):
    """i_a, i_b, v_a, v_b and theta_m in a log, in mA and degrees, read as the phase CSV reads."""
    bench = dc.bench_from_frame(small_frame())
    theta_e = 4.0 * np.linspace(0.0, 2.0, bench.num_samples)
    phases = bench.to_phase_frame(theta_e).drop(columns=["i_c", "v_c"])
    ref = dc.bench_from_frame(phases.assign(theta_m=theta_e / 4.0).drop(columns=["theta_e"]), "ref", pole_pairs=4.0)
    log = pd.DataFrame({"zeit_ms": np.arange(len(phases)) / 20.0, "Seg": phases["segment"], "Lock": phases["locked"],
                        "Ia": phases["i_a"] * 1e3, "Ib": phases["i_b"] * 1e3, "Ua": phases["v_a"],
                        "Ub": phases["v_b"], "phi_m": np.degrees(theta_e / 4.0)})
    log.to_parquet(tmp_path / "phase.parquet", index=False)
    fmt = data.format_from_dict({
        "columns": {"t": "zeit_ms", "segment": "Seg", "locked": "Lock", "i_a": "Ia", "i_b": "Ib", "v_a": "Ua",
                    "v_b": "Ub", "theta_m": "phi_m"},
        "units": {"t": "ms", "i_a": "mA", "i_b": "mA", "theta_m": "deg"}})
    got = dc.load_bench(tmp_path / "phase.parquet", format=fmt, pole_pairs=4.0)
    np.testing.assert_allclose(got.currents, ref.currents, rtol=1e-12, atol=1e-12)
    for a, b in zip(got.segments, ref.segments):
        np.testing.assert_allclose(a.voltages, b.voltages, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-12)


def test_a_log_with_a_segment_channel_needs_no_windows(tmp_path):
    """Segments from a text channel, as a drivecal file has them: mapped by a format file, or (channels named as
    drivecal's columns, in SI units) read without one."""
    import h5py

    bench = dc.bench_from_frame(small_frame(), "small")
    frame = bench.to_frame()
    with h5py.File(tmp_path / "named.h5", "w") as f:
        for column in frame.columns:
            values = frame[column].to_numpy()
            f.create_dataset(column, data=values.astype("S") if column == "segment" else values)
    assert_same_bench(dc.load_bench(tmp_path / "named.h5"), bench)
    with h5py.File(tmp_path / "own.h5", "w") as f:
        f.create_dataset("log/step", data=frame["segment"].to_numpy().astype("S"))
        f.create_dataset("log/clamp", data=frame["locked"].to_numpy())
        f.create_dataset("log/zeit", data=frame["t"].to_numpy() * 1e6).attrs["unit"] = "µs"
        for column, name in (("v_d", "Ud"), ("v_q", "Uq"), ("i_d", "Id"), ("i_q", "Iq")):
            f.create_dataset(f"log/{name}", data=frame[column].to_numpy() * (1e3 if column[0] == "i" else 1.0))
    fmt = data.format_from_dict({"columns": {"segment": "step", "locked": "clamp", "t": "zeit", "v_d": "Ud",
                                             "v_q": "Uq", "i_d": "Id", "i_q": "Iq"},
                                 "units": {"t": "us", "i_d": "mA", "i_q": "mA"}}, "own.toml")
    assert_same_bench(dc.load_bench(tmp_path / "own.h5", format=fmt), bench)
