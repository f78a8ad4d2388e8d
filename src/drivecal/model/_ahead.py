"""Turns to trace and compile: one program traces at a time, and work done ahead of need gives way.

Tracing is Python and holds the GIL; XLA releases it while it compiles. Several programs traced at once
take as long in all as one after the other, and each is ready later: a cold ``drivecal demo`` traced its
two designs' six score-test kernels at once, each trace taking 2.2 s where one alone takes 0.8 s. So a
program is traced in a turn (:func:`_turn`): one at a time, and it compiles once traced, beside the next
trace. ``model._lowered_cache`` takes the turns where it traces and compiles a program.

A first fit compiles its score tests' kernels in a thread beside its own (:func:`compiled_ahead`). That
work is marked ahead of need (:func:`ahead_of_need`) and gives way: it traces only when no program that is
needed now waits to, and it compiles one program at a time, holding its turn through the compilation,
until the work is needed (:meth:`AheadOfNeed.needed`). Among the threads waiting, the one first in the
listed order of the work goes first (:func:`side_by_side`): work is listed largest first.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import contextvars
import threading
from typing import Any, Callable


class AheadOfNeed:
    """The mark of work done ahead of need (:func:`ahead_of_need`), until :meth:`needed` says it is needed now."""

    def __init__(self, *, after_first_trace: bool = False) -> None:
        self.is_needed = False
        #: Whether the work waits to trace until a program needed now has been traced since it was marked.
        self.after_first_trace = after_first_trace
        self.needed_traces = _NEEDED_TRACES[0]

    def needed(self) -> None:
        """The work is needed now: its programs trace in turns as any other, each compiling beside the next trace.

        A first fit's score-test kernels, traced and compiled ahead one at a time beside its base fit, were
        still queued when the fit was done, and the selection waited for them one after the other on one
        core (a cold ``drivecal fit examples/bench.csv``: from 2.4 to 5.6 s).
        """
        with _TURNS:
            self.is_needed = True
            if _AHEAD_IN_TURN[0] is not None and _AHEAD_IN_TURN[0][1] is self:
                _AHEAD_IN_TURN[0] = None
            _TURNS.notify_all()


#: The mark of work done ahead of need in this context (:func:`ahead_of_need`), or None.
_AHEAD: contextvars.ContextVar[AheadOfNeed | None] = contextvars.ContextVar("drivecal_ahead_of_need", default=None)
#: This context's place in the work listed (:func:`side_by_side` appends the job's index).
_PLACE: contextvars.ContextVar[tuple] = contextvars.ContextVar("drivecal_place", default=())
_TURNS = threading.Condition()
#: The token of the thread tracing now (:func:`_turn`), or None.
_TRACING: list = [None]
#: The (token, mark) of the thread whose work ahead of need holds its turn (tracing, then compiling), or None.
_AHEAD_IN_TURN: list = [None]
#: The threads waiting for a turn: (their place in the work, a number of their own, their mark or None).
_WAITING: list[tuple[tuple, int, AheadOfNeed | None]] = []
#: This thread's turn token (:func:`_turn`), or None.
_TURN_HELD = threading.local()
#: How many programs needed at once have been traced in this process (``AheadOfNeed.after_first_trace``).
_NEEDED_TRACES = [0]
#: The places of jobs ahead of need listed (:func:`side_by_side`) whose threads have not yet asked for a turn
#: nor ended: a thread ahead of need listed later waits for them (threads start in order, but a job that asks
#: later, after more Python, could lose its turn to one listed after it).
_EXPECTED: list[tuple] = []


def _is_needed(mark: AheadOfNeed | None) -> bool:
    return mark is None or mark.is_needed


def _order(waiting: tuple) -> tuple:
    """Who goes first: work needed now, then in the listed order."""
    return (not _is_needed(waiting[2]), waiting[0], waiting[1])


def _may_go(waiting: tuple) -> bool:
    if _TRACING[0] is not None or min(map(_order, _WAITING)) != _order(waiting):
        return False
    if _is_needed(waiting[2]):
        return True
    # ahead of need: not before work listed earlier whose thread has not yet asked (it may be the largest)
    mark = waiting[2]
    return (_AHEAD_IN_TURN[0] is None and not any(place < waiting[0] for place in _EXPECTED)
            and not (mark.after_first_trace and _NEEDED_TRACES[0] == mark.needed_traces))


@contextlib.contextmanager
def ahead_of_need(mark: AheadOfNeed | None = None):
    """Mark the calls in this context as work done ahead of need (a first fit's later kernels, compiled beside it).

    Such calls load kept programs at once, side by side, but trace only where no program needed now
    waits to, and trace and compile one program at a time across all such threads: several traces
    beside the caller's own starve it (a cold ``drivecal fit examples/bench.csv``: its base fit's
    first kernel ready at 15 s with five threads tracing beside it, at 4 s with one). Threads started
    inside inherit the mark where they run in a copy of the context (``contextvars.copy_context().run``).
    ``mark``: the caller's, to say when the work is needed (:meth:`AheadOfNeed.needed`); default: the
    enclosing context's, else a new one. Yields the mark.
    """
    mark = mark or _AHEAD.get() or AheadOfNeed()
    token = _AHEAD.set(mark)
    try:
        yield mark
    finally:
        _AHEAD.reset(token)


@contextlib.contextmanager
def compiled_ahead(prepare: Callable[..., Any], *args: Any, after_first_trace: bool = False):
    """Run ``prepare(*args)`` (compiling a later step's kernels) in a thread during the block, and wait for it.

    XLA releases the GIL while it compiles: a first fit compiles its own kernels and its score tests'
    side by side, the score tests' ahead of need (:func:`ahead_of_need`) until the block ends; what is
    left then is needed at once (:meth:`AheadOfNeed.needed`). ``after_first_trace``: the work traces
    nothing until the block has traced a program of its own (where the block's first program is on
    its path and traces soon: a fit's sensitivity kernel, which would otherwise wait for the largest
    score test's trace, ~1 s). A failure in it is left for the later step to meet and report.
    """
    with ahead_of_need(AheadOfNeed(after_first_trace=after_first_trace)) as mark:
        def run() -> None:
            with contextlib.suppress(Exception):  # met and reported by the step that needs the kernel
                prepare(*args)

        thread = threading.Thread(target=contextvars.copy_context().run, args=(run,), name="drivecal-compile-ahead",
                                  daemon=True)
    thread.start()
    try:
        yield
    finally:
        mark.needed()
        thread.join()


@contextlib.contextmanager
def _turn():
    """Wait for this thread's turn to trace a program (the rules: this module's docstring); the turn ends
    with the block, or at :func:`_traced` where the work is needed now."""
    if getattr(_TURN_HELD, "token", None) is not None:  # a program asked for inside this thread's own turn
        yield
        return
    mark, token = _AHEAD.get(), object()
    with _TURNS:
        waiting = (_PLACE.get(), id(token), mark)
        _WAITING.append(waiting)
        _arrived(waiting[0])
        while not _may_go(waiting):
            _TURNS.wait()
        _WAITING.remove(waiting)
        _TRACING[0] = _TURN_HELD.token = token
        if not _is_needed(mark):
            _AHEAD_IN_TURN[0] = (token, mark)
    try:
        yield
    finally:
        _end_turn()


def _traced() -> None:
    """This thread's program is traced and lowered; it compiles now, while the next program traces (work
    ahead of need keeps its turn through the compilation, until it is needed). Counts a needed program's
    trace (``AheadOfNeed.after_first_trace``)."""
    with _TURNS:
        if _TRACING[0] is not None and _TRACING[0] is getattr(_TURN_HELD, "token", None):
            _TRACING[0] = None
            if _is_needed(_AHEAD.get()):
                _NEEDED_TRACES[0] += 1
            _TURNS.notify_all()


def _end_turn() -> None:
    """Give up this thread's turn (:func:`_turn`), what is left of it."""
    token = getattr(_TURN_HELD, "token", None)
    with _TURNS:
        if token is not None and _TRACING[0] is token:
            _TRACING[0] = None
        if token is not None and _AHEAD_IN_TURN[0] is not None and _AHEAD_IN_TURN[0][0] is token:
            _AHEAD_IN_TURN[0] = None
        _TURNS.notify_all()
    _TURN_HELD.token = None


