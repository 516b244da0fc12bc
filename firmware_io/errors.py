"""The one root of every error the three packages raise, and how a command reports one.

A command raises; ``handover``'s ``main`` catches HandoverError once and prints
``handover CMD: <what is wrong and what to do>``, exiting with the error's code: 2 for what the
user can fix (bad option, file, URL), 1 where the device or the run itself failed. Lives in
firmware_io, the lowest package, so every package can derive from it.
"""

from __future__ import annotations

__all__ = ["DEVICE_ERROR", "INTERRUPTED", "DeviceFailure", "HandoverError", "Interrupted"]

USER_ERROR = 2
"""Bad option, bad file, bad URL: what the user can fix."""
DEVICE_ERROR = 1
"""The device could not be opened or was lost: check the link, run again."""
INTERRUPTED = 130
"""Ctrl-C, as a shell reports SIGINT."""


class HandoverError(Exception):
    """Base of every error of firmware_io, runtime and trainer; ``exit_code`` is the command's exit code.

    Subclasses keep their builtin base too (``class X(HandoverError, ValueError)``) so an
    ``except ValueError`` written against them still catches them."""

    exit_code: int = USER_ERROR


class DeviceFailure(HandoverError):
    """The device or the run failed, not the user's input (exit 1)."""

    exit_code = DEVICE_ERROR


class Interrupted(HandoverError):
    """Ctrl-C, said with what was kept (exit 130)."""

    exit_code = INTERRUPTED
