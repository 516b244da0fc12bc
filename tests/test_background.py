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
