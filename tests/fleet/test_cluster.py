"""A batch on a dask cluster: losing it ends the run in one sentence and exit status 8, --resume completes it;
a lost cluster is waited for (--reconnect); TLS from dask's own configuration. Every cluster listens on 127.0.0.1."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pandas as pd
import pytest

import drivecal as dc
from drivecal import fleet
from drivecal.cli import main
from drivecal.errors import ClusterLost, DrivecalError
from drivecal.fleet import _cluster
from helpers.cli import run_cli

MOTOR = dc.load_motor(None)
EXIT_CLUSTER_LOST = 8  # docs/exit-statuses.md: the exit status of a batch whose cluster was lost
LOOPBACK = {"127.0.0.1", "::1"}

#: A LocalCluster in a process of its own (its scheduler, and nannies whose workers are child processes),
#: on 127.0.0.1 only: dashboards off, each worker's HTTP server on loopback.
_CLUSTER_SCRIPT = """
import sys, time
from distributed import LocalCluster

if __name__ == "__main__":
    cluster = LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                           scheduler_port=int(sys.argv[1]), dashboard_address=None,
                           worker_dashboard_address="127.0.0.1:0")
    print(cluster.scheduler_address, flush=True)
    while True:
        time.sleep(60)
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def cluster_process(tmp_path):
    """Start a LocalCluster in its own process group: ``start(port=0) -> (process, address)``; all killed after."""
    script = tmp_path / "cluster.py"
    script.write_text(_CLUSTER_SCRIPT)
    started = []

    def start(port: int = 0):
        log = tmp_path / f"cluster-{len(started)}.log"  # dask's own logs, kept out of the CLI's stderr
        with open(log, "w") as stderr:
            process = subprocess.Popen([sys.executable, str(script), str(port)], stdout=subprocess.PIPE,
                                       stderr=stderr, text=True, start_new_session=True)
        started.append(process)
        address = process.stdout.readline().strip()
        assert address.startswith("tcp://127.0.0.1:"), log.read_text()
        return process, address

    yield start
    for process in started:
        try:
            os.killpg(process.pid, signal.SIGKILL)  # the scheduler's process and its workers
        except ProcessLookupError:
            pass
        process.wait()


def _listeners(pids) -> set[str]:
    """The addresses the processes ``pids`` listen on (TCP); at least one (the cluster's own)."""
    import psutil

    found = set()
    for pid in pids:
        try:
            connections = psutil.Process(pid).net_connections(kind="inet")
        except psutil.NoSuchProcess:
            continue
        found |= {c.laddr.ip for c in connections if c.status == psutil.CONN_LISTEN}
    assert found, f"no listening socket found in processes {pids}"
    return found


def _process_tree(pid: int) -> list[int]:
    import psutil

    return [pid] + [p.pid for p in psutil.Process(pid).children(recursive=True)]


def _one_sentence(code, err, *needles):
    assert code == EXIT_CLUSTER_LOST, (code, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("drivecal: error: ") and "Traceback" not in err, err
    assert lines[0].endswith(".") and lines[0].count(". ") == 0, lines[0]  # one sentence
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --------------------------------------------------------------------------- a killed scheduler


@pytest.mark.slow
def test_a_killed_scheduler_ends_the_batch_in_one_sentence_and_resume_completes_it(
        tmp_path, cluster_process, monkeypatch, capsys):
    """The scheduler is killed (SIGKILL) once the first chunk is saved: exit status 8, one sentence (what was lost,
    how many motors are saved, the recovery command); the saved parts are intact; --resume on a new cluster gives
    every motor exactly once, as an uninterrupted local run does (to 1e-9 relative)."""
    from distributed import LocalCluster

    fleet.synthetic_fleet(tmp_path / "in", 8, seed=11)
    out = tmp_path / "results.parquet"
    process, address = cluster_process()
    assert _listeners(_process_tree(process.pid)) <= LOOPBACK

    real_run_batch = fleet.run_batch

    def run_batch(*args, progress, **kwargs):  # the CLI's run, its scheduler killed after its first saved chunk
        def progress_then_kill(done, total):
            progress(done, total)
            if done and process.poll() is None:
                process.kill()
                process.wait()

        return real_run_batch(*args, progress=progress_then_kill, **kwargs)

    monkeypatch.setattr(fleet, "run_batch", run_batch)
    args = ["batch", tmp_path / "in", "--out", out, "--chunk", 2]
    code, err = run_cli(args + ["--scheduler", address], capsys)
    sentence = _one_sentence(code, err, f"lost the dask scheduler at {address}", "restart the scheduler",
                             "the same command with --resume")
    parts = sorted(fleet.parts_dir(out).glob("part-*.parquet"))
    saved = pd.concat([pd.read_parquet(p) for p in parts], ignore_index=True)
    assert 0 < len(saved) < 8 and not out.exists()
    assert f"{len(saved)} of 8 motors are saved in {fleet.parts_dir(out)}/" in sentence
    assert f"calibrate the other {8 - len(saved)}" in sentence
    assert saved["serial"].is_unique and (saved["status"] == "calibrated").all()

    monkeypatch.setattr(fleet, "run_batch", real_run_batch)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tcp",
                      dashboard_address=None) as cluster:
        assert _listeners([os.getpid()]) <= LOOPBACK
        assert main([str(a) for a in args + ["--scheduler", cluster.scheduler_address, "--resume"]]) == 0
    table = pd.read_parquet(out)
    serials = sorted(p.stem for p in (tmp_path / "in").iterdir())
    assert sorted(table["serial"]) == serials and len(serials) == 8  # every motor, exactly once
    assert not fleet.parts_dir(out).exists()
    kept = table.set_index("serial").loc[saved["serial"]]
    for name in dc.ESTIMATED:  # the saved rows are kept as they were
        np.testing.assert_array_equal(kept[name].to_numpy(), saved[name].to_numpy())
    fleet.run_batch([tmp_path / "in"], tmp_path / "local.parquet", MOTOR, chunk=2, workers=1)
    local = pd.read_parquet(tmp_path / "local.parquet").set_index("serial").loc[table["serial"]]
    for name in dc.ESTIMATED:
        np.testing.assert_allclose(table[name].to_numpy(), local[name].to_numpy(), rtol=1e-9)


