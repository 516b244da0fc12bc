"""A step repeated in a daemon thread of its own, which outlives any step that fails.

The model watcher and the decision guard each run one: a step that raises is logged and the loop
goes on, since a watcher that dies silently leaves the daemon unguarded without a word.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

__all__ = ["Background"]


class Background:
    """Calls ``step()`` every ``interval()`` seconds (asked again before each wait) from ``start`` until
    ``stop``; ``on_start`` runs first in the thread. A step's exception is logged as ``failed`` on ``log``
    with its traceback once; the same failure again is only counted (a step failing at every poll wrote a
    traceback a poll), and the count is said when the step works again, fails another way or stops."""

    def __init__(self, name: str, step: Callable[[], None], interval: Callable[[], float], log: logging.Logger,
                 failed: str, on_start: Callable[[], None] | None = None) -> None:
        self.name = name
        self.step = step
        self.interval = interval
        self.log = log
        self.failed = failed
        self.on_start = on_start
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start the thread; a second start while it runs does nothing. Each start has a stop signal of its
        own: a thread ``stop`` gave up waiting for (a step still under way) ends after that step."""
        if self._thread is not None:
            return
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(self._stop,), name=self.name, daemon=True)
        self._thread.start()

    def _run(self, stop: threading.Event) -> None:
        if self.on_start is not None:
            self.on_start()
        failing: str | None = None
        repeats = 0
        while not stop.wait(self.interval()):
            try:
                self.step()
            except Exception as exc:
                text = f"{type(exc).__name__}: {exc}"
                if text == failing:
                    repeats += 1
                    continue
                self._say_repeats(failing, repeats)
                failing, repeats = text, 0
                self.log.exception(self.failed)
                continue
            if failing is not None:
                self._say_repeats(failing, repeats)
                self.log.warning("%s: works again", self.failed)
                failing, repeats = None, 0
        self._say_repeats(failing, repeats)

    def _say_repeats(self, failing: str | None, repeats: int) -> None:
        if failing is not None and repeats:
            self.log.error("%s %d more times the same way (%s)", self.failed, repeats, failing)

    def stop(self, timeout: float) -> None:
        """Ask the thread to end and wait for it up to ``timeout`` seconds (a step under way finishes)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
