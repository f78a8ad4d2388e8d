"""Issue 19: a fleet in one table. One Parquet dataset holding many motors (a file, or a directory of parts)
calibrates to the same results table as one file per motor; bench logs in a batch go through --format."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from drivecal import fleet
from drivecal.cli import main

from helpers.bench_logs import continuous_recording, format_toml, write_mdf4

MOTOR = dc.load_motor(None)
#: Columns that name where a row came from, not what was calibrated.
WHERE = ["file", "file_sha256", "tested_at"]  # where and when the bench wrote each file


@pytest.fixture(scope="module")
def per_motor(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet_dataset")
    fleet.synthetic_fleet(root / "per_motor", 4, seed=11)
    return root


def _same_table(a: pd.DataFrame, b: pd.DataFrame) -> None:
    a = a.drop(columns=WHERE).sort_values("serial").reset_index(drop=True)
    b = b.drop(columns=WHERE).sort_values("serial").reset_index(drop=True)
    pd.testing.assert_frame_equal(a, b, check_exact=False, rtol=1e-12, atol=0)


def test_one_parquet_dataset_of_many_motors_gives_the_table_of_one_file_per_motor(per_motor, capsys):
    root = per_motor
    files = sorted((root / "per_motor").glob("*.parquet"))
    frames = [pd.read_parquet(f) for f in files]
    assert all(f["serial"].nunique() == 1 for f in frames)
    one = fleet.run_batch([root / "per_motor"], root / "one.parquet", MOTOR, workers=1, effects=())
    reference = pd.read_parquet(root / "one.parquet")
    assert one.total == 4 and set(reference["serial"]) == {f"SN{i:06d}" for i in range(4)}

    # One file: all the motors' rows in one table, through the command line.
    pd.concat(frames, ignore_index=True).to_parquet(root / "fleet.parquet", index=False)
    assert main(["batch", str(root / "fleet.parquet"), "--out", str(root / "file.parquet"), "--workers", "1",
                 "--effects", "none", "--json"]) == 0
    capsys.readouterr()
    table = pd.read_parquet(root / "file.parquet")
    assert set(table["file"]) == {str((root / "fleet.parquet").resolve())}
    _same_table(table, reference)

    # A directory of parts, the motors' rows interleaved within a part (as a logger appends them).
    parts = root / "parts"
    parts.mkdir()
    mixed = pd.concat(frames[:3], ignore_index=True)
    order = np.argsort(np.tile(np.arange(len(frames[0])), 3), kind="stable")  # row k of each motor in turn
    mixed.iloc[order].to_parquet(parts / "part-0.parquet", index=False)
    frames[3].to_parquet(parts / "part-1.parquet", index=False)
    fleet.run_batch([parts], root / "parts.parquet", MOTOR, workers=1, effects=())
    _same_table(pd.read_parquet(root / "parts.parquet"), reference)


def test_a_batch_of_bench_logs_reads_them_through_the_format_file(per_motor):
    """MDF4 logs (mA, rpm, one continuous recording) in a batch: the rows of the same motors' drivecal files."""
    root = per_motor
    logs = root / "logs"
    logs.mkdir()
    for f in sorted((root / "per_motor").glob("*.parquet")):  # four: the batch size compiled above
        bench = dc.bench_from_frame(pd.read_parquet(f), str(f))
        logged, windows = continuous_recording(bench, rest=40)
        logged.pop("phi_el")
        write_mdf4(logs / f"{f.stem}.mf4", logged)
    fmt = root / "logs.toml"
    fmt.write_text(format_toml(windows, names={"t": "time", "v_d": "Ud_ref", "v_q": "Uq_ref", "i_d": "Id",
                                               "i_q": "Iq", "w_m": "n_mech"}).replace('theta_e = "deg"\n', ""))
    table = fleet.calibrate_files([str(p) for p in sorted(logs.glob("*.mf4"))], MOTOR, effects=(), format=fmt)
    reference = fleet.calibrate_files([str(p) for p in sorted((root / "per_motor").glob("*.parquet"))], MOTOR,
                                      effects=())
    assert list(table["serial"]) == [f"SN{i:06d}" for i in range(4)]  # no serial channel: the file names
    columns = [c for c in reference.columns if c not in WHERE + ["serial"]]
    pd.testing.assert_frame_equal(table[columns], reference[columns], check_exact=False, rtol=1e-9)


def test_a_dataset_partitioned_by_serial_takes_each_motors_serial_from_its_directory(per_motor):
    root = per_motor
    files = sorted((root / "per_motor").glob("*.parquet"))
    hive = root / "hive"
    for f in files:
        frame = pd.read_parquet(f)
        (hive / f"serial={frame['serial'][0]}").mkdir(parents=True)
        frame.drop(columns="serial").to_parquet(hive / f"serial={frame['serial'][0]}" / "part-0.parquet", index=False)
    table = fleet.calibrate_files([str(p) for p in fleet.discover([hive])], MOTOR, effects=())
    reference = fleet.calibrate_files([str(p) for p in files], MOTOR, effects=())
    assert list(table["serial"]) == [f"SN{i:06d}" for i in range(4)]
    pd.testing.assert_frame_equal(table.drop(columns=WHERE), reference.drop(columns=WHERE), check_exact=False,
                                  rtol=1e-12)
