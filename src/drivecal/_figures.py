"""drivecal's figures rendered to PNG, deterministically, in parallel worker processes.

The figures themselves (``drivecal._figure_kinds``) are built from plain data, so a
figure can be drawn in another process that loads numpy and matplotlib and nothing
of JAX. The reports send their inputs to :class:`FigureRenderer`, which draws them
in up to ``os.cpu_count()`` worker processes while the parent goes on (the figures
of a report cost more than its calibration when drawn one after the other, in one
process).

A figure is deterministic: fixed size and dpi, no ``Software`` metadata in the
PNG, a fixed ``svg.hashsalt``; the same job gives the same bytes in a worker and
in the parent.
"""

from __future__ import annotations

import contextlib
import io
import os
import queue
import threading
from typing import Any, Mapping, Sequence

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from PIL import Image

from ._figure_kinds import FIGURES, plt

#: Environment variable: the number of figure worker processes (0: draw in the calling process).
PROCESSES_ENV = "DRIVECAL_FIGURE_PROCESSES"
#: Seconds a figure may take in a worker before the parent draws it itself.
WORKER_TIMEOUT_S = 120.0
#: Niceness a figure worker adds to its own (Unix): the workers load matplotlib while the command fits, and its fit
#: goes first on the cores (`fit --out` waited ~0.5 s longer for its fit while two workers loaded at its priority).
WORKER_NICENESS = 10
#: A figure worker: lower its priority (where the system has one), then load matplotlib and serve.
WORKER_PROGRAM = ("import os\nif hasattr(os, 'nice'):\n    os.nice(%d)\nfrom drivecal._figures import serve\nserve()"
                  % WORKER_NICENESS)
#: Margin left around a figure's content in its PNG (inches; savefig's default for a tight box).
PAD_IN = 0.1


def png_bytes(fig, dpi: int) -> bytes:
    """The PNG of a matplotlib figure drawn once at ``dpi`` (dots per inch), trimmed to its content; closes the figure.

    One draw on the figure's own canvas (a figure laid out at ``dpi`` keeps the text sizes measured for its
    layout), then the uniform margin around the content is cut to :data:`PAD_IN`: the tight box of
    ``savefig(bbox_inches="tight")``, without its second draw. Where the content reaches an edge of the
    canvas (it may stick out), that ``savefig`` is used instead. An opaque figure is saved as RGB; no
    ``Software`` metadata.
    """
    matplotlib.rcParams["svg.hashsalt"] = "drivecal"
    fig.dpi = dpi
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    canvas.draw()
    rgba = _trimmed(np.asarray(canvas.buffer_rgba()), round(PAD_IN * dpi))
    buf = io.BytesIO()
    if rgba is None:
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight", pad_inches=PAD_IN, metadata={"Software": None})
    else:
        image = Image.fromarray(rgba)
        (image.convert("RGB") if image.getextrema()[3] == (255, 255) else image).save(buf, format="png", dpi=(dpi, dpi))
    plt.close(fig)
    return buf.getvalue()


def _trimmed(rgba: np.ndarray, pad: int) -> np.ndarray | None:
    """An image, shape (rows, columns, 4), cut to its content (what differs from its corner's colour) with ``pad``
    pixels around it; None where the content reaches an edge."""
    pixels = rgba.view(np.uint32)[..., 0]  # one number per pixel: its four bytes
    content = pixels != pixels[0, 0]
    rows, cols = np.flatnonzero(content.any(axis=1)), np.flatnonzero(content.any(axis=0))
    if not rows.size:
        return rgba
    if rows[0] == 0 or cols[0] == 0 or rows[-1] == rgba.shape[0] - 1 or cols[-1] == rgba.shape[1] - 1:
        return None
    return rgba[max(rows[0] - pad, 0):rows[-1] + pad + 1, max(cols[0] - pad, 0):cols[-1] + pad + 1]


def render(name: str, kwargs: Mapping[str, Any], dpi: int) -> bytes:
    """Draw figure ``name`` of :data:`FIGURES` from ``kwargs`` and return its PNG (a worker's job).

    The figure is built at ``dpi`` (dots per inch), so that its layout and its PNG share one renderer.
    """
    with matplotlib.rc_context({"figure.dpi": dpi}):
        fig = FIGURES[name](**kwargs)
    return png_bytes(fig, dpi)