def test_a_scheduler_that_is_not_there_leaves_nothing_behind(tmp_path, monkeypatch, capsys):
    """Nothing listens at --scheduler: exit status 8 and one sentence, no parts directory; an empty one left by
    an earlier version does not make the next plain run refuse (it gets as far as connecting)."""
    fleet.synthetic_fleet(tmp_path / "in", 2, seed=1)
    monkeypatch.setattr(_cluster, "CONNECT_TIMEOUT", 1.0)
    out = tmp_path / "results.parquet"
    address = f"tcp://127.0.0.1:{_free_port()}"
    args = ["batch", tmp_path / "in", "--out", out, "--scheduler", address]
    code, err = run_cli(args, capsys)
    _one_sentence(code, err, f"cannot connect to the dask scheduler at {address}", "no motor was calibrated",
                  "the same command again")
    assert not fleet.parts_dir(out).exists() and not out.exists()
    fleet.parts_dir(out).mkdir()
    code, err = run_cli(args, capsys)
    _one_sentence(code, err, "cannot connect")
    assert "earlier run" not in err


# --------------------------------------------------------------------------- lost workers, reconnecting


def _chunks(n: int) -> list[list[int]]:
    return [[k] for k in range(n)]


def _slow_sum(values):
    time.sleep(0.1)
    return sum(values)


def test_losing_every_worker_ends_the_batch_unless_one_comes_back_in_time(monkeypatch):
    """Every worker gone: ClusterLost after the wait for workers; with --reconnect, a worker that comes back
    within it finishes the batch, every chunk exactly once."""
    from distributed import LocalCluster

    monkeypatch.setattr(_cluster, "NO_WORKER_WAIT", 1.0)
    monkeypatch.setattr(_cluster, "POLL", 0.2)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tcp",
                      dashboard_address=None) as cluster:
        seen = []
        t0 = time.monotonic()
        with pytest.raises(ClusterLost) as info:
            for k, value in _cluster.on_dask(_chunks(12), _slow_sum, cluster.scheduler_address):
                seen.append(k)
                if len(seen) == 1:
                    cluster.scale(0)
        assert "lost every worker of the dask scheduler" in str(info.value) and "none for 1 s" in str(info.value)
        assert 1 <= len(seen) < 12 and time.monotonic() - t0 < 30

        cluster.scale(1)
        seen = {}
        for k, value in _cluster.on_dask(_chunks(12), _slow_sum, cluster.scheduler_address, reconnect=20):
            seen[k] = seen.get(k, 0) + 1
            assert value == k
            if len(seen) == 1:  # no worker for ~2 s, longer than the wait without --reconnect
                cluster.scale(0)
                comeback = threading.Timer(2.5, cluster.scale, args=(1,))
                comeback.start()
        comeback.join()
        assert seen == {k: 1 for k in range(12)}


