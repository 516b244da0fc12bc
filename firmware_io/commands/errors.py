"""How every ``handover`` command reports a mistake it can name: one line on stderr, an exit code.

The house rule: ``handover CMD: <what is wrong and what to do>``, exit 2 for a user error
(bad option, bad file, bad URL). Commands pass another code where a device or the run itself
failed (1) or the user interrupted (130). Lives in firmware_io, the lowest package, so the
commands of every package can call it.
"""

from __future__ import annotations

import sys

__all__ = ["DEVICE_ERROR", "INTERRUPTED", "USER_ERROR", "fail"]

USER_ERROR = 2
"""Bad option, bad file, bad URL: what the user can fix."""
DEVICE_ERROR = 1
"""The device could not be opened or was lost: check the link, run again."""
INTERRUPTED = 130
"""Ctrl-C, as a shell reports SIGINT."""


def fail(command: str, message: str, code: int = USER_ERROR) -> int:
    """Print ``handover <command>: <message>`` to stderr and return ``code`` (the command's exit code)."""
    print(f"handover {command}: {message}", file=sys.stderr)
    return code
