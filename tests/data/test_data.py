"""Bench files: formats, phase data, and every kind of bad input refused in one sentence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from helpers.cli import assert_one_sentence, run_cli

FS = 20_000.0


def small_frame(n: int = 60) -> pd.DataFrame:
    """Two plausible segments (a locked d-step, a free q-step) without running the engine."""
    t = np.arange(n) / FS
    rise = 1.0 - np.exp(-t * 0.45 / 3.2e-3)
    d = pd.DataFrame({"segment": "d", "locked": 1, "t": t, "v_d": 8.0, "v_q": 0.0,
                      "i_d": 8.0 / 0.45 * rise, "i_q": 0.0})
    q = pd.DataFrame({"segment": "spin", "locked": 0, "t": t, "v_d": 0.0, "v_q": 8.0,
                      "i_d": 0.0, "i_q": 8.0 / 0.45 * rise})
    return pd.concat([d, q], ignore_index=True)


def test_csv_text_is_pandas_csv_to_the_byte(clean_default):
    """The bench's CSV text (the synthetic bench's hash) is what pandas writes, with the optional columns, a
    name that needs quoting, NaN, infinities and a negative zero."""
    import dataclasses

    bench = clean_default.add_noise(0.02, 5)
    segs = list(bench.segments)
    n0, n1 = segs[0].num_samples, segs[1].num_samples
    segs[0] = dataclasses.replace(segs[0], name='a,"b"', inverter_off=True, temperature=np.full(n0, np.nan))
    segs[1] = dataclasses.replace(segs[1], temperature=np.linspace(20.0, 21.0, n1), w_m=-np.zeros(n1),
                                  theta_e=np.full(n1, np.inf))
    for b in (bench, dataclasses.replace(bench, segments=tuple(segs))):
        pandas_text = b.to_frame().to_csv(index=False, float_format="%.17g", lineterminator="\n")
        assert b.to_csv_text() == pandas_text


@pytest.mark.parametrize("suffix", [".csv", ".parquet", ".mat"])
def test_save_and_load_round_trip_exactly(tmp_path, suffix, clean_default):
    bench = clean_default.add_noise(0.02, 5)
    path = bench.save(tmp_path / f"bench{suffix}")
    loaded = dc.load_bench(path)
    assert loaded.sample_rate == pytest.approx(bench.sample_rate, rel=1e-9)
    assert [s.name for s in loaded.segments] == [s.name for s in bench.segments]
    assert [s.locked for s in loaded.segments] == [s.locked for s in bench.segments]
    np.testing.assert_array_equal(loaded.currents, bench.currents)
    for a, b in zip(loaded.segments, bench.segments):
        np.testing.assert_array_equal(a.voltages, b.voltages)
        assert a.at_rest
    assert not list(tmp_path.glob(".*part"))  # no temporary file left


def test_phase_data_converts_to_dq(clean_default):
    """Phase quantities made by inverse Park/Clarke read back as the dq file."""
    bench = clean_default.add_noise(0.02, 5)
    theta_e = 4.0 * np.linspace(0.0, 7.0, bench.num_samples)
    phases = bench.to_phase_frame(theta_e)
    np.testing.assert_allclose(phases[["i_a", "i_b", "i_c"]].sum(axis=1), 0.0, atol=1e-12)
    by_theta_m = phases.drop(columns=["theta_e"]).assign(theta_m=theta_e / 4.0)
    for frame in (phases, phases.drop(columns=["i_c", "v_c"]), by_theta_m):
        converted = dc.bench_from_frame(frame, "abc", pole_pairs=4.0)
        np.testing.assert_allclose(converted.currents, bench.currents, atol=1e-12)
        for a, b in zip(converted.segments, bench.segments):
            np.testing.assert_allclose(a.voltages, b.voltages, atol=1e-12)


def test_segment_not_at_rest_starts_from_its_first_sample():
    frame = small_frame()
    late = frame[frame["segment"] == "d"].iloc[10:]
    bench = dc.bench_from_frame(late, "late.csv")
    seg = bench.segments[0]
    assert not seg.at_rest
    np.testing.assert_allclose(seg.initial_state()[:2], late[["i_d", "i_q"]].to_numpy()[0])
    assert dc.bench_from_frame(frame, "ok.csv").segments[0].at_rest


def test_at_rest_noise_comes_from_the_start_of_the_segment():
    """The noise level the at-rest check compares the first sample with is that of the segment's start
    (data.AT_REST_NOISE_SAMPLES samples), not of what the segment does later."""
    from drivecal.data import AT_REST_NOISE_SAMPLES

    rng = np.random.default_rng(3)
    n = 4 * AT_REST_NOISE_SAMPLES
    noise = np.where(np.arange(n) < AT_REST_NOISE_SAMPLES, 0.01, 1.0) * rng.normal(size=n)
    frame = pd.DataFrame({"segment": "d", "locked": 1, "t": np.arange(n) / 20e3, "v_d": 0.0, "v_q": 0.0,
                          "i_d": noise, "i_q": 0.0})
    frame.loc[0, "i_d"] = 0.2  # 20 noise levels of the start, 0.2 of the later samples
    assert not dc.bench_from_frame(frame, "offset.csv").segments[0].at_rest
    frame.loc[0, "i_d"] = 0.02
    assert dc.bench_from_frame(frame, "quiet.csv").segments[0].at_rest


def _bad_frames():
    f = small_frame()
    cases = {}
    cases["missing column"] = (f.drop(columns=["i_q"]), ["missing column 'i_q'"])
    x = f.copy()
    x.loc[7, "i_d"] = np.nan
    cases["NaN"] = (x, ["column 'i_d'", "missing value in data row 8"])
    x = f.copy()
    x.loc[9, "v_q"] = np.inf
    cases["Inf"] = (x, ["column 'v_q'", "data row 10", "finite"])
    x = f.copy()
    x.loc[3, "segment"] = ""
    cases["empty segment name"] = (x, ["column 'segment' is empty in data row 4"])
    cases["no samples"] = (f.iloc[:0], ["has no samples"])
    x = pd.concat([f, f.iloc[[0]].assign(segment="lonely")], ignore_index=True)
    cases["single sample"] = (x, ["segment 'lonely' has a single sample"])
    x = f.copy()
    x.loc[20, "t"] += 0.3 / FS
    cases["non-uniform time"] = (x, ["segment 'd'", "not uniformly sampled", "resample"])
    x = f.copy()
    x.loc[[20, 21], "t"] = x.loc[[21, 20], "t"].to_numpy()
    cases["decreasing time"] = (x, ["segment 'd'", "column 't' decreases", "sort the rows"])
    x = f.copy()
    x.loc[21, "t"] = x.loc[20, "t"]
    cases["duplicated timestamps"] = (x, ["column 't' repeats the timestamp", "remove the duplicated rows"])
    x = f.copy()
    x["w_m"] = np.where(np.arange(len(x)) % 10 == 0, 1.0, np.nan)
    cases["mixed rates in a CSV"] = (x, ["column 'w_m' has a value only on every 10th row", "resample"])
    x = f.copy()
    x[["i_d", "i_q"]] *= 1000.0
    cases["currents in mA"] = (x, ["are 'i_d'/'i_q' in mA?", "divide by 1000"])
    x = f.copy()
    x.loc[x["segment"] == "spin", "t"] *= 2.0
    cases["mixed sample rates across segments"] = (x, ["sampled at 10000 Hz but 'd' at 20000 Hz"])
    return cases


CASES = _bad_frames()


@pytest.mark.parametrize("case", list(CASES))
def test_bad_bench_file_is_refused_in_one_sentence(case, tmp_path, capsys):
    frame, needles = CASES[case]
    path = tmp_path / "bench.csv"
    frame.to_csv(path, index=False)
    out = tmp_path / "results"
    code, err = run_cli(["fit", path, "--out", out], capsys)
    assert_one_sentence(code, err, str(path), *needles)
    assert not out.exists()  # nothing written


def test_mat_file_with_columns_of_different_lengths(tmp_path, capsys):
    from scipy.io import savemat

    f = small_frame()
    columns = {c: f[c].to_numpy() for c in f.columns if c != "segment"}
    columns["segment"] = np.array(f["segment"].tolist(), dtype=object)
    columns["w_m"] = np.zeros(len(f) // 10)
    path = tmp_path / "bench.mat"
    savemat(path, columns, oned_as="column")
    code, err = run_cli(["fit", path], capsys)
    assert_one_sentence(code, err, str(path), "w_m", "different sample rates")


def test_unreadable_and_unknown_files(tmp_path, capsys):
    code, err = run_cli(["fit", tmp_path / "nope.csv"], capsys)
    assert_one_sentence(code, err, "nope.csv: no such file")
    (tmp_path / "b.xlsx").write_text("x")
    code, err = run_cli(["fit", tmp_path / "b.xlsx"], capsys)
    assert_one_sentence(code, err, "unknown bench-file format '.xlsx'")


PLAN_OK = """
sample_rate = "20 kHz"
[[segment]]
name = "d"
duration = "5 ms"
locked = true
v_d = "8 V"
"""


@pytest.mark.parametrize(
    "text, needles",
    [
        (PLAN_OK.replace('v_d = "8 V"', 'v_d = "40 V"'), ["segment 'd'", "outside the voltage circle"]),
        ("colour = 3\n" + PLAN_OK, ["unknown key 'colour'"]),
        (PLAN_OK + "colour = 3\n", ["unknown key 'segment[0].colour'"]),
        (PLAN_OK.replace('"5 ms"', '"5 mV"'), ["'segment[0].duration'", "'5 mV' has unit 'mV' but a time in s"]),
    ],
)
def test_bad_plan_file_via_cli(text, needles, tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(text)
    out = tmp_path / "bench.csv"
    for args in (["simulate", plan, "--out", out], ["design", plan]):
        code, err = run_cli(args, capsys)
        assert_one_sentence(code, err, str(plan), *needles)
        assert not out.exists() and not list(tmp_path.glob(".bench*"))


def test_lambda_m_requested_without_free_segment(tmp_path, capsys):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN_OK)
    motor = tmp_path / "motor.toml"
    motor.write_text('estimate = ["R", "Ld", "lambda_m"]\n')
    code, err = run_cli(["design", plan, "--motor", motor], capsys)
    assert_one_sentence(code, err, str(plan), "lambda_m is requested", "no free-rotor segment",
                        "add a free spin-up segment")
    bench = tmp_path / "bench.csv"
    small_frame().query("segment == 'd'").to_csv(bench, index=False)
    code, err = run_cli(["fit", bench, "--motor", motor], capsys)
    assert_one_sentence(code, err, str(bench), "lambda_m is requested", "no free-rotor segment")


def test_bad_motor_file_via_cli(tmp_path, capsys):
    motor = tmp_path / "motor.toml"
    motor.write_text('R = "0.45 ohm"\nLd = "3.2 mA"\n')
    code, err = run_cli(["design", Path(__file__).resolve().parents[2] / "examples" / "default_plan.toml",
                         "--motor", motor], capsys)
    assert_one_sentence(code, err, str(motor), "'Ld'", "inductance")


def test_columns_and_frame_give_the_same_bench(tmp_path):
    """The columnar path (what files are read into) checks and splits exactly as a DataFrame does."""
    frame = small_frame()
    frame.loc[5, "i_d"] += 0.01  # something not symmetric
    from_frame = dc.bench_from_frame(frame, "frame")
    columns = {c: frame[c].to_numpy() for c in frame.columns}
    from_columns = dc.bench_from_frame(columns, "columns")
    path = tmp_path / "bench.parquet"
    frame.to_parquet(path, index=False)
    from_file = dc.load_bench(path)
    for other in (from_columns, from_file):
        assert other.sample_rate == from_frame.sample_rate
        for a, b in zip(other.segments, from_frame.segments):
            assert (a.name, a.locked, a.at_rest) == (b.name, b.locked, b.at_rest)
            np.testing.assert_array_equal(a.t, b.t)
            np.testing.assert_array_equal(a.voltages, b.voltages)
            np.testing.assert_array_equal(a.currents, b.currents)
    with pytest.raises(dc.DataError, match="one length"):
        dc.bench_from_frame({**columns, "i_q": columns["i_q"][:-1]}, "short.csv")


def test_fleet_whiteness_equals_the_single_fit_test():
    """The fleet's batched Ljung-Box p-values are the verdict's, series by series."""
    from drivecal.fleet import residual_diagnostics
    from drivecal.diagnose import WHITENESS_ALPHA, ljung_box

    rng = np.random.default_rng(3)
    residuals = rng.standard_normal((5, 300, 2))
    residuals[2, 100:, 0] += np.sin(np.arange(200) / 5.0)  # one coloured series
    start = np.zeros(300, dtype=bool)
    start[[0, 100]] = True
    diag = residual_diagnostics(residuals, start)
    for b in range(5):
        p = [ljung_box(residuals[b, lo:hi, j])[1] for lo, hi in ((0, 100), (100, 300)) for j in (0, 1)]
        assert diag["resid_min_p"][b] == pytest.approx(min(p), rel=1e-9)
        assert diag["mismatch"][b] == (min(p) < WHITENESS_ALPHA / 4)
    assert diag["mismatch"][2]


def test_many_tables_checked_together_as_one_by_one(monkeypatch):
    """benches_from_frames == bench_from_frame per table: the same benches, the same one-sentence errors."""
    from drivecal import data
    from drivecal.data import benches_from_frames

    good = small_frame()
    rng = np.random.default_rng(7)
    frames, sources = [], []
    for k in range(6):  # alike in layout, each with its own noise; one starts moving
        f = good.copy()
        f[["i_d", "i_q"]] += 0.01 * rng.standard_normal((len(f), 2))
        if k == 3:
            f.loc[0, "i_d"] = 5.0
        frames.append(f)
        sources.append(f"good{k}.csv")
    for case, (bad, _) in CASES.items():  # every corruption, most of them laid out as the good ones
        frames.append(bad)
        sources.append(f"{case}.csv")
    frames.append(good.assign(w_m=np.linspace(0.0, 3.0, len(good))))  # another layout, its own group
    sources.append("speed.csv")
    columns = [{c: f[c].to_numpy() for c in f.columns} for f in frames]
    alone_checked = []
    one = data.bench_from_frame
    monkeypatch.setattr(data, "bench_from_frame", lambda frame, source, **kw: alone_checked.append(source)
                        or one(frame, source, **kw))
    together = benches_from_frames(columns, sources, nominal_R=0.45)
    monkeypatch.undo()
    assert not {"good1.csv", "good2.csv", "good3.csv"} & set(alone_checked)  # checked with good0, vectorised
    assert len(together) == len(frames)
    for frame, source, result in zip(columns, sources, together):
        try:
            alone = dc.bench_from_frame(frame, source, nominal_R=0.45)
        except dc.DataError as exc:
            assert isinstance(result, dc.DataError), source
            assert str(result) == str(exc)
            continue
        assert isinstance(result, dc.BenchData), (source, result)
        assert (result.sample_rate, result.source) == (alone.sample_rate, alone.source)
        for a, b in zip(result.segments, alone.segments):
            assert (a.name, a.locked, a.at_rest) == (b.name, b.locked, b.at_rest)
            for field in ("t", "voltages", "currents", "w_m"):
                np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not together[3].segments[0].at_rest and together[0].segments[0].at_rest
    assert sum(isinstance(r, dc.DataError) for r in together) == len(CASES)


@pytest.mark.parametrize("delay", [0, 2])
def test_stacked_experiment_is_the_stack_of_experiments(delay):
    """Built at once for a fleet, or per bench and stacked: the same arrays, the same layout."""
    import jax

    from drivecal.data import stacked_experiment
    from drivecal.model import stack_experiments

    frame = small_frame().assign(w_m=lambda f: np.where(f["locked"] == 1, 0.0, np.linspace(0.0, 5.0, len(f))))
    benches = [dc.bench_from_frame(frame, "a"), dc.bench_from_frame(frame.iloc[5:], "b")]  # b starts moving
    benches.append(dc.bench_from_frame(frame.assign(t=frame["t"] * 1.5), "c"))  # another sample rate
    benches = [b for b in benches if b.num_samples == benches[0].num_samples] + [benches[2]]
    assert not dc.bench_from_frame(frame.iloc[5:], "b").segments[0].at_rest
    for measured in (True, False):
        one_by_one = stack_experiments([b.experiment(measured, delay) for b in benches])
        at_once = stacked_experiment(benches, measured, delay)
        leaves_a, tree_a = jax.tree_util.tree_flatten(one_by_one)
        leaves_b, tree_b = jax.tree_util.tree_flatten(at_once)
        assert tree_a == tree_b
        for a, b in zip(leaves_a, leaves_b):
            assert np.shape(a) == np.shape(b) and np.asarray(a).dtype == np.asarray(b).dtype
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    moving = [dc.bench_from_frame(frame.iloc[5:], "b")] * 2
    np.testing.assert_array_equal(stacked_experiment(moving, True, delay).initial_state[0],
                                  moving[0].experiment(True, delay).initial_state)


def test_parquet_text_columns_read_as_labels(tmp_path):
    """Text columns come back as Python strings (None where null), as pandas would give them."""
    from drivecal.data import read_table

    frame = small_frame(8).assign(serial="SN1")
    frame.loc[3, "segment"] = None
    path = tmp_path / "b.parquet"
    frame.to_parquet(path, index=False)
    for content in (None, path.read_bytes()):
        columns = read_table(path, content)
        assert columns["segment"].dtype == object and columns["serial"].dtype == object
        assert columns["segment"].tolist() == [None if pd.isna(x) else x for x in frame["segment"]]
        assert columns["serial"].tolist() == ["SN1"] * len(frame)
        np.testing.assert_array_equal(columns["i_d"], frame["i_d"].to_numpy())
    frame.drop(columns="serial").to_parquet(path, index=False)  # without the serial column
    assert read_table(path)["segment"].tolist() == [None if pd.isna(x) else x for x in frame["segment"]]


@pytest.mark.parametrize("dialect", [(",", "."), (";", ","), ("\t", ".")], ids=["comma", "semicolon-comma", "tab"])
def test_csv_columns_are_pandas_to_the_bit(tmp_path, dialect):
    """A CSV bench file reads as pandas reads it (Arrow's reader where it agrees): names, dtypes, every bit of
    every number, text as labels (None where empty); a name given twice, a timestamp column and a
    column with no value are read by pandas itself."""
    from drivecal.data import read_table

    sep, decimal = dialect
    rng = np.random.default_rng(7)
    frame = small_frame(40).assign(serial="SN1", i_d=lambda f: f["i_d"] + rng.normal(0.0, 0.02, len(f)))
    frame.loc[5, "segment"] = None
    path = tmp_path / "b.csv"
    frame.to_csv(path, index=False, sep=sep, decimal=decimal, float_format="%.17g")
    expected = pd.read_csv(path, sep=sep, decimal=decimal)
    columns = read_table(path)
    assert list(columns) == list(expected.columns)
    for name in expected.columns:
        want = expected[name].to_numpy()
        if want.dtype.kind == "f":
            assert columns[name].dtype == np.float64
            np.testing.assert_array_equal(columns[name].view(np.int64), want.view(np.int64))
        elif want.dtype.kind in "iub":
            assert columns[name].dtype == want.dtype
            np.testing.assert_array_equal(columns[name], want)
        else:
            assert columns[name].tolist() == [None if pd.isna(x) else x for x in want]
    path.write_text("segment,serial,t\n01,000123,0\n01,000123,1\n")  # text as written, not numbers
    assert read_table(path)["serial"].tolist() == ["000123"] * 2 and read_table(path)["segment"][0] == "01"
    odd = {"twice": "t,i_d,i_d\n0,1.5,2.5\n", "timestamp": "t,i_d\n2026-01-01 00:00:00.5,1\n2026-01-01 00:00:01,2\n",
           "empty": "t,i_d,w_m\n0,1,\n1,2,\n"}
    for text in odd.values():
        path.write_text(text)
        want = dc.data.columns_of(pd.read_csv(path))
        got = read_table(path)
        assert list(got) == list(want)
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])


def test_tables_with_temperature_and_angle_checked_together_as_one_by_one():
    """Temperature and rotor-angle columns take the vectorised path too: the same benches, the same sentences."""
    from drivecal.data import benches_from_frames

    rng = np.random.default_rng(11)
    good = small_frame().assign(temperature=lambda f: np.where(f["segment"] == "d", 40.0, np.nan),
                                theta_e=lambda f: np.linspace(0.0, 3.0, len(f)))
    frames = []
    for k in range(8):
        f = good.copy()
        f[["i_d", "i_q"]] += 0.01 * rng.standard_normal((len(f), 2))
        if k == 2:
            f.loc[4, "temperature"] = np.nan  # blank inside a segment with a temperature
        if k == 3:
            f.loc[70, "locked"] = 1.0  # the free segment's flag changes mid-way
        if k == 4:
            f.loc[f["segment"] == "spin", "locked"] = 1  # locked throughout: a valid, different bench
        if k == 5:
            f.loc[7, "theta_e"] = np.inf
        frames.append({c: f[c].to_numpy() for c in f.columns})
    sources = [f"b{k}.csv" for k in range(len(frames))]
    together = benches_from_frames(frames, sources, nominal_R=0.45)
    for frame, source, result in zip(frames, sources, together):
        try:
            alone = dc.bench_from_frame(frame, source, nominal_R=0.45)
        except dc.DataError as exc:
            assert isinstance(result, dc.DataError) and str(result) == str(exc), source
            continue
        assert isinstance(result, dc.BenchData), (source, result)
        for a, b in zip(result.segments, alone.segments):
            assert (a.name, a.locked, a.at_rest) == (b.name, b.locked, b.at_rest)
            for field in ("t", "voltages", "currents", "temperature", "theta_e"):
                x, y = getattr(a, field), getattr(b, field)
                assert (x is None) == (y is None), (source, field)
                if x is not None:
                    np.testing.assert_array_equal(x, y)
    assert [isinstance(r, dc.DataError) for r in together] == [k in (2, 3, 5) for k in range(8)]
    assert together[4].segments[1].locked and together[0].segments[1].temperature is None
    assert "column 'temperature' is blank or not a number at sample 5" in str(together[2])
