"""Where a batch's chunks run: in this process, in local helper processes, or on a dask cluster.

A batch process is tuned once for the long run (:func:`tune_for_batch`). Local
helpers take chunks from one queue, each pinned to a core of its own when there
are enough; they are forked while JAX has not started in this process, else
spawned, and die with it. A dask scheduler's workers are tuned on their first
chunk; reaching the cluster, and noticing its loss, is ``_cluster``'s. The
chunks' work itself (``calibrate``) is handed in: this module knows nothing of
bench files or fits.
"""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING, Callable, Iterable

from ._cluster import on_dask

if TYPE_CHECKING:
    import pandas as pd

# --------------------------------------------------------------------------- the process


_tuned = False


def tune_for_batch() -> None:
    """Tune this process for a long batch; call it once the modules are imported, before JAX starts.

    - The objects loaded so far (JAX, drivecal: millions) leave the garbage collector's view
      (``gc.freeze``): its full collections walked them all, ~3 % of a batch's CPU.
    - Freed memory is reused, not returned to the system (:func:`_keep_freed_memory`).

    Once per process; later calls do nothing.
    """
    import gc

    global _tuned
    if _tuned:
        return
    _tuned = True
    gc.freeze()
    _keep_freed_memory()


def _in_dask_worker() -> bool:
    """Whether this code runs as a task of a dask worker (a process that only runs batches)."""
    if "distributed" not in sys.modules:  # not imported: certainly not a worker (and importing it costs)
        return False
    try:
        sys.modules["distributed"].get_worker()
    except (AttributeError, ValueError):
        return False
    return True


def _keep_freed_memory() -> bool:
    """Let this process reuse the memory it frees instead of returning it to the system (glibc only).

    Each chunk's fit allocates ~120 MB of temporaries, and glibc hands blocks that large out as fresh
    mappings (from the threads XLA computes on): every page then faults on first touch, ~120 faults
    and ~0.25 ms of system time a motor. With one malloc arena, no mappings and a high trim threshold,
    the next chunk reuses the same pages (faults a third, system time half). Takes effect for threads
    started afterwards (JAX's); returns whether it applied.
    """
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (macOS, musl): nothing to tune
        return False
    m_trim_threshold, m_mmap_max, m_arena_max = -1, -4, -8
    return all(mallopt(option, value) == 1
               for option, value in ((m_arena_max, 1), (m_mmap_max, 0), (m_trim_threshold, 1 << 30)))


def tune_if_dask_worker() -> None:
    """Tune this process for batches if it is a dask worker not yet tuned (called as a chunk starts).

    A dask worker runs batches only: tuned as local helpers are, on its first chunk (10 000 motors
    on a 2-worker LocalCluster: 14.0 s untuned, 10.9 s tuned; medians of 3, interleaved).
    """
    if not _tuned and _in_dask_worker():
        tune_for_batch()


# --------------------------------------------------------------------------- the chunks


def run_chunks(
    chunks: list[list[str]],
    calibrate: Callable[[list[str]], pd.DataFrame],
    workers: int | None,
    scheduler: str | None,
    reconnect: float = 0.0,
) -> Iterable[tuple[int, pd.DataFrame]]:
    """Yield ``(chunk index, calibrate(chunk))`` as chunks finish: here, in local helpers, or on dask workers.

    ``calibrate`` must pickle (a module-level function, or a ``functools.partial`` of one) to run elsewhere.
    On a dask cluster (``scheduler``), :class:`drivecal.errors.ClusterLost` ends the run when the scheduler
    or every worker is lost and does not come back within ``reconnect`` seconds (``_cluster.on_dask``).
    """
    if not chunks:
        return
    if scheduler is not None:
        yield from on_dask(chunks, calibrate, scheduler, reconnect)
        return
    workers = min(workers or len(_allowed_cores()) or os.cpu_count() or 1, len(chunks))
    if workers <= 1:
        for k, paths in enumerate(chunks):
            yield k, calibrate(paths)
        return
    yield from _on_local_processes(chunks, calibrate, workers)


def _on_local_processes(chunks: list[list[str]], calibrate: Callable, workers: int) -> Iterable[tuple[int, pd.DataFrame]]:
    """``workers`` helper processes take chunks from one queue, each the next as it finishes; this one saves.

    The helpers are forked from this process while JAX has not started here (a fork then copies the
    imported modules, not threads), else spawned; each loads the compiled fit from the persistent cache
    and keeps it for its next chunks. When there are no more helpers than cores, each is pinned to a
    core of its own (:func:`_worker_started`). They die with this process (Linux), so a killed run
    leaves none. This process only hands out chunks and saves their rows: JAX never starts in it.
    """
    import multiprocessing
    import queue
    import threading
    from concurrent.futures import ProcessPoolExecutor

    try:
        from jax._src.xla_bridge import backends_are_initialized
    except ImportError:  # another JAX: assume it runs here, and spawn
        def backends_are_initialized() -> bool:
            return True

    todo, lock, finished, stop = iter(enumerate(chunks)), threading.Lock(), queue.Queue(), threading.Event()

    def take():
        with lock:
            return None if stop.is_set() else next(todo, None)

    context = multiprocessing.get_context("spawn" if backends_are_initialized() else "fork")
    cores = _cores_to_pin(workers)
    started = context.Value("i", 0)  # helpers started so far: the next one takes cores[started]
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_started,
                             initargs=(cores, started)) as pool:

        def feed(_done=None) -> None:
            """Hand a helper its next chunk (called again as each of its chunks finishes)."""
            item = take()
            if item is not None:
                pool.submit(calibrate, item[1]).add_done_callback(lambda f, k=item[0]: (finished.put((k, f)), feed()))

        try:
            for _ in range(workers):
                feed()
            for _ in chunks:
                k, future = finished.get()
                yield k, future.result()
        finally:
            stop.set()  # on an error or interrupt, no helper starts another chunk


def _allowed_cores() -> list[int]:
    """The cores this process may run on (its affinity); empty where the system does not say (not Linux)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:
        return []


def _cores_to_pin(workers: int) -> tuple[int, ...]:
    """The cores local helpers are pinned to, one each; none when there are more helpers than cores.

    Two processes fitting chunks side by side on this 2-core machine took 1.36 ms a motor each pinned
    and 1.56 ms left to the scheduler (medians of six). XLA sizes its thread pool by the cores it may
    use, so a pinned helper's threads no longer wait on each other across cores (pinning only those
    threads gave 1.44 ms), and the helper keeps its core's caches.
    """
    cores = _allowed_cores()  # none known (not Linux): no pinning
    return tuple(cores[:workers]) if workers <= len(cores) else ()


def _worker_started(cores: tuple[int, ...] = (), started=None) -> None:
    """A local helper process: pinned to its core (before JAX starts its threads, which inherit it),
    dies with the batch (Linux), tuned as the batch is."""
    import ctypes
    import signal

    if cores and started is not None:
        with started.get_lock():
            index, started.value = started.value, started.value + 1
        os.sched_setaffinity(0, {cores[index % len(cores)]})
    try:
        pr_set_pdeathsig = 1
        ctypes.CDLL(None).prctl(pr_set_pdeathsig, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux
        pass
    tune_for_batch()  # a forked helper inherits this process's tuning (frozen objects, malloc settings): no-op
