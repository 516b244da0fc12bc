"""Observing the daemon's hot path: listeners called with each frame and each decision.

As python-can's Notifier/Listener: ``Daemon.listeners`` is a plain list, so benchmarks and tests drive
the real ``Daemon.handle_frame`` and a daemon without listeners pays one empty-list check per frame.
Listeners run in the daemon's thread: they must be quick and must not raise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from runtime.detector import Decision

__all__ = ["DecisionTimings", "FrameListener", "FrameRecorder"]


@dataclass(slots=True)
class DecisionTimings:
    """``time.perf_counter()`` stamps of one decision, in the order the stages run.

    ``received``: the frame's last byte parsed (``Frame.received``; parse, CRC, decode, plausibility
    and ring push + trigger of this frame lie between it and ``started``); ``started``: this
    decision begins; ``windowed``: the model's input window taken from the ring; ``decided``: the model answered (the decision's latency ends here);
    ``checked``: output contract checked; ``built``: the event object built; ``serialised``: its
    JSON line encoded; ``sent``: handed to every sink. The last three stay None when no event is
    reported (continuous mode between reports, a class outside ``scene.events``).
    """

    received: float
    started: float
    windowed: float
    decided: float
    checked: float
    built: float | None = None
    serialised: float | None = None
    sent: float | None = None


class FrameListener:
    """Base listener: override what you need (both do nothing here)."""

    def on_frame(self, frame: Any) -> None:
        """A frame ``Daemon.handle_frame`` is about to handle (before ring, trigger and model)."""

    def on_decision(self, decision: Decision) -> None:
        """The model decided (``decision.frame`` ends the window, ``decision.timings`` stamps its stages,
        ``decision.report`` says whether an event went out): called after the event, if any, was sent."""


class FrameRecorder(FrameListener):
    """Keeps the numbers of the frames handled and the timings of the decisions (tests, benchmarks)."""

    def __init__(self) -> None:
        self.frames: list[int] = []
        self.decisions: list[tuple[int, DecisionTimings]] = []

    def on_frame(self, frame: Any) -> None:
        self.frames.append(frame.number)

    def on_decision(self, decision: Decision) -> None:
        self.decisions.append((decision.frame.number, decision.timings))
