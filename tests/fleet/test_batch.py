"""Reading a batch's chunk: its files are requested from the disk at once, then read."""

from __future__ import annotations

import os

import pytest

import drivecal as dc
from drivecal import fleet
from drivecal.fleet import _batch

MOTOR = dc.load_motor(None)


def test_a_chunk_asks_for_its_files_before_reading_them(tmp_path, monkeypatch):
    """Each chunk's files are requested from the disk at once (posix_fadvise WILLNEED), before the first is read;
    a file that cannot be opened is skipped there and reported by its read as before."""
    if not hasattr(os, "posix_fadvise"):
        pytest.skip("no posix_fadvise on this system")
    fleet.synthetic_fleet(tmp_path / "in", 3, seed=8)
    files = [str(p) for p in fleet.discover([tmp_path / "in"])]
    missing = str(tmp_path / "in" / "gone.parquet")
    events = []
    real_read_table = _batch.read_table

    def advise(fd, offset, length, advice):
        events.append(("advise", os.readlink(f"/proc/self/fd/{fd}") if os.path.exists("/proc/self/fd") else fd,
                       advice))

    def read_table(path, content=None):
        events.append(("read", str(path), None))
        return real_read_table(path, content)

    monkeypatch.setattr(os, "posix_fadvise", advise)
    monkeypatch.setattr(_batch, "read_table", read_table)
    loaded = _batch._load(files + [missing], MOTOR)
    advised = [e for e in events if e[0] == "advise"]
    assert all(e[2] == os.POSIX_FADV_WILLNEED for e in advised)
    if os.path.exists("/proc/self/fd"):
        assert [e[1] for e in advised] == [os.path.realpath(f) for f in files]
    assert len(advised) == len(files)
    assert events.index(("read", files[0], None)) == len(files)  # every request before the first read
    assert [item.bench is not None for item in loaded] == [True, True, True, False]
    assert "No such file" in loaded[-1].reason


@pytest.mark.parametrize("n, chunk, size", [(0, 256, 1), (1, 256, 1), (2, 256, 2), (3, 256, 4), (129, 256, 256),
                                            (200, 128, 128), (256, 256, 256)])
def test_batch_sizes_are_powers_of_two_at_most_a_chunk(n, chunk, size):
    assert _batch._bucket(n, chunk) == size


# --------------------------------------------------------------------------- resuming a run: refusals

