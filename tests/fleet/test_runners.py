"""Where a batch's chunks run: local helper processes (pinned, one core each) and a dask cluster."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from drivecal import fleet
from drivecal.fleet import _runners

MOTOR = dc.load_motor(None)


_WHERE_HELPERS_RUN = """
import json, os, time
from drivecal.fleet import _runners

def where(chunk):
    time.sleep(0.2)  # long enough that both helpers get chunks
    return os.getpid(), sorted(os.sched_getaffinity(0))

rows = dict(_runners._on_local_processes([[k] for k in range(8)], where, workers=2))
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
            tuned = client.run(lambda: __import__("drivecal.fleet._runners", fromlist=["_tuned"])._tuned)
        assert any(tuned.values())
    helped = fleet.run_batch([tmp_path / "in"], tmp_path / "two.parquet", MOTOR, chunk=8, workers=2)
    assert local.total == remote.total == helped.total == 24
    a = pd.read_parquet(tmp_path / "local.parquet")
    for other in ("dask.parquet", "two.parquet"):
        b = pd.read_parquet(tmp_path / other)
        assert a["serial"].tolist() == b["serial"].tolist()
        for name in dc.ESTIMATED:
            np.testing.assert_allclose(a[name], b[name], rtol=1e-10)


def test_chunks_run_here_in_order_with_one_worker():
    """One worker: every chunk in this process, in order; no chunks: nothing runs."""
    seen = []

    def calibrate(paths):
        seen.append(os.getpid())
        return pd.DataFrame({"file": paths})

    rows = list(_runners.run_chunks([["a", "b"], ["c"]], calibrate, workers=1, scheduler=None))
    assert [k for k, _ in rows] == [0, 1] and [t["file"].tolist() for _, t in rows] == [["a", "b"], ["c"]]
    assert seen == [os.getpid()] * 2
    assert list(_runners.run_chunks([], calibrate, workers=4, scheduler=None)) == []
