"""A batch on a dask cluster: connecting (TLS from dask's own configuration), noticing the cluster's loss,
and waiting a bounded time for it to come back.

The cluster is lost when its scheduler goes (the connection closes, or it stops answering for
:data:`CONNECT_TIMEOUT`), or when it has had no worker for :data:`NO_WORKER_WAIT` (the ``reconnect``
wait, when longer). Without a ``reconnect`` wait that ends the run with :class:`ClusterLost`; with one,
a lost scheduler is waited for (the same address, restarted) and the chunks not yet finished are sent
again. Chunks already handed back stay handed back: the caller has saved them.

Nothing here is drivecal-specific but the sentences: the chunks' work is handed in (``calibrate``).
"""

from __future__ import annotations

import contextlib
import logging
import re
import ssl
import time
from concurrent.futures import CancelledError
from typing import TYPE_CHECKING, Callable, Iterable

from ..errors import ClusterLost, DrivecalError

if TYPE_CHECKING:
    import pandas as pd

#: Seconds one attempt to reach the scheduler may take, and that it may take to answer.
CONNECT_TIMEOUT = 10.0
#: Seconds without any worker after which the workers count as lost (or the ``reconnect`` wait, if longer):
#: a worker restarted by its service manager is back well within it.
NO_WORKER_WAIT = 10.0
#: Seconds between two looks at the cluster while no chunk finishes.
POLL = 1.0

_RECOVER = "see docs/cluster.md"


class _Lost(Exception):
    """The cluster went away while chunks were out: ``what`` (a phrase), ``fix`` (what brings it back);
    ``waited``: the workers were waited for already (a lost scheduler is waited for by reconnecting)."""

    def __init__(self, what: str, fix: str, waited: bool = False):
        super().__init__(what)
        self.what, self.fix, self.waited = what, fix, waited


def on_dask(chunks: list[list[str]], calibrate: Callable, scheduler: str,
            reconnect: float = 0.0) -> Iterable[tuple[int, pd.DataFrame]]:
    """Send every chunk to the workers of the dask scheduler at ``scheduler``; yield ``(index, result)`` as
    each finishes.

    ``reconnect``: seconds to wait for a lost cluster to come back (0: none). Raises :class:`ClusterLost`
    (one sentence: what was lost and how to bring it back) when the scheduler cannot be reached, or the
    scheduler or every worker is lost and does not come back in time; a chunk's own error as it is.
    """
    pending = dict(enumerate(chunks))
    lost: _Lost | None = None
    while pending:
        client = _connect(scheduler, reconnect, lost)
        try:
            with _quiet_client(client):
                for k, result in _collect(client, pending, calibrate, scheduler, max(NO_WORKER_WAIT, reconnect)):
                    del pending[k]
                    yield k, result
        except _Lost as exc:
            if reconnect <= 0 or exc.waited:
                raise _lost(exc, 0.0 if exc.waited else reconnect) from None
            lost = exc  # wait for the scheduler to come back, then send the chunks not yet finished again


def _lost(exc: _Lost, waited: float) -> ClusterLost:
    wait = f", and it did not come back within --reconnect {waited:g} s" if waited > 0 else ""
    return ClusterLost(f"{exc.what}{wait}; {exc.fix}.", lost=exc.what + wait, fix=exc.fix)


def stopped(exc: ClusterLost, saved: int, total: int, where: str) -> ClusterLost:
    """``exc`` as the sentence that ends a batch: what was lost, how many motors are saved (``where``), the
    recovery command."""
    rest = total - saved
    if saved:
        kept = f"{saved} of {total} motors are saved in {where}"
        again = f"then run the same command with --resume to calibrate the other {rest}"
    else:
        kept, again = "no motor was calibrated", "then run the same command again"
    return ClusterLost(f"{exc.lost}; {kept}; {exc.fix}, {again}.", lost=exc.lost, fix=exc.fix, saved=saved,
                       total=total)


