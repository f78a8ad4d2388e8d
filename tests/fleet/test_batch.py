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
