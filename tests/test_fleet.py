"""Fleet calibration: planted outliers, corrupt files, kill-and-resume, a dask cluster."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from drivecal import fleet
from drivecal.cli import main

MOTOR = dc.load_motor(None)
DEMAGNETISED = {"lambda_m": 0.85}
SHORTED_TURN = {"R": 0.85, "Ld": 0.85, "Lq": 0.85}


@pytest.fixture(scope="module")
def fleet_500(tmp_path_factory):
    """500 motors (2 % spread) with 5 planted faults, calibrated in-process."""
    root = tmp_path_factory.mktemp("fleet500")
    planted = {17: DEMAGNETISED, 123: SHORTED_TURN, 250: DEMAGNETISED, 333: SHORTED_TURN, 480: DEMAGNETISED}
    truth = fleet.synthetic_fleet(root / "in", 500, outliers=planted, seed=5)
    summary = fleet.run_batch([root / "in"], root / "results.parquet", MOTOR, chunk=256, workers=1)
    return truth, summary, pd.read_parquet(root / "results.parquet")


@pytest.mark.slow
def test_planted_outliers_are_found_exactly(fleet_500):
    truth, summary, table = fleet_500
    assert summary.total == 500 and summary.calibrated == 500 and summary.failed == 0
    planted = set(truth.loc[truth["planted_outlier"], "serial"])
    assert set(summary.outliers) == planted
    flagged = table.set_index("serial")["outlier_params"]
    for serial in planted:
        faults = set(flagged[serial].split(", "))
        assert faults in ({"lambda_m"}, {"R", "Ld", "Lq"}), (serial, faults)


@pytest.mark.slow
def test_fleet_intervals_cover_the_truth(fleet_500):
    """2000 intervals (500 motors x 4 parameters): coverage 95 % within 4 binomial SDs."""
    truth, _, table = fleet_500
    merged = table.merge(truth, on="serial", suffixes=("", "_true"))
    inside = np.concatenate([
        ((merged[f"{n}_ci_low"] <= merged[f"{n}_true"]) & (merged[f"{n}_true"] <= merged[f"{n}_ci_high"])).to_numpy()
        for n in dc.ESTIMATED
    ])
    assert abs(inside.mean() - 0.95) < 4 * np.sqrt(0.95 * 0.05 / inside.size), inside.mean()
    assert merged["mismatch"].mean() < 0.01  # the whiteness test at family-wise 1e-3


def test_corrupt_files_are_recorded_and_the_rest_calibrated(tmp_path, capsys):
    truth = fleet.synthetic_fleet(tmp_path / "in", 13, seed=2)
    good = pd.read_parquet(tmp_path / "in" / "SN000000.parquet").drop(columns=["serial"])
    good.assign(i_d=np.where(np.arange(len(good)) == 40, np.nan, good["i_d"])).to_csv(tmp_path / "in" / "nan.csv",
                                                                                      index=False)
    good.drop(columns=["v_q"]).to_parquet(tmp_path / "in" / "novq.parquet")
    (tmp_path / "in" / "garbage.mat").write_bytes(b"not a mat file at all")
    out = tmp_path / "results.parquet"
    with pytest.raises(SystemExit) as info:
        main(["batch", str(tmp_path / "in"), "--out", str(out), "--chunk", "16", "--workers", "1"])
    assert info.value.code == 1
    assert "completed with failures" in capsys.readouterr().out
    table = pd.read_parquet(out).set_index("serial")
    assert len(table) == 16 and table.index.is_unique
    assert (table.loc[truth["serial"], "status"] == "calibrated").all()
    reasons = table.loc[["nan", "novq", "garbage"], "reason"]
    assert "column 'i_d' has a missing value in data row 41" in reasons["nan"]
    assert "missing column 'v_q'" in reasons["novq"]
    assert "cannot be read as a mat bench file" in reasons["garbage"]
    assert (table.loc[["nan", "novq", "garbage"], "status"] == "invalid file").all()
    assert not fleet.parts_dir(out).exists()


def _batch_process(inputs: Path, out: Path, *extra: str, workers: int = 1) -> subprocess.Popen:
    exe = Path(sys.executable).with_name("drivecal")
    return subprocess.Popen([str(exe), "batch", str(inputs), "--out", str(out), "--chunk", "4", "--workers",
                             str(workers), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_killed_run_resumes_without_losing_or_repeating_a_motor(tmp_path):
    """Killed and resumed on two local processes (a forked helper), it equals one uninterrupted in-process run."""
    fleet.synthetic_fleet(tmp_path / "in", 96, seed=3)
    out = tmp_path / "killed.parquet"
    proc = _batch_process(tmp_path / "in", out, workers=2)
    parts = fleet.parts_dir(out)
    deadline = time.monotonic() + 300
    while not (parts.is_dir() and len(list(parts.glob("part-*.parquet"))) >= 2):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()  # reaps it and closes its pipes
    written = len(list(parts.glob("part-*.parquet")))
    assert not out.exists() and 2 <= written < 24  # killed mid-run

    resumed = _batch_process(tmp_path / "in", out, "--resume", workers=2)
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    whole = _batch_process(tmp_path / "in", tmp_path / "whole.parquet")
    _, err = whole.communicate(timeout=600)
    assert whole.returncode == 0, err

    a = pd.read_parquet(out).sort_values("serial").reset_index(drop=True)
    b = pd.read_parquet(tmp_path / "whole.parquet").sort_values("serial").reset_index(drop=True)
    assert a["serial"].is_unique and len(a) == 96
    assert a["serial"].tolist() == b["serial"].tolist()
    numeric = [c for c in a.columns if a[c].dtype.kind == "f"]
    np.testing.assert_allclose(a[numeric].to_numpy(), b[numeric].to_numpy(), rtol=1e-10, equal_nan=True)
    assert (a["status"] == b["status"]).all()


_WHERE_HELPERS_RUN = """
import json, os, time
from drivecal.fleet import _batch as fleet

