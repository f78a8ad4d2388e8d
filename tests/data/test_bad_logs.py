"""Issue 19: every bad log or format file refused in one sentence naming the file, the channel and the fix;
exit status 2, no traceback, nothing written."""

from __future__ import annotations

import pytest

import drivecal as dc

from helpers.bench_logs import continuous_recording, format_toml, small_frame, units_of, write_hdf5, write_mdf4
from helpers.cli import assert_one_sentence, run_cli


def _small_bench() -> dc.BenchData:
    return dc.bench_from_frame(small_frame(), "small")


@pytest.fixture()
def log(tmp_path):
    """A small MDF4 log of two segments, its windows, and a format file writer."""
    logged, windows = continuous_recording(_small_bench(), rest=10)
    path = write_mdf4(tmp_path / "bench.mf4", logged)
    return path, logged, windows


def _refused(tmp_path, capsys, log_path, fmt_text, *needles):
    fmt = tmp_path / "format.toml"
    fmt.write_text(fmt_text)
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "results"
    code, err = run_cli(["fit", log_path, "--format", fmt, "--out", out], capsys)
    assert_one_sentence(code, err, *needles)
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written


def test_the_good_log_is_read(log):
    path, _, windows = log
    fmt = path.with_suffix(".toml")
    fmt.write_text(format_toml(windows))
    bench = dc.load_bench(path, format=fmt)
    assert [s.name for s in bench.segments] == ["d", "spin"] and [s.num_samples for s in bench.segments] == [60, 60]


def test_a_mapped_channel_that_does_not_exist_names_the_close_matches(log, tmp_path, capsys):
    path, _, windows = log
    text = format_toml(windows).replace('i_q = "Iq"', 'i_q = "Iq_meas"')
    _refused(tmp_path, capsys, path, text, str(path), "channel 'Iq_meas'", "'i_q'", "close matches: 'Iq'",
             "correct [columns] i_q")


def test_channels_of_different_rates_are_named(tmp_path, capsys):
    from asammdf import MDF, Signal

    logged, windows = continuous_recording(_small_bench(), rest=10)
    t = logged["time"]
    mdf = MDF(version="4.10")
    mdf.append([Signal(v, t, name=k, unit=units_of(k)) for k, v in logged.items() if k not in ("time", "n_mech")])
    slow = t[::4]
    mdf.append([Signal(logged["n_mech"][::4], slow, name="n_mech", unit="rpm")])
    path = tmp_path / "rates.mf4"
    mdf.save(str(path), overwrite=True)
    mdf.close()
    _refused(tmp_path, capsys, path, format_toml(windows), str(path), "'n_mech' (w_m) is sampled at 5000 Hz",
             "at 20000 Hz", "one rate")


def test_tdms_waveforms_of_different_rates_are_named(tmp_path, capsys):
    from nptdms import ChannelObject, GroupObject, TdmsWriter

    logged, windows = continuous_recording(_small_bench(), rest=10)
    path = tmp_path / "rates.tdms"
    with TdmsWriter(str(path)) as writer:
        channels = [ChannelObject("g", k, v, properties={"unit_string": units_of(k),
                                                         "wf_increment": 1e-3 if k == "Iq" else 5e-5})
                    for k, v in logged.items() if k != "time"]
        writer.write_segment([GroupObject("g")] + channels)
    _refused(tmp_path, capsys, path, format_toml(windows, t_name=None), str(path), "channel 'Iq' (i_q)",
             "1000 Hz", "20000 Hz")


def test_channels_of_different_lengths_are_named(tmp_path, capsys):
    logged, windows = continuous_recording(_small_bench(), rest=10)
    logged["Iq"] = logged["Iq"][:-7]
    path = write_hdf5(tmp_path / "short.h5", logged)
    _refused(tmp_path, capsys, path, format_toml(windows), str(path), "channel 'Iq' (i_q) has 143 samples",
             "'time' (t) 150", "same span")


def test_an_unknown_unit(log, tmp_path, capsys):
    path, _, windows = log
    text = format_toml(windows).replace('i_d = "mA"', 'i_d = "milliamps"')
    _refused(tmp_path, capsys, path, text, "format.toml", "unknown unit 'milliamps' for 'i_d'", "mA")


def test_a_unit_of_another_quantity(log, tmp_path, capsys):
    path, _, windows = log
    text = format_toml(windows).replace('w_m = "rpm"', 'w_m = "mA"')
    _refused(tmp_path, capsys, path, text, "format.toml", "unit 'mA' for 'w_m' is a current", "rpm")