def serve() -> None:
    """A figure worker's loop (``python -c "from drivecal._figures import serve; serve()"``).

    Reads jobs from stdin and writes their PNGs to stdout, each a pickled message after its length
    (8 bytes, big-endian): in ``(name, kwargs, dpi)``, out ``("ok", png)`` or ``("error", text)``.
    Ends at the end of its input.
    """
    import pickle
    import sys

    source, sink = sys.stdin.buffer, sys.stdout.buffer
    _send(sink, pickle.dumps(("ok", _ready())))
    while True:
        message = _receive(source)
        if message is None:
            return
        try:
            reply = ("ok", render(*pickle.loads(message)))
        except Exception as exc:  # noqa: BLE001 - the parent draws it itself and sees the error there
            reply = ("error", f"{type(exc).__name__}: {exc}")
        _send(sink, pickle.dumps(reply))


def _send(stream, payload: bytes) -> None:
    stream.write(len(payload).to_bytes(8, "big") + payload)
    stream.flush()


def _receive(stream) -> bytes | None:
    head = stream.read(8)
    if len(head) < 8:
        return None
    size = int.from_bytes(head, "big")
    payload = stream.read(size)
    return payload if len(payload) == size else None


def _ready() -> bytes:
    """A worker's first work: matplotlib and its fonts loaded before the real figures arrive."""
    fig = plt.figure(figsize=(1, 1))
    fig.text(0.5, 0.5, "0")
    fig.canvas.draw()
    plt.close(fig)
    return b""


def worker_count() -> int:
    """Figure worker processes to use: ``$DRIVECAL_FIGURE_PROCESSES``, else one per core when there are two or more."""
    text = os.environ.get(PROCESSES_ENV, "").strip()
    if text:
        try:
            return max(0, int(text))
        except ValueError:
            return 0
    cores = os.cpu_count() or 1
    return cores if cores >= 2 else 0


class FigureRenderer:
    """Draws figure jobs in worker processes that load numpy and matplotlib, not JAX.

    ``start()`` launches the workers early (they load matplotlib while the caller
    computes); ``submit()`` queues a job and returns it, ``job.result()`` gives
    its PNG bytes. The workers are plain ``python -c`` processes fed through
    pipes (not ``multiprocessing``, which would run the caller's ``__main__``
    again in each). With no workers (one core, ``DRIVECAL_FIGURE_PROCESSES=0``),
    or when a worker fails or stalls, a figure is drawn in this process: the
    bytes are the same either way. Use as a context manager, or call ``close()``.
    """

    def __init__(self, processes: int | None = None):
        self.processes = worker_count() if processes is None else max(0, int(processes))
        self._queue: queue.Queue | None = None
        self._threads: list[threading.Thread] = []
        self._jobs: dict[bytes, _Job] = {}  # by job_key: a figure asked for twice is drawn once

    def start(self) -> "FigureRenderer":
        """Launch the workers (idempotent); each loads matplotlib at once."""
        if self._queue is None and self.processes > 0:
            self._queue = queue.Queue()
            for _ in range(self.processes):
                thread = threading.Thread(target=_feed, args=(self._queue,), daemon=True)
                thread.start()
                self._threads.append(thread)
        return self

    def submit(self, name: str, kwargs: Mapping[str, Any], dpi: int) -> "_Job":
        """Queue figure ``name`` of :data:`FIGURES` drawn at ``dpi``; the job already queued where the same figure
        was asked for before (:func:`job_key`): a report's page and its PNG files share one drawing."""
        key = job_key(name, kwargs, dpi)
        if key is not None and key in self._jobs:
            return self._jobs[key]
        self.start()
        job = _Job(name, dict(kwargs), int(dpi))
        if key is not None:
            self._jobs[key] = job
        if self._queue is not None:
            self._queue.put(job)
        elif job.claim():
            job.done.set()  # no workers: result() draws it here
        return job

    def forget(self) -> None:
        """Drop the jobs kept for reuse: a figure asked for after this is drawn again (a renderer kept for many
        reports would otherwise hold every PNG it drew)."""
        self._jobs.clear()

    def render_all(self, jobs: Sequence[tuple[str, Mapping[str, Any], int]]) -> list[bytes]:
        """PNG bytes of each ``(name, kwargs, dpi)``, drawn in parallel where workers run.

        The caller draws too while it waits, from the end of the list (the workers take from
        its start): never slower than drawing them all here, apart from the cores the workers share.
        """
        pending = [self.submit(*job) for job in jobs]
        for job in reversed(pending):
            if job.claim():
                job.png = render(job.name, job.kwargs, job.dpi)
                job.done.set()
        return [job.result() for job in pending]

    def close(self) -> None:
        """Stop the workers once the queued jobs are done."""
        if self._queue is not None:
            for _ in self._threads:
                self._queue.put(None)
            for thread in self._threads:
                thread.join()
            self._queue, self._threads = None, []

    def __enter__(self) -> "FigureRenderer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()