def check_address(scheduler: str):
    """The dask ``Security`` to reach ``scheduler`` with, from dask's configuration (``distributed.comm.tls.*``,
    ``distributed.comm.require-encryption``); refused in one sentence where the two do not go together."""
    import dask.config
    from distributed.security import Security

    if "://" in scheduler and scheduler.split("://", 1)[0] not in ("tcp", "tls"):
        raise DrivecalError(f"--scheduler {scheduler}: give the scheduler's address as tls://HOST:PORT (or "
                            "tcp://HOST:PORT on a trusted network), as `dask scheduler` prints it.")
    if dask.config.get("distributed.client.security-loader", None):
        return None  # the configured loader finds the credentials, as dask's Client does
    security = Security()  # dask's configuration: certificates, and whether encryption is required
    tls = scheduler.startswith("tls://")
    if tls and not (security.tls_ca_file and security.tls_client_cert):
        raise DrivecalError(
            f"--scheduler {scheduler}: dask's configuration holds no TLS certificates for a client; set "
            "distributed.comm.tls.ca-file, distributed.comm.tls.client.cert and distributed.comm.tls.client.key "
            "(in ~/.config/dask/distributed.yaml or DASK_DISTRIBUTED__COMM__TLS__... variables; see docs/cluster.md).")
    if security.require_encryption and not tls:
        raise DrivecalError(f"--scheduler {scheduler}: dask's configuration requires encryption "
                            "(distributed.comm.require-encryption); give the scheduler's tls:// address.")
    return security


def _connect(scheduler: str, wait: float, lost: _Lost | None):
    """A client of the scheduler, tried for ``wait`` seconds (at least once); ClusterLost when none answers."""
    from distributed import Client

    security = check_address(scheduler)
    deadline = time.monotonic() + wait
    while True:
        # The client keeps an attempt's timeout for its later connections to the scheduler (dask's connection
        # pool): one attempt may take CONNECT_TIMEOUT, or a busy scheduler would count as lost; within a
        # reconnect wait, no longer than what is left of it.
        attempt = CONNECT_TIMEOUT if wait <= 0 else max(1.0, min(CONNECT_TIMEOUT, deadline - time.monotonic()))
        try:
            with _quiet():
                return Client(scheduler, timeout=f"{attempt}s", security=security)
        except (OSError, TimeoutError) as exc:
            if _tls_refused(exc):
                raise DrivecalError(
                    f"--scheduler {scheduler}: the scheduler and this client do not accept each other's TLS "
                    "certificates; give the client the cluster's CA file (distributed.comm.tls.ca-file) and a "
                    "certificate that CA signed (distributed.comm.tls.client.cert and .key; see docs/cluster.md).") \
                    from None
            if time.monotonic() + 0.5 >= deadline:
                if lost is not None:
                    raise _lost(lost, wait) from None
                within = f" within --reconnect {wait:g} s" if wait > 0 else ""
                what = f"cannot connect to the dask scheduler at {scheduler}{within} ({_reason(exc)})"
                raise _lost(_Lost(what, f"start the scheduler and its workers, or check the address ({_RECOVER})"),
                            0.0) from None
            time.sleep(0.5)
        except (ValueError, TypeError) as exc:  # an address dask cannot read
            raise DrivecalError(f"--scheduler {scheduler}: not an address dask can connect to ({_reason(exc)}); "
                                "give it as tls://HOST:PORT, as `dask scheduler` prints it.") from None


