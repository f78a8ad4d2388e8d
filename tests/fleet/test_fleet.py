"""Fleet calibration: planted outliers, corrupt files, kill-and-resume, the report's outlier band.

Where the chunks run (local helpers, a dask cluster): test_runners.py; reading a chunk: test_batch.py.
"""

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
from drivecal.results import Status

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
    assert "is truncated or not a MAT file" in reasons["garbage"]
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
    assert table.loc["SN000003", "status"] == Status.INVALID.label == "invalid file"
    assert "lambda_m is requested" in table.loc["SN000003", "reason"]


def test_the_report_band_is_drawn_at_the_runs_outlier_z(tmp_path):
    """The histogram band is median ± the run's --outlier-z robust SDs, as the table records it (not the default);
    a table written before the column existed is drawn at the default; a resumed run re-checks at its own z."""
    import matplotlib.pyplot as plt

    fleet.synthetic_fleet(tmp_path / "in", 8, seed=9)
    out = tmp_path / "r.parquet"
    fleet.run_batch([tmp_path / "in"], out, MOTOR, chunk=8, workers=1, outlier_z=3.0)
    table = fleet.load_results(out)
    assert (table["outlier_z"] == 3.0).all()
    values = table["lambda_m"].astype(float)
    centre = float(np.median(values))
    scale = 1.4826 * float(np.median(np.abs(values - centre)))
    for recorded, z in ((table, 3.0), (table.drop(columns="outlier_z"), fleet.DEFAULT_OUTLIER_Z)):
        fig = fleet.fleet_histograms(recorded, ["lambda_m"])
        ax = fig.axes[0]
        band = [p for p in ax.patches if p.get_label().startswith("median ±")]
        assert len(band) == 1
        xs = band[0].get_path().transformed(band[0].get_patch_transform()).vertices[:, 0]
        np.testing.assert_allclose([xs.min(), xs.max()], [centre - z * scale, centre + z * scale], rtol=1e-12)
        assert f"median ± {z:g} robust SD" in [t.get_text() for t in ax.get_legend().get_texts()]
        plt.close(fig)

    again = fleet.run_batch([tmp_path / "in"], out, MOTOR, chunk=8, workers=1, resume=True, outlier_z=4.0)
    assert again.done_before == 8
    rechecked = fleet.load_results(out)
    assert (rechecked["outlier_z"] == 4.0).all()
    flags = ["outlier", "outlier_params", "outlier_z"]
    pd.testing.assert_frame_equal(rechecked.drop(columns=flags), table.drop(columns=flags))  # z-scores unchanged
    z = rechecked[[f"z_{n}" for n in dc.ESTIMATED]].abs()
    assert (rechecked["outlier"] == (z > 4.0).any(axis=1)).all() and (table["outlier"] == (z > 3.0).any(axis=1)).all()


def test_the_old_status_constants_are_the_status_labels():
    """STATUS_* stay exported for one release, as the Status labels (the table's words)."""
    assert (fleet.STATUS_CALIBRATED, fleet.STATUS_PARTIAL, fleet.STATUS_NOT_CONVERGED, fleet.STATUS_INVALID) == (
        "calibrated", "partially calibrated", "not converged", "invalid file")
    assert fleet.STATUS_PARTIAL == Status.PARTIAL.label and Status.from_label(fleet.STATUS_INVALID) is Status.INVALID


def test_every_name_the_fleet_package_lists_loads_on_first_use():
    """``drivecal.fleet`` loads its modules when a name is first asked for (the fleet report needs no JAX): each
    listed name resolves to its module's object, and a name it does not list is an AttributeError."""
    import importlib

    for name in fleet.__all__:
        value = getattr(fleet, name)
        owner = getattr(value, "__module__", None)
        if owner is not None and owner.startswith("drivecal.fleet."):
            assert getattr(importlib.import_module(owner), name) is value
    assert sorted(set(fleet.__all__)) == sorted(fleet.__all__)
    offered = {n for n in dir(fleet) if not n.startswith("_")} - {"annotations", "TYPE_CHECKING"}
    assert offered == set(fleet.__all__)  # the names it loads on use are the names it lists
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        fleet.nope  # noqa: B018