def job_key(name: str, kwargs: Mapping[str, Any], dpi: int) -> bytes | None:
    """What a figure job draws, as bytes: equal for jobs that give the same PNG; None where its inputs are of a
    kind not spelled out here (such a job is never taken for another).

    Lists and tuples are one kind (the figures read both as sequences); arrays keep their dtype and shape, numbers
    their type and exact value (``repr``), numpy scalars count as the Python number they hold.
    """
    import pickle

    def spelled(x: Any) -> Any:
        if isinstance(x, Mapping):
            return ("map", tuple(sorted((str(k), spelled(v)) for k, v in x.items())))
        if isinstance(x, (list, tuple)) or (isinstance(x, np.ndarray) and x.dtype.hasobject and x.ndim == 1):
            return ("seq", tuple(spelled(v) for v in x))
        if isinstance(x, np.ndarray) and not x.dtype.hasobject:
            return ("array", x.dtype.str, x.shape, x.tobytes())
        if isinstance(x, np.generic):
            return spelled(x.item())
        if x is None or isinstance(x, (bool, int, float, str)):
            return (type(x).__name__, repr(x))
        raise _Unspelled

    try:
        return pickle.dumps((name, int(dpi), spelled(kwargs)))
    except _Unspelled:
        return None


class _Unspelled(Exception):
    """An input :func:`job_key` does not spell out."""


class _Job:
    """A queued figure: its PNG from a worker, or the same figure drawn here where no worker could."""

    def __init__(self, name: str, kwargs: dict, dpi: int):
        self.name, self.kwargs, self.dpi = name, kwargs, dpi
        self.png: bytes | None = None
        self.done = threading.Event()
        self._claimed = threading.Lock()

    def claim(self) -> bool:
        """Take the job (a worker's thread or the caller): True for the first to ask, False after."""
        return self._claimed.acquire(blocking=False)

    def result(self) -> bytes:
        """The PNG bytes (waits for the worker; draws the figure here if the worker gave none)."""
        self.done.wait(WORKER_TIMEOUT_S)
        if self.png is None:
            self.png = render(self.name, self.kwargs, self.dpi)
        return self.png


def _feed(jobs: "queue.Queue[_Job | None]") -> None:
    """One worker's thread: start the worker, then hand it jobs one at a time until ``None``."""
    import pickle
    import subprocess
    import sys

    try:
        proc = subprocess.Popen([sys.executable, "-c", WORKER_PROGRAM],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                env={**os.environ, "PYTHONPATH": _package_parent()})
        ready = _receive(proc.stdout)
    except OSError:
        proc, ready = None, None
    alive = ready is not None
    while True:
        job = jobs.get()
        if job is None:
            break
        if not job.claim():  # the caller drew it while it waited
            continue
        if alive:
            try:
                _send(proc.stdin, pickle.dumps((job.name, job.kwargs, job.dpi)))
                reply = _receive(proc.stdout)
                status, value = pickle.loads(reply) if reply is not None else ("error", "worker ended")
                alive = reply is not None
                if status == "ok":
                    job.png = value
            except (OSError, pickle.PickleError, EOFError):
                alive = False
        job.done.set()  # without a PNG, result() draws it in the caller
    if proc is not None:
        # Every job handed to it has its reply: nothing is lost by ending the worker now, and a worker left
        # to exit on its own spends ~0.2 s tearing matplotlib down, which the caller's close() would wait for.
        with contextlib.suppress(OSError):
            proc.kill()
        proc.wait()
        for stream in (proc.stdin, proc.stdout):
            with contextlib.suppress(OSError):
                stream.close()


def _package_parent() -> str:
    """The folder drivecal is imported from, first on the worker's path (a source tree, not another install)."""
    parent = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rest = os.environ.get("PYTHONPATH", "")
    return parent + (os.pathsep + rest if rest else "")