def _one_sentence(err, *needles):
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("drivecal: error: ") and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def _snapshot(root):
    return {p: p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _resume(tmp_path, capsys, *extra):
    from drivecal.cli import main

    before = _snapshot(tmp_path)
    with pytest.raises(SystemExit) as info:
        main(["batch", str(tmp_path / "in"), "--out", str(tmp_path / "r.parquet"), "--resume", "--workers", "1",
              *map(str, extra)])
    assert info.value.code == 2
    assert _snapshot(tmp_path) == before  # nothing written
    return capsys.readouterr().err


@pytest.fixture()
def one_motor(tmp_path):
    fleet.synthetic_fleet(tmp_path / "in", 2, seed=3)
    return tmp_path


def test_resume_refuses_a_corrupt_table(one_motor, capsys):
    """Before: pyarrow's 'ArrowInvalid: Parquet magic bytes not found' with a traceback."""
    out = one_motor / "r.parquet"
    out.write_bytes(b"not parquet at all")
    err = _resume(one_motor, capsys)
    _one_sentence(err, str(out), "not a readable Parquet table", "r.parquet.parts/", "choose another --out")


def test_resume_refuses_a_corrupt_part(one_motor, capsys):
    parts = fleet.parts_dir(one_motor / "r.parquet")
    parts.mkdir()
    (parts / "part-000000.parquet").write_bytes(b"PAR1 truncated")
    err = _resume(one_motor, capsys)
    _one_sentence(err, str(parts / "part-000000.parquet"), str(parts), "delete part-000000.parquet",
                  "choose another --out")


def _first_part(tmp_path, motor):
    files = [str(p) for p in fleet.discover([tmp_path / "in"])]
    parts = fleet.parts_dir(tmp_path / "r.parquet")
    parts.mkdir()
    table = fleet.calibrate_files(files[:1], motor, chunk=1)
    table.to_parquet(parts / "part-000000.parquet", index=False)
    return table


def test_resume_refuses_another_motor_file(one_motor, capsys):
    """Before: the second run's motors were added to the first's table: one table, two priors."""
    first = one_motor / "first.toml"
    first.write_text('R = "0.45 ohm"\n')
    other = one_motor / "other.toml"
    other.write_text('R = "0.60 ohm"\n')
    table = _first_part(one_motor, dc.load_motor(first))
    assert (table["motor_sha256"] == _batch.motor_sha256(dc.load_motor(first))).all()
    assert (table["motor_file"] == str(first)).all()
    err = _resume(one_motor, capsys, "--motor", other)
    _one_sentence(err, str(first), str(other), "resume with the same motor file", "start a new --out")
    # the same priors from a file laid out differently are the same motor file
    same = one_motor / "same.toml"
    same.write_text('# the same motor\nR = 0.45\n')
    assert _batch.motor_sha256(dc.load_motor(same)) == _batch.motor_sha256(dc.load_motor(first))


def test_resume_refuses_another_drivecal_version(one_motor, capsys):
    table = _first_part(one_motor, MOTOR)
    part = fleet.parts_dir(one_motor / "r.parquet") / "part-000000.parquet"
    table.assign(drivecal_version="0.0.1").to_parquet(part, index=False)
    err = _resume(one_motor, capsys)
    _one_sentence(err, "drivecal 0.0.1", "resume with drivecal 0.0.1", "start a new --out")


def test_resume_with_the_same_motor_file_goes_on(one_motor):
    _first_part(one_motor, MOTOR)
    summary = fleet.run_batch([one_motor / "in"], one_motor / "r.parquet", MOTOR, chunk=1, workers=1, resume=True)
    assert summary.done_before == 1 and summary.total == 2


@pytest.mark.long
@pytest.mark.slow
def test_a_flagged_motor_is_fitted_again_with_its_effects(tmp_path):
    """In a batch, a motor whose residuals are not white goes through the effect selection (fleet/_effects.py)."""
    import shutil
    from pathlib import Path

    import numpy as np

    examples = Path(__file__).resolve().parents[2] / "examples"
    shutil.copy(examples / "bench.csv", tmp_path / "ideal.csv")
    shutil.copy(examples / "inverter_bench.csv", tmp_path / "inverter.csv")  # delay 1, dead time, offsets
    table = fleet.calibrate_files([str(tmp_path / "ideal.csv"), str(tmp_path / "inverter.csv")],
                                  dc.load_motor(None))
    rows = {Path(f).stem: i for i, f in enumerate(table["file"])}
    assert table["effects"][rows["ideal"]] == ""
    assert set(table["effects"][rows["inverter"]].split(",")) == {"delay", "dead_time", "offsets"}
    assert not table["mismatch"][rows["inverter"]]
    assert abs(table["delay"][rows["inverter"]] - 1.0) < 3 * table["delay_se"][rows["inverter"]]
    assert np.isnan(table["delay"][rows["ideal"]])


def test_a_chunk_s_solve_is_kept_for_the_next_batch_process(tmp_path):
    """A fleet's chunk of 256 fits compiles one solve, which must be kept on disk with its executable (of at most
    ``_setup.MAX_CACHED_OBJECTS`` object files): otherwise every later batch process compiles it again, ~5 s each
    (with XLA's default emitters the chunk's solve had 401 object files, and a warm batch of 1000 motors took
    11 s against 2.3 s)."""
    import pickle
    import subprocess
    import sys
    import zlib

    fleet.synthetic_fleet(tmp_path / "in", 256, seed=3)
    env = {**os.environ, "DRIVECAL_JAX_CACHE": "1", "DRIVECAL_JAX_CACHE_DIR": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-c", "import sys; from drivecal.cli import main; sys.exit(main())",
                           "batch", str(tmp_path / "in"), "--out", str(tmp_path / "results.parquet"), "--workers", "1"],
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    entries = [zlib.decompress(data) for p in (tmp_path / "cache").rglob("solve_batch-*.pkl")
               if (data := p.read_bytes()) != b"not kept"]
    chunk = [e for e in map(pickle.loads, entries) if e[0].in_avals[0].shape[0] == 256]
    assert chunk, "no solve of a chunk of 256 fits was kept"
    assert all(kept is not None for _, _, kept, _ in chunk), "the chunk's solve was kept without its executable"
