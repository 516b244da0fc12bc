"""A candidate model in shadow: it decides on the serving model's windows off the hot thread, and the
health view compares the two (``[model] shadow``; docs/GUIDE.md, "A candidate in shadow").

The hot thread hands each decided window (a copy) and the serving decision to ``offer``: one
``put_nowait`` into a bounded queue, a full queue drops the window and counts it, nothing waits. A
thread of its own weighs the shadow folder's files with the model folder's watcher and quarantine
(runtime.model_watch: the same checks and warm-up; a candidate that cannot be fed the serving
model's windows is refused in one line), runs the candidate on each window, counts the comparison
(runtime.shadow_stats) and sends a ``"type": "shadow"`` line when either model would report an event.
"""

from __future__ import annotations

import json
import logging
import queue
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from runtime.background import Background
from runtime.frame_rate import fed_as_it_comes
from runtime.health import Health, one_line
from runtime.model_watch import ModelWatcher, Rejection
from runtime.output_check import output_problem
from runtime.quarantine import QuarantineStore
from runtime.shadow_stats import Comparison, judged_right
from runtime.sinks import PROTOCOL_VERSION
from runtime.trigger_settings import resolve_trigger

if TYPE_CHECKING:
    from runtime.config import Config
    from runtime.detector import Decision
    from runtime.model import LoadedModel
    from runtime.ring import RingBuffer

__all__ = ["QUEUE_WINDOWS", "Shadow"]

log = logging.getLogger("handover.shadow")

QUEUE_WINDOWS = 32
"""Windows waiting for the candidate at most (a second of continuous mode); more are dropped and counted."""
EVENTS_KEPT = 64
"""Reported windows remembered for the robot's outcome on them (it comes seconds after the event)."""
WAIT_S = 0.1
"""Longest the shadow thread waits for a window before it looks at the folder and the serving model again."""


@dataclass
class ShadowLine:
    """The candidate's decision on a window the serving model decided (a ``"type": "shadow"`` line)."""

    time: float
    cls: str
    scores: dict[str, float]
    reported: bool
    """Whether the candidate's class is one ``scene.events`` reports (it would have been an event)."""
    latency_us: float
    """The candidate's own decision time, in the shadow thread."""
    model_id: str
    serving_class: str
    serving_reported: bool
    serving_model_id: str
    frame_first: int
    frame_last: int
    device_time_ms: int
    instance: str = ""

    def to_json(self) -> str:
        return json.dumps({
            "type": "shadow", "protocol": PROTOCOL_VERSION, "instance": self.instance, "class": self.cls,
            "time": self.time, "scores": {k: round(float(v), 6) for k, v in self.scores.items()},
            "reported": self.reported, "latency_us": round(float(self.latency_us), 1), "model_id": self.model_id,
            "serving_class": self.serving_class, "serving_reported": self.serving_reported,
            "serving_model_id": self.serving_model_id, "agrees": self.cls == self.serving_class,
            "frame_first": self.frame_first, "frame_last": self.frame_last, "device_time_ms": self.device_time_ms},
            separators=(",", ":"), allow_nan=False)


@dataclass(slots=True)
class Offered:
    """One decided window as the hot thread hands it over."""

    window: np.ndarray
    """float32 ``[1, T, C]``, a copy of the ring's."""
    model: Any
    serving_class: str
    serving_reported: bool
    frame_first: int
    frame_last: int
    device_time_ms: int
    time: float


def _trigger_problem(mine: Any, serving: Any) -> str | None:
    """Why a candidate cut by trigger settings ``mine`` is not judged on windows cut by ``serving``'s, or None:
    in shadow it would answer windows it was not trained on (a model from before ``back_frames``, say)."""
    differ = [f"{k} {v!r} (the serving model's {getattr(serving, k)!r})" for k, v in asdict(mine).items()
              if v != getattr(serving, k)]
    if not differ:
        return None
    return (f"its windows were cut by another trigger: {', '.join(differ)}; on the serving model's windows it would "
            "be judged on cuts it was not trained on: promote it without a shadow verdict (docs/GUIDE.md) or train "
            "both with one trigger")