def side_by_side(jobs: list[Callable[[], Any]]) -> list:
    """``[job() for job in jobs]``, each in a thread of its own, in a copy of the caller's context (its
    :func:`ahead_of_need` mark): kernels compile and load side by side (XLA releases the GIL); the
    numbers are those of one after the other. Each job has its place in the list: the threads waiting
    for a turn to trace go in the order listed (:func:`_turn`)."""
    ahead, places = not _is_needed(_AHEAD.get()), [_PLACE.get() + (k,) for k in range(len(jobs))]

    def placed(place: tuple, job: Callable[[], Any]) -> Any:
        _PLACE.set(place)
        try:
            return job()
        finally:
            with _TURNS:
                _arrived(place)
                _TURNS.notify_all()

    if ahead:
        with _TURNS:
            _arrived(_PLACE.get())  # a job listing work of its own: its jobs are what is expected now
            _EXPECTED.extend(places)
    with concurrent.futures.ThreadPoolExecutor(len(jobs)) as pool:
        return [done.result() for done in [pool.submit(contextvars.copy_context().run, placed, place, job)
                                           for place, job in zip(places, jobs)]]


def _arrived(place: tuple) -> None:
    """The job at ``place`` has asked for a turn or ended: no longer expected (:data:`_EXPECTED`)."""
    if place in _EXPECTED:
        _EXPECTED.remove(place)


#: Whether the calls in this context only get their programs ready (:func:`outputs_unused`).
_OUTPUTS_UNUSED: contextvars.ContextVar[bool] = contextvars.ContextVar("drivecal_outputs_unused", default=False)


@contextlib.contextmanager
def outputs_unused():
    """Programs called in this context through the on-disk cache (``model.cached_call``) are made ready (loaded,
    or traced and compiled) and none whose compiled kernel is at hand runs: zeros of its outputs' shapes and
    dtypes are returned.

    For work whose results are discarded, done only so that the kernels are ready when needed (a fit's score
    tests compiled ahead beside it): a warm ``drivecal fit examples/bench.csv`` ran each of its six kernels
    once more for nothing. Threads started inside inherit it where they run in a copy of the context.
    """
    token = _OUTPUTS_UNUSED.set(True)
    try:
        yield
    finally:
        _OUTPUTS_UNUSED.reset(token)
