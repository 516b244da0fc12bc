"""Waiting in tests for what another thread or process does: poll a condition, never sleep a guess."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable


def wait_for(condition: Callable[[], object], timeout: float = 10.0) -> bool:
    """Poll ``condition`` every 10 ms until it holds or ``timeout`` seconds pass; whether it holds then."""
    deadline = time.monotonic() + timeout
    while not condition() and time.monotonic() < deadline:
        time.sleep(0.01)
    return bool(condition())


def sigterm_seconds(proc: subprocess.Popen) -> float:
    """Send SIGTERM; seconds until the process ended (killed, and the test failed, after 10 s)."""
    start = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    return time.monotonic() - start