def test_a_unit_that_contradicts_the_files_own(log, tmp_path, capsys):
    path, _, windows = log
    text = format_toml(windows).replace('i_d = "mA"', 'i_d = "A"')
    _refused(tmp_path, capsys, path, text, str(path), "channel 'Id' is logged in 'mA' by the file",
             "[units] i_d = 'A'", 'set [units] i_d = "mA"')


def test_a_file_unit_with_no_unit_in_the_format_file(log, tmp_path, capsys):
    path, _, windows = log
    text = format_toml(windows).replace('w_m = "rpm"\n', "")
    _refused(tmp_path, capsys, path, text, str(path), "channel 'n_mech' is logged in 'rpm'", "rad/s assumed")


def _windows_text(windows, change):
    edited = [dict(w) for w in windows]
    change(edited)
    return format_toml(edited)


def test_windows_that_overlap(log, tmp_path, capsys):
    path, _, windows = log

    def overlap(w):
        w[1]["start"] = "3 ms"  # the d-step window runs to 3.475 ms

    _refused(tmp_path, capsys, path, _windows_text(windows, overlap), "format.toml", "windows 'd'", "'spin'",
             "overlap")


def test_a_window_outside_the_recording(log, tmp_path, capsys):
    path, _, windows = log

    def late(w):
        w[1]["stop"] = "1 s"

    _refused(tmp_path, capsys, path, _windows_text(windows, late), str(path), "window 'spin'",
             "outside the recording (0 s to 0.0075 s)", "correct its start and stop")


def test_a_window_of_fewer_than_two_samples(log, tmp_path, capsys):
    path, _, windows = log

    def narrow(w):
        w[1]["start"], w[1]["stop"] = "4.01 ms", "4.06 ms"  # one sample, at 4.05 ms (a step is 0.05 ms)

    _refused(tmp_path, capsys, path, _windows_text(windows, narrow), str(path), "window 'spin'", "1 sample(s)",
             "at least two samples")


@pytest.mark.parametrize("edit, needles", [
    (lambda t: t.replace('i_d = "Id"', 'i_dd = "Id"'), ["unknown key 'columns.i_dd'", "the known keys are"]),
    (lambda t: t.replace("[units]", "[unit]"), ["unknown key 'unit'"]),
    (lambda t: t.replace('locked = true', 'locked = true\nclamped = 1', 1), ["unknown key 'segment[0].clamped'"]),
    (lambda t: t.replace('w_m = "rpm"', 'speed = "rpm"'), ["unknown key 'units.speed'"]),
], ids=["column", "table", "window-key", "unit-key"])
def test_a_format_key_drivecal_does_not_know(edit, needles, log, tmp_path, capsys):
    path, _, windows = log
    _refused(tmp_path, capsys, path, edit(format_toml(windows)), "format.toml", *needles)


def test_a_log_without_segment_channel_or_windows(log, tmp_path, capsys):
    path, _, _ = log
    _refused(tmp_path, capsys, path, format_toml([]), str(path), "no segment channel", "drivecal inspect")


def test_a_window_without_locked_and_no_locked_channel(log, tmp_path, capsys):
    path, _, windows = log
    _refused(tmp_path, capsys, path, format_toml(windows).replace("locked = false\n", ""), str(path),
             "window 'spin'", "add locked = true or false")


def test_a_log_that_is_not_one(tmp_path, capsys):
    for name in ("broken.mf4", "broken.tdms", "broken.h5"):
        (tmp_path / name).write_bytes(b"not a log at all" * 10)
        _refused(tmp_path, capsys, tmp_path / name, format_toml([]), name, "cannot be read as", "export it again")
        (tmp_path / name).unlink()


def test_batch_refuses_a_bad_format_file_before_writing_anything(log, tmp_path, capsys):
    path, _, windows = log
    fmt = tmp_path / "format.toml"
    fmt.write_text(format_toml(windows).replace("[units]", "[unit]"))
    before = sorted(p.name for p in tmp_path.iterdir())
    code, err = run_cli(["batch", path, "--format", fmt, "--out", tmp_path / "r.parquet", "--workers", "1"], capsys)
    assert_one_sentence(code, err, "format.toml", "unknown key 'unit'")
    assert sorted(p.name for p in tmp_path.iterdir()) == before
