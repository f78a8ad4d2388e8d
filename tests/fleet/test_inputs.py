"""A batch's inputs (drivecal/fleet/_inputs.py): the files named on the command line, found and ordered."""

from __future__ import annotations

import os
from pathlib import Path

from drivecal import fleet
from drivecal.fleet._inputs import discover_paths


def test_the_files_are_found_once_and_in_path_order(tmp_path):
    """Directories (recursively, with files of other kinds left out), single files and glob patterns; a file named
    twice counts once; the order is ``Path``'s, component by component (``a/b`` before ``a-b``, which a string
    sort puts first), and the strings are the paths."""
    names = ["a/SN2.csv", "a/SN10.parquet", "a-b/SN1.csv", "a/sub/SN3.mat", "a/notes.txt", "ab.csv"]
    for name in names:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("x")
    inputs = [tmp_path / "a", tmp_path / "a-b" / "SN1.csv", str(tmp_path / "a*.csv"), tmp_path / "a" / "SN2.csv"]
    found = discover_paths(inputs)
    root = str(tmp_path.resolve())
    expected = sorted({os.path.join(root, n) for n in names if not n.endswith(".txt")}, key=lambda p: Path(p))
    assert found == expected
    assert found.index(os.path.join(root, "a", "sub", "SN3.mat")) < found.index(os.path.join(root, "a-b", "SN1.csv"))
    assert fleet.discover(inputs) == [Path(p) for p in expected]
