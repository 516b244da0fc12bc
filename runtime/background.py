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
    ``stop``; ``on_start`` runs first in the thread. A step's exception is logged as ``failed`` on ``log``."""

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
        """Start the thread; a second start while it runs does nothing."""
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        if self.on_start is not None:
            self.on_start()
        while not self._stop.wait(self.interval()):
            try:
                self.step()
            except Exception:
                self.log.exception(self.failed)

    def stop(self, timeout: float) -> None:
        """Ask the thread to end and wait for it up to ``timeout`` seconds (a step under way finishes)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