class Shadow:
    """The candidate of ``cfg.model.shadow`` (none when unset). ``loader`` and ``scene_check`` are the model
    folder's (runtime.model_serving.ModelSlot.load and .problem), ``quarantine`` its store; ``serving()`` is the
    model serving now; ``emit`` sends a line to the sinks (from the shadow thread)."""

    def __init__(self, cfg: Config, health: Health, loader: Callable[[Path], Any],
                 scene_check: Callable[[Any], str | None], quarantine: QuarantineStore,
                 serving: Callable[[], Any], emit: Callable[[ShadowLine], object],
                 clock: Callable[[], float] = time.perf_counter, queue_size: int = QUEUE_WINDOWS) -> None:
        self.cfg, self.health, self.loader, self.scene_check = cfg, health, loader, scene_check
        self.quarantine, self.serving, self.emit, self.clock = quarantine, serving, emit, clock
        self.candidate: LoadedModel | None = None
        """The candidate that runs now (set by the shadow thread; the hot thread only reads it)."""
        self.comparison: Comparison | None = None
        self.dropped = 0
        """Windows not handed over because the queue was full (written by the hot thread only)."""
        self.rejected = 0
        self.quarantined = 0
        self.watcher: ModelWatcher | None = None
        self._queue: queue.Queue[Offered] = queue.Queue(maxsize=queue_size)
        self._loop: Background | None = None
        self._said: dict = {}
        self._seen: Any = None
        """The serving model the candidate was last weighed against."""
        self._next_poll = 0.0
        self._first_poll = True
        self._last_event: int | None = None
        """The last frame of the newest window the serving model reported (the hot thread writes it)."""
        self._outcomes: deque[tuple[int, str]] = deque(maxlen=64)
        """(event's last frame, the robot's word), from the control socket's or ROS 2's thread."""
        self._events: dict[int, tuple[str, str, tuple[str, ...]]] = {}
        """The last ``EVENTS_KEPT`` reported windows compared: last frame -> (serving class, candidate class, the
        serving model's classes)."""

    # -- the hot thread's side ------------------------------------------------------------------------
    def offer(self, decision: Decision, ring: RingBuffer) -> None:
        """Hand the decided window and the serving decision to the shadow thread; never waits."""
        if self.candidate is None:
            return
        model, frame = decision.model, decision.frame
        if decision.report >= 0:
            self._last_event = frame.number
        item = Offered(ring.window(model.meta.T).copy(), model, model.meta.classes[decision.label],
                       decision.report >= 0, decision.first, frame.number, int(frame.timestamp_ms), time.time())
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    # -- the control socket's and the ROS 2 node's threads -----------------------------------------------
    def outcome(self, word: str) -> None:
        """The robot's word on its last event (field capture took it): both models judged by it in the shadow
        thread (runtime.shadow_stats.judged_right)."""
        if self.candidate is not None and self._last_event is not None:
            self._outcomes.append((self._last_event, word))

    # -- between frames: start, stop, reload, health -----------------------------------------------------
    @property
    def folder(self) -> str | None:
        return self.cfg.model.shadow

    def start(self) -> None:
        """Watch ``cfg.model.shadow`` from the shadow thread (nothing when unset). A thread still warming up a
        candidate is not waited for beyond 0.1 s (a reload runs between frames): it ends after that step."""
        self.stop(timeout=0.1)
        if self.watch():
            self._loop = Background("shadow", self.step, lambda: 0.0, log, "shadow step failed")
            self._loop.start()

    def watch(self) -> bool:
        """A watcher on ``cfg.model.shadow`` for ``step`` (False when unset); ``start`` runs ``step`` in a thread."""
        if not self.folder:
            return False
        self.watcher = ModelWatcher(
            self.folder, loader=self.loader, check=self.fit_problem, poll_interval=self.cfg.model.poll_interval_s,
            decision_budget=self.cfg.model.decision_budget, on_reject=self._rejected, quarantine=self.quarantine,
            said=self._said, after_reject="it does not run in shadow (model.shadow); serving goes on", key="model.shadow")
        self._first_poll, self._next_poll = True, 0.0
        return True

    def stop(self, timeout: float = 0.5) -> None:
        if self._loop is not None:
            self._loop.stop(timeout)
            self._loop = None
        self.watcher = None
        self.candidate = None

    def refit(self, cfg: Config) -> None:
        """A reloaded config: a new shadow folder or model settings start the shadow afresh."""
        old, self.cfg = self.cfg, cfg
        if (cfg.model, cfg.onnxruntime, cfg.scene) != (old.model, old.onnxruntime, old.scene):
            self.start()

    def counters(self) -> dict[str, Any]:
        """The health view's ``shadow``: the folder, the candidate against the serving model, what was refused."""
        if not self.folder:
            return {}
        comparison = self.comparison
        figures = comparison.figures(self.dropped) if comparison is not None else {"candidate_id": None}
        return {"shadow": {"folder": self.folder, "models_rejected": self.rejected,
                           "models_quarantined": self.quarantined, **figures}}

    # -- the shadow thread ------------------------------------------------------------------------------
    def step(self) -> None:
        """One turn of the shadow thread: the folder when due, the serving model followed, one window compared."""
        watcher = self.watcher
        if watcher is None:
            return
        now = self.clock()
        if now >= self._next_poll:
            self._next_poll = now + self.cfg.model.poll_interval_s
            self._poll(watcher)
        self._follow(self.serving())
        try:
            item = self._queue.get(timeout=WAIT_S)
        except queue.Empty:
            item = None
        if item is not None:
            self.compare(item)
        self._judge()

    def _judge(self) -> None:
        """The robot's outcomes heard since the last turn, on the events both models decided."""
        candidate, comparison = self.candidate, self.comparison
        while self._outcomes:
            frame_last, word = self._outcomes.popleft()
            pair = self._events.get(frame_last)
            if candidate is None or comparison is None or pair is None:
                continue  # the window was dropped, or came before this candidate
            classes = (*pair[2], *candidate.meta.classes)  # a class name of either model is a person's label
            serving, mine = judged_right(pair[0], word, classes), judged_right(pair[1], word, classes)
            if serving is not None and mine is not None:
                comparison.judge(frame_last, serving, mine)

    def fit_problem(self, candidate: Any) -> str | None:
        """Why ``candidate`` cannot run beside the serving model on its windows, or None."""
        serving = self.serving()
        if serving is None:
            return "no model serves, so no window to compare it on; weighed again when one serves"
        if problem := self.scene_check(candidate):
            return problem
        ms, mc = serving.meta, candidate.meta
        if not fed_as_it_comes(ms.sample_rate_hz, mc.sample_rate_hz):
            return (f"its sample rate is {mc.sample_rate_hz:.2f} Hz, the serving model's {ms.sample_rate_hz:.2f} Hz: "
                    "the serving model's frames would reach it at another rate; train it at the serving rate")
        for what, a, b in (("window", mc.T, ms.T),
                           ("pads", list(mc.pads), list(ms.pads)), ("taxel columns", mc.n_channels, ms.n_channels)):
            if a != b:
                return (f"its {what} is {a}, the serving model's {b}: it cannot be fed the serving model's windows; "
                        "train it on the same pads, window and rate")
        pinned = self.cfg.trigger
        return _trigger_problem(resolve_trigger(pinned, mc.trigger), resolve_trigger(pinned, ms.trigger))

    def _poll(self, watcher: ModelWatcher) -> None:
        watcher.poll(require_stable=not self._first_poll)
        self._first_poll = False
        model = watcher.take()
        if watcher is not self.watcher:  # a reload replaced the watcher meanwhile
            return
        if model is not None:
            self._arrive(model)
        elif watcher.take_withdrawal() and self.candidate is not None:
            log.warning("shadow: candidate %s left %s; no candidate runs until one is dropped",
                        self.candidate.model_id, self.folder)
            self.candidate = None

    def _arrive(self, model: LoadedModel) -> None:
        self.comparison = Comparison(model.model_id, Path(model.path).name, self.dropped)
        self.candidate = model
        self.health.resolve("shadow")
        serving = self.serving()
        log.info("shadow: candidate %s (%s) runs beside serving model %s on its windows", model.model_id,
                 Path(model.path).name, serving.model_id if serving is not None else "none")

    def _follow(self, serving: Any) -> None:
        """The serving model changed: the candidate is weighed against the new one (or waits for one)."""
        if serving is self._seen:
            return
        self._seen = serving
        candidate = self.candidate
        if candidate is not None and (problem := self.fit_problem(candidate)):
            log.warning("shadow: candidate %s stops: %s", candidate.model_id, problem)
            self.health.report_error(f"shadow model {Path(candidate.path).name} stops: {problem}", "shadow")
            self.candidate = None
        if self.candidate is None and self.watcher is not None:
            self.watcher.rescan(keep_current=False)  # a file refused for the old serving model may fit the new one

    def compare(self, item: Offered) -> None:
        """The candidate on one offered window: counted, and a shadow line when either model reports."""
        model, comparison = self.candidate, self.comparison
        if model is None or comparison is None or item.window.shape[1:] != (model.meta.T, model.meta.n_channels):
            return  # no candidate, or a window of a serving model it was not weighed against
        started = self.clock()
        try:
            labels, scores = model.run_trusted(item.window)
            problem = output_problem(labels, scores, model.meta.n_classes)
        except Exception as exc:  # a graph that fails on real frames only
            problem = f"inference failed: {one_line(exc)}"
        latency_us = (self.clock() - started) * 1e6
        if problem is not None:
            return self._take_out(model, f"{problem} (frames {item.frame_first}..{item.frame_last})")
        cls = model.meta.classes[int(labels[0])]
        reported = cls in self.cfg.scene.events
        comparison.add(item.serving_class, item.serving_reported, cls, reported, latency_us)
        if item.serving_reported:
            self._events[item.frame_last] = (item.serving_class, cls, tuple(item.model.meta.classes))
            while len(self._events) > EVENTS_KEPT:
                del self._events[next(iter(self._events))]
        if reported or item.serving_reported:
            self.emit(ShadowLine(item.time, cls, dict(zip(model.meta.classes, scores[0].tolist(), strict=True)),
                                 reported, latency_us, model.model_id, item.serving_class, item.serving_reported,
                                 item.model.model_id, item.frame_first, item.frame_last, item.device_time_ms))

    def _take_out(self, model: LoadedModel, reason: str) -> None:
        """The candidate broke the output contract: quarantined as a serving model would be; serving goes on."""
        self.quarantined += 1
        self.candidate = None
        if self.watcher is not None:
            self.watcher.quarantine_file(Path(model.path), reason)
            self.watcher.reconsider_older()
        else:
            self.quarantine.quarantine_file(model.path, reason)
        log.error("shadow: candidate %s (%s) taken out: %s; it is not loaded again until the file changes; serving "
                  "goes on", model.model_id, Path(model.path).name, reason)
        self.health.report_error(f"shadow model {Path(model.path).name} taken out: {reason}", "shadow")

    def _rejected(self, rejection: Rejection) -> None:
        if not rejection.repeat:
            self.rejected += 1
        self.health.report_error(f"shadow model {rejection.path.name} rejected: {rejection.reason}", "shadow")