def where(chunk):
    time.sleep(0.2)  # long enough that both helpers get chunks
    return os.getpid(), sorted(os.sched_getaffinity(0))

rows = dict(fleet._on_local_processes([[k] for k in range(8)], where, workers=2))
print(json.dumps({"chunks": sorted(rows), "parent": os.getpid(), "helpers": list(rows.values())}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity") or len(os.sched_getaffinity(0)) < 2,
                    reason="needs a system that pins processes, and two cores")
def test_local_helpers_each_run_on_a_core_of_their_own():
    """Two helpers, forked from a fresh process: each pinned to one core, not the same one; the parent computes nothing."""
    import json

    done = subprocess.run([sys.executable, "-c", _WHERE_HELPERS_RUN], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    seen = json.loads(done.stdout.strip().splitlines()[-1])
    assert seen["chunks"] == list(range(8))
    cores_of = {}
    for pid, cores in seen["helpers"]:
        assert cores_of.setdefault(pid, cores) == cores  # a helper stays where it was pinned
    assert seen["parent"] not in cores_of and len(cores_of) == 2
    first, second = cores_of.values()
    assert len(first) == len(second) == 1 and first != second


@pytest.mark.slow
def test_dask_cluster_and_local_processes_give_the_same_table(tmp_path):
    """A dask LocalCluster (--scheduler), and two local helpers, spawned (JAX runs here already)."""
    from distributed import LocalCluster

    fleet.synthetic_fleet(tmp_path / "in", 24, seed=4)
    local = fleet.run_batch([tmp_path / "in"], tmp_path / "local.parquet", MOTOR, chunk=8, workers=1)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = fleet.run_batch([tmp_path / "in"], tmp_path / "dask.parquet", MOTOR, chunk=8,
                                 scheduler=cluster.scheduler_address)
        with cluster.get_client() as client:  # the workers that ran chunks were tuned for batches
            tuned = client.run(lambda: __import__("drivecal.fleet._batch", fromlist=["_tuned"])._tuned)
        assert any(tuned.values())
    helped = fleet.run_batch([tmp_path / "in"], tmp_path / "two.parquet", MOTOR, chunk=8, workers=2)
    assert local.total == remote.total == helped.total == 24
    a = pd.read_parquet(tmp_path / "local.parquet")
    for other in ("dask.parquet", "two.parquet"):
        b = pd.read_parquet(tmp_path / other)
        assert a["serial"].tolist() == b["serial"].tolist()
        for name in dc.ESTIMATED:
            np.testing.assert_allclose(a[name], b[name], rtol=1e-10)


def test_resume_after_parts_finished_out_of_order(tmp_path):
    """Chunks finish out of order, so a killed run can leave part 1 without part 0; resuming keeps it."""
    fleet.synthetic_fleet(tmp_path / "in", 8, seed=6)
    files = [str(p) for p in fleet.discover([tmp_path / "in"])]
    out = tmp_path / "r.parquet"
    parts = fleet.parts_dir(out)
    parts.mkdir()
    fleet.calibrate_files(files[4:], MOTOR, chunk=4).to_parquet(parts / "part-000001.parquet", index=False)
    summary = fleet.run_batch([tmp_path / "in"], out, MOTOR, chunk=4, workers=1, resume=True)
    table = pd.read_parquet(out)
    assert summary.done_before == 4 and summary.total == 8
    assert sorted(table["file"]) == files


def test_existing_results_need_resume(tmp_path, capsys):
    fleet.synthetic_fleet(tmp_path / "in", 1, seed=1)
    out = tmp_path / "r.parquet"
    out.write_bytes(b"old")
    with pytest.raises(SystemExit) as info:
        main(["batch", str(tmp_path / "in"), "--out", str(out)])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "results of an earlier run exist; pass --resume" in err and err.count("\n") == 1
    with pytest.raises(SystemExit):
        main(["batch", str(tmp_path / "nothing-here"), "--out", str(tmp_path / "x.parquet")])
    assert "no bench files" in capsys.readouterr().err


def test_requested_parameters_are_checked_per_motor(tmp_path):
    """With 'estimate' in the motor file, a file whose run cannot show a requested parameter is refused."""
    fleet.synthetic_fleet(tmp_path / "in", 4, seed=7)
    bad = pd.read_parquet(tmp_path / "in" / "SN000003.parquet")
    bad.loc[bad["locked"] == 0, "locked"] = 1  # no free rotor: lambda_m cannot show
    bad.to_parquet(tmp_path / "in" / "SN000003.parquet", index=False)
    motor = tmp_path / "motor.toml"
    motor.write_text('estimate = ["R", "Ld", "Lq", "lambda_m"]\n')
    summary = fleet.run_batch([tmp_path / "in"], tmp_path / "r.parquet", dc.load_motor(motor), chunk=4, workers=1)
    table = pd.read_parquet(tmp_path / "r.parquet").set_index("serial")
    assert summary.failed == 1 and summary.calibrated == 3
    assert table.loc["SN000003", "status"] == fleet.STATUS_INVALID
    assert "lambda_m is requested" in table.loc["SN000003", "reason"]


def test_a_chunk_asks_for_its_files_before_reading_them(tmp_path, monkeypatch):
    """Each chunk's files are requested from the disk at once (posix_fadvise WILLNEED), before the first is read;
    a file that cannot be opened is skipped there and reported by its read as before."""
    if not hasattr(os, "posix_fadvise"):
        pytest.skip("no posix_fadvise on this system")
    fleet.synthetic_fleet(tmp_path / "in", 3, seed=8)
    files = [str(p) for p in fleet.discover([tmp_path / "in"])]
    missing = str(tmp_path / "in" / "gone.parquet")
    events = []
    from drivecal.fleet import _batch

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
