"""Work ahead of need takes turns: one program at a time, in the order listed, and a compile beside the next
trace once the work is needed (drivecal/model/_ahead.py). What the lowered cache does in its turn is tested in
test_lowered_cache.py."""

from __future__ import annotations

import contextvars
import threading
import time

import pytest

from drivecal.model import _ahead as ahead


def _until(condition, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert condition()


@pytest.fixture(autouse=True)
def no_turn_left():
    """Every test ends with no turn held and no thread waiting (a stuck turn would hang the suite's next test)."""
    yield
    assert ahead._TRACING[0] is None and ahead._AHEAD_IN_TURN[0] is None and not ahead._WAITING
    assert not ahead._EXPECTED


def _waiting_thread(work, mark=None, place=()):
    """A started thread running ``work`` in a context of its own (``mark``: its work ahead of need)."""
    def run():
        ahead._PLACE.set(place)
        ahead._AHEAD.set(mark)
        work()

    thread = threading.Thread(target=contextvars.copy_context().run, args=(run,))
    thread.start()
    return thread


def _in_turn(record, name):
    def work():
        with ahead._turn():
            record.append(name)
            ahead._traced()
    return work


def test_side_by_side_gives_each_job_its_place_and_returns_in_order():
    assert ahead.side_by_side([ahead._PLACE.get] * 3) == [(0,), (1,), (2,)]
    nested = ahead.side_by_side([lambda: ahead.side_by_side([ahead._PLACE.get] * 2)] * 2)
    assert nested == [[(0, 0), (0, 1)], [(1, 0), (1, 1)]]


def test_one_trace_at_a_time_needed_work_first_then_in_the_order_listed():
    mark, order, threads = ahead.AheadOfNeed(), [], []
    with ahead._turn():  # a trace under way while the others queue, in this order
        for name, place, m in (("ahead 2", (2,), mark), ("needed 1", (1,), None), ("ahead 0,5", (0, 5), mark),
                               ("needed 0", (0,), None), ("ahead 0,1", (0, 1), mark)):
            threads.append(_waiting_thread(_in_turn(order, name), m, place))
            _until(lambda: len(ahead._WAITING) == len(threads))
        assert not order
    for thread in threads:
        thread.join(timeout=60)
    assert order == ["needed 0", "needed 1", "ahead 0,1", "ahead 0,5", "ahead 2"]


def test_work_ahead_of_need_compiles_in_its_turn_but_never_holds_up_a_needed_trace():
    mark, order = ahead.AheadOfNeed(), []
    with ahead.ahead_of_need(mark), ahead._turn():
        ahead._traced()  # traced; compiling, and still in its turn
        assert ahead._TRACING[0] is None and ahead._AHEAD_IN_TURN[0] is not None
        other = _waiting_thread(_in_turn(order, "ahead"), mark, (1,))
        needed = _waiting_thread(_in_turn(order, "needed"))
        needed.join(timeout=60)
        assert order == ["needed"]  # a needed program traces beside the compilation
        other.join(timeout=0.3)
        assert other.is_alive()  # the next program ahead of need waits for the compilation
        mark.needed()  # needed now: the compilation no longer holds up the next trace
        other.join(timeout=60)
        assert order == ["needed", "ahead"]


def test_once_needed_a_traced_program_gives_up_its_turn_to_the_next_trace():
    mark = ahead.AheadOfNeed()
    mark.needed()
    with ahead.ahead_of_need(mark), ahead._turn():
        assert ahead._TRACING[0] is not None and ahead._AHEAD_IN_TURN[0] is None
        ahead._traced()
        assert ahead._TRACING[0] is None


def test_compiled_ahead_prepares_in_a_marked_thread_and_waits_for_it_once_needed():
    seen = {}

    def prepare(a, b):
        mark = ahead._AHEAD.get()
        seen.update(args=(a, b), mark=mark, thread=threading.current_thread().name)
        _until(lambda: mark.is_needed)
        seen["needed"] = True

    with ahead.compiled_ahead(prepare, 1, 2):
        _until(lambda: "mark" in seen)
        assert not seen["mark"].is_needed and ahead._AHEAD.get() is None  # the caller's own work: not marked
    assert seen["args"] == (1, 2) and seen["needed"] and seen["thread"] == "drivecal-compile-ahead"


def test_compiled_ahead_leaves_a_failure_to_the_step_that_needs_the_kernel():
    def prepare():
        raise RuntimeError("met later")

    with ahead.compiled_ahead(prepare):
        pass


def test_work_ahead_of_need_waits_for_work_listed_before_it_that_has_not_asked_yet():
    """Threads start in the order listed, but the first job may ask for its turn after the second (more Python
    first): the second waits for it, so that the work listed first (the largest) traces first."""
    mark, order, asked = ahead.AheadOfNeed(), [], threading.Event()

    def first():
        asked.wait(60)  # asks after the second has
        with ahead._turn():
            order.append("first")

    def second():
        with ahead._turn():
            order.append("second")

    def watch_second():
        _until(lambda: len(ahead._WAITING) == 1)
        asked.set()

    with ahead.ahead_of_need(mark):
        watcher = threading.Thread(target=watch_second)
        watcher.start()
        ahead.side_by_side([first, second])
    watcher.join(timeout=60)
    assert order == ["first", "second"] and not ahead._EXPECTED
    with ahead.ahead_of_need(mark):  # nested lists: a job's own jobs are not held up by the job
        assert ahead.side_by_side([lambda: ahead.side_by_side([_in_turn(order, "nested")] * 2)]) == [[None, None]]
    assert order[2:] == ["nested", "nested"] and not ahead._EXPECTED


def test_work_marked_after_first_trace_waits_for_a_needed_program_to_be_traced():
    """``after_first_trace``: nothing traced ahead of need until the caller's own first program is traced (the
    caller's trace would otherwise wait behind the largest of them); then as any work ahead of need."""
    mark, order = ahead.AheadOfNeed(after_first_trace=True), []
    waiting = _waiting_thread(_in_turn(order, "ahead"), mark, (0,))
    _until(lambda: len(ahead._WAITING) == 1)
    waiting.join(timeout=0.3)
    assert waiting.is_alive() and not order  # the turn is free, but no needed program has been traced
    _in_turn(order, "needed")()  # the caller's first program, traced
    waiting.join(timeout=60)
    assert order == ["needed", "ahead"]
    late = ahead.AheadOfNeed(after_first_trace=True)
    late.needed()  # once needed, it waits no more
    _waiting_thread(_in_turn(order, "needed ahead"), late).join(timeout=60)
    assert order[-1] == "needed ahead"


def test_a_program_asked_for_inside_a_turn_does_not_wait_for_the_turn_it_is_in():
    """A trace that asks for another program (concrete arguments, so it is exported too) takes no second
    turn: it would wait for its own."""
    done = []

    def nested():
        with ahead._turn():
            with ahead._turn():
                done.append("inner")
            done.append("outer")

    thread = threading.Thread(target=nested)
    thread.start()
    thread.join(timeout=10)
    assert done == ["inner", "outer"]
