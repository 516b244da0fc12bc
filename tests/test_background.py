"""The loop the model watcher and the decision guard run in a thread of their own."""

from __future__ import annotations

import logging
import threading

from runtime.background import Background
from tests.waiting import wait_for


def test_a_failing_step_is_logged_and_the_loop_goes_on_until_stopped(caplog):
    steps: list[int] = []
    started: list[str] = []
    intervals: list[float] = [0.001]

    def step() -> None:
        steps.append(len(steps))
        if len(steps) == 2:
            raise RuntimeError("boom")

    def interval() -> float:
        intervals.append(intervals[-1])
        return intervals[-1]

    loop = Background("test-loop", step, interval, logging.getLogger("handover.test"), "test step failed",
                      on_start=lambda: started.append(threading.current_thread().name))
    with caplog.at_level(logging.ERROR, logger="handover.test"):
        loop.start()
        loop.start()  # a second start while it runs: still one thread
        assert wait_for(lambda: len(steps) >= 5, timeout=10.0)
        loop.stop(timeout=5.0)
    assert started == ["test-loop"]
    failures = [r for r in caplog.records if r.getMessage() == "test step failed"]
    assert len(failures) == 1 and failures[0].exc_info[0] is RuntimeError
    assert len(intervals) > len(steps)  # the interval is asked before every wait
    loop.stop(timeout=1.0)  # stopping twice is harmless
    assert all(t.name != "test-loop" for t in threading.enumerate())


def _loop(step, name: str = "test-loop") -> Background:
    return Background(name, step, lambda: 0.0, logging.getLogger("handover.test"), "test step failed")


def test_a_step_failing_the_same_way_every_time_is_one_traceback_and_a_count(caplog):
    """A model folder that fails at every poll (0.01 s at the fastest) wrote a traceback a poll."""
    steps: list[int] = []
    kinds = ["same"] * 30 + ["other"] * 3 + [None] * 5

    def step() -> None:
        steps.append(len(steps))
        kind = kinds[min(len(steps) - 1, len(kinds) - 1)]
        if kind is not None:
            raise OSError(kind)

    loop = _loop(step)
    with caplog.at_level(logging.INFO, logger="handover.test"):
        loop.start()
        assert wait_for(lambda: len(steps) >= len(kinds), timeout=10.0)
        loop.stop(timeout=5.0)
    lines = [(r.getMessage(), r.exc_info is not None and r.exc_info[0] is not None) for r in caplog.records]
    assert lines == [("test step failed", True), ("test step failed 29 more times the same way (OSError: same)", False),
                     ("test step failed", True), ("test step failed 2 more times the same way (OSError: other)", False),
                     ("test step failed: works again", False)]


def test_a_failure_still_repeating_at_stop_is_counted_once(caplog):
    steps: list[int] = []

    def step() -> None:
        steps.append(1)
        raise RuntimeError("always")

    loop = _loop(step)
    with caplog.at_level(logging.INFO, logger="handover.test"):
        loop.start()
        assert wait_for(lambda: len(steps) >= 5, timeout=10.0)
        loop.stop(timeout=5.0)
    messages = [r.getMessage() for r in caplog.records]
    assert messages[0] == "test step failed" and len(messages) == 2
    assert messages[1].startswith("test step failed ") and messages[1].endswith(" more times the same way (RuntimeError: always)")


def test_a_thread_stop_gave_up_on_ends_after_its_step_even_when_started_again():
    """stop() with a step still under way, then start(): the old thread saw the stop signal cleared and
    ran on beside the new one (two watchers polling one folder)."""
    release = threading.Event()
    blocked = threading.Event()
    ran_in: list[str] = []

    def step() -> None:
        ran_in.append(threading.current_thread().ident)
        if not blocked.is_set():
            blocked.set()
            release.wait(10.0)

    loop = _loop(step, "test-restart")
    loop.start()
    assert blocked.wait(10.0)
    first = ran_in[0]
    loop.stop(timeout=0.0)  # gives up: the step still runs
    loop.start()
    release.set()
    assert wait_for(lambda: sum(t.name == "test-restart" for t in threading.enumerate()) == 1, timeout=10.0)
    n = len(ran_in)
    assert wait_for(lambda: len(ran_in) >= n + 5, timeout=10.0)
    assert ran_in[-5:] != [first] * 5 and first not in ran_in[n:]
    loop.stop(timeout=5.0)