def test_a_restarted_scheduler_is_reconnected_to(cluster_process):
    """--reconnect: the scheduler (and its workers) killed and started again on the same address within the
    wait; the chunks not yet handed back are sent again, every chunk exactly once."""
    port = _free_port()
    process, address = cluster_process(port)
    seen = {}
    for k, value in _cluster.on_dask(_chunks(10), sum, address, reconnect=60):
        seen[k] = seen.get(k, 0) + 1
        assert value == k
        if len(seen) == 1:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()
            cluster_process(port)
    assert seen == {k: 1 for k in range(10)}


# --------------------------------------------------------------------------- TLS


def _certificates(directory, ca=None) -> dict[str, str]:
    """A node's key and certificate signed by a cluster CA (made here unless given), with the openssl commands of
    docs/cluster.md: ``{"ca": ..., "cert": ..., "key": ...}`` paths."""
    directory.mkdir(parents=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    if ca is None:
        ca = {"ca": str(directory / "ca.pem"), "ca_key": str(directory / "ca.key")}
        subprocess.run(["openssl", "req", "-x509", *ec, "-days", "2", "-subj", "/CN=drivecal cluster CA",
                        "-keyout", ca["ca_key"], "-out", ca["ca"]], check=True, capture_output=True)
    node = {**ca, "cert": str(directory / "node.pem"), "key": str(directory / "node.key")}
    subprocess.run(["openssl", "req", *ec, "-subj", "/CN=dask node", "-keyout", node["key"],
                    "-out", str(directory / "node.csr")], check=True, capture_output=True)
    subprocess.run(["openssl", "x509", "-req", "-in", str(directory / "node.csr"), "-CA", ca["ca"], "-CAkey",
                    ca["ca_key"], "-CAcreateserial", "-days", "2", "-out", node["cert"]], check=True,
                   capture_output=True)
    return node


def _tls_config(node: dict[str, str]) -> dict[str, object]:
    """dask's configuration of a TLS cluster: every role with ``node``'s certificate, encryption required."""
    config: dict[str, object] = {"distributed.comm.require-encryption": True,
                                 "distributed.comm.tls.ca-file": node["ca"]}
    for role in ("scheduler", "worker", "client"):
        config[f"distributed.comm.tls.{role}.cert"] = node["cert"]
        config[f"distributed.comm.tls.{role}.key"] = node["key"]
    return config


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command to make certificates")
def test_a_tls_cluster_takes_its_certificates_from_dask_configuration(tmp_path, monkeypatch):
    """A TLS LocalCluster on 127.0.0.1 calibrates a batch, its certificates from dask's configuration only; with
    encryption required a tcp:// address is refused, a client with another CA's certificate is refused at the
    handshake, and without certificates in the configuration a tls:// address is refused before connecting."""
    import dask
    from distributed import LocalCluster
    from distributed.security import Security

    node = _certificates(tmp_path / "tls")
    stranger = _certificates(tmp_path / "other")  # another cluster's CA
    fleet.synthetic_fleet(tmp_path / "in", 2, seed=5)
    monkeypatch.setattr(_cluster, "CONNECT_TIMEOUT", 2.0)
    with dask.config.set(_tls_config(node)):
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, host="127.0.0.1", protocol="tls",
                          security=Security(), dashboard_address=None) as cluster:
            address = cluster.scheduler_address
            assert address.startswith("tls://127.0.0.1:")
            assert _listeners([os.getpid()]) <= LOOPBACK
            summary = fleet.run_batch([tmp_path / "in"], tmp_path / "tls.parquet", MOTOR, chunk=2, scheduler=address)
            assert summary.total == summary.calibrated == 2
            with pytest.raises(DrivecalError, match="requires encryption.*tls:// address"):
                fleet.run_batch([tmp_path / "in"], tmp_path / "tcp.parquet", MOTOR, chunk=2,
                                scheduler=address.replace("tls://", "tcp://"))
            foreign_client = {"distributed.comm.tls.client.cert": stranger["cert"],
                              "distributed.comm.tls.client.key": stranger["key"]}
            for config in (_tls_config(stranger), foreign_client):  # neither side, or the scheduler, says no
                with dask.config.set(config), pytest.raises(DrivecalError) as refused:
                    list(_cluster.on_dask(_chunks(2), sum, address))
                assert "do not accept each other's TLS certificates" in str(refused.value)
                assert not isinstance(refused.value, ClusterLost)  # bad input (exit status 2), not a lost cluster
    assert not (tmp_path / "tcp.parquet").exists() and not fleet.parts_dir(tmp_path / "tcp.parquet").exists()
    with pytest.raises(DrivecalError, match=r"no TLS certificates.*distributed\.comm\.tls\.ca-file"):
        fleet.run_batch([tmp_path / "in"], tmp_path / "none.parquet", MOTOR, chunk=2, scheduler=address)