def _collect(client, pending: dict[int, list[str]], calibrate: Callable, scheduler: str,
             worker_wait: float) -> Iterable[tuple[int, pd.DataFrame]]:
    """Submit the pending chunks; yield each as it finishes; raise _Lost when the scheduler or every worker goes."""
    from distributed import wait

    futures = {client.submit(calibrate, paths, pure=False): k for k, paths in pending.items()}
    remaining = set(futures)
    gone = f"lost the dask scheduler at {scheduler}"
    restart = f"restart the scheduler and its workers ({_RECOVER})"
    idle_since = None  # when the cluster was first seen without workers
    while remaining:
        try:
            done, _ = wait(list(remaining), timeout=POLL, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        except CancelledError as exc:  # the futures were cancelled: the client lost the scheduler
            raise _Lost(f"{gone} ({_cancelled(exc)})", restart) from None
        except OSError as exc:
            raise _Lost(f"{gone} ({_reason(exc)})", restart) from None
        for future in sorted(done, key=futures.__getitem__):
            remaining.discard(future)
            yield futures[future], _result(future, pending[futures[future]], gone, restart)
        if done:
            continue
        if client.status != "running":
            raise _Lost(f"{gone} (the connection to it closed)", restart)
        try:
            workers = client.nthreads(callback_timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError) as exc:
            raise _Lost(f"{gone} (it did not answer: {_reason(exc)})", restart) from None
        if workers:
            idle_since = None
        elif idle_since is None:
            idle_since = time.monotonic()
        elif time.monotonic() - idle_since >= worker_wait:
            raise _Lost(f"lost every worker of the dask scheduler at {scheduler} (none for {worker_wait:g} s)",
                        f"start its workers again ({_RECOVER})", waited=True)


def _result(future, paths: list[str], gone: str, restart: str):
    """A finished chunk's result; _Lost where the cluster lost it; the chunk's own error as it is."""
    from distributed import KilledWorker

    if future.status == "error":
        error = future.exception()
        if isinstance(error, KilledWorker):
            raise _Lost(f"the chunk of {len(paths)} motors from {paths[0]} ended every worker that ran it "
                        f"({_reason(error)})", "check the workers' memory and logs, restart them", waited=True)
        return future.result()  # the chunk's own exception, raised here
    try:
        return future.result()
    except CancelledError as exc:
        raise _Lost(f"{gone} ({_cancelled(exc)})", restart) from None
    except OSError as exc:
        raise _Lost(f"{gone} ({_reason(exc)})", restart) from None


def _tls_refused(exc: BaseException) -> bool:
    """Whether a failed connection is a TLS handshake that failed (a certificate not accepted), not an absent peer."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, ssl.SSLError) or type(seen).__name__ == "FatalCommClosedError":
            return True
        seen = seen.__cause__ or seen.__context__
    return False


def _cancelled(exc: BaseException) -> str:
    """Why dask cancelled futures, as a phrase: the lost connection, or dask's own words."""
    return "the connection to it closed" if "connection-lost" in str(exc) else _reason(exc)


def _reason(exc: BaseException) -> str:
    """An exception as a short phrase on one line: a closed connection says so, without dask's connection objects."""
    if isinstance(exc, ConnectionError) or type(exc).__name__ == "CommClosedError":
        return "the connection to it closed"
    text = re.sub(r"in <[^>]*>: ", "", " ".join(str(exc).split())) or type(exc).__name__
    text = re.sub(r"Timed out trying to connect to \S+ after (\S+) s", r"no answer in \1 s", text)
    text = text.split(". ")[0].rstrip(".")  # dask's first sentence: drivecal's stays one
    return text if len(text) <= 160 else text[:157] + "..."


@contextlib.contextmanager
def _quiet():
    """dask's loggers (each with its level, from dask's configuration) log nothing while drivecal tells what
    happened in its own sentence."""
    names = ["distributed"] + [n for n in logging.Logger.manager.loggerDict if n.startswith("distributed.")]
    loggers = [logging.getLogger(n) for n in names]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for logger, level in zip(loggers, levels):
            logger.setLevel(level)


@contextlib.contextmanager
def _quiet_client(client):
    """Use ``client``, then close it; a lost connection's messages and its close are not logged."""
    try:
        yield client
    finally:
        with _quiet():
            with contextlib.suppress(Exception):
                client.close(timeout=2)
