"""The detection daemon's main loop: frames -> ring -> trigger -> inference -> sinks.

One thread does the hot path. Per frame: copy the scene's columns into the ring, one max for
the trigger; only when a window's last frame has arrived does the model run, at once, and the
time from that frame's arrival (``Frame.received``) to the decision is recorded. A decision
later than one sample period is a missed deadline.

Everything slow happens elsewhere or between frames: model files are validated and warmed
up by the watcher thread and swapped in by one reference assignment between two windows;
the health file is written about once a second; the device is reopened with backoff after
an unplug or a stall; SIGTERM ends the loop within a read timeout (0.1 s); SIGHUP reloads
the config and keeps the old one if the new one is invalid.
"""

from __future__ import annotations

import logging
import signal
import time
from collections import deque
from collections.abc import Callable
from functools import partial
from typing import IO, Any

from firmware_io.layout import SensorLayout
from runtime import realtime
from runtime.arm_motion import ArmMotion, arm_frames
from runtime.config import Config
from runtime.config_reload import ConfigReload, set_log_level
from runtime.control import ControlSocket, GraspControl, MessageLog
from runtime.decision import ContinuousDecision
from runtime.device_link import CONNECT_BOUND_S, DeviceLink, default_client
from runtime.frame_rate import FrameClock
from runtime.health import Health, StatusFile, one_line
from runtime.heap import GarbageSchedule, release_heap, settle_heap
from runtime.listeners import DecisionTimings, FrameListener
from runtime.model_serving import DEFAULT_RATE_HZ, ModelServing
from runtime.model_watch import ModelWatcher
from runtime.output_check import output_problem
from runtime.quarantine import QuarantineStore, store_path
from runtime.rehearsal import Rehearsal
from runtime.retry_notes import RetryNotes
from runtime.ring import RingBuffer
from runtime.scene import events_problem, scene_problem
from runtime.sdnotify import Notifier
from runtime.sinks import Event, SinkSet
from runtime.trigger_settings import TriggerSettings

__all__ = ["Daemon", "events_problem", "scene_problem"]  # the last two are re-exported for run --check

log = logging.getLogger("handover.daemon")

READ_TIMEOUT_S = 0.1
"""Longest the loop blocks on the device: bounds the reaction to SIGTERM and the watchdog."""
HEALTH_PERIOD_S = 1.0
HOLD_LIMIT_S = 10.0
"""How long open windows may hold back a model swap or a reload (``Daemon.windows_hold``); longer
for a stream so slow that two windows take longer."""
SHUTDOWN_STOP_S = 0.3
"""Longest the stop handshake may take at shutdown (SIGTERM must end the process within 1 s)."""


def _event(model: Any, frame: Any, index: int, scores: Any, latency_us: float, missed: bool, first: int) -> Event:
    """The decision line of class ``index`` for the window ending at ``frame`` (its first frame ``first``)."""
    meta = model.meta
    return Event(time.time(), meta.classes[index], dict(zip(meta.classes, scores[0].tolist(), strict=True)),
                 latency_us, model.model_id, first, frame.number, int(frame.timestamp_ms), missed)


class Daemon(GraspControl, ModelServing, DeviceLink, ConfigReload):
    """The long-running service. ``run()`` returns the exit code.

    This module holds the loop and the hot path; the mixins hold the rest: which model serves
    (runtime.model_serving), the device link (runtime.device_link), SIGHUP (runtime.config_reload)
    and the robot's grasp messages (runtime.control).
    """

    def __init__(
        self,
        cfg: Config,
        notifier: Notifier | None = None,
        stream: IO[str] | None = None,
        client_factory: Callable[[str], Any] | None = None,
        on_event: Callable[[Event], None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.notifier = notifier or Notifier()
        self.stream = stream
        self.client_factory = client_factory or default_client
        self.on_event = on_event
        self.health = Health()
        self.status_file: StatusFile | None = StatusFile(cfg.health_file) if cfg.health_file else None
        self.latest_frame: Any = None
        """The newest frame (the ROS 2 sink's pad images read it from their own thread)."""
        self.grasp_request: tuple[bool, str] | None = None
        """The latest ``set_grasp`` call: (closed, source)."""
        self.sinks = SinkSet.from_config(cfg.sinks, stream, ros2=cfg.ros2, daemon=self)
        self.model: Any = None
        self._fallback: Any = None
        """The model the last swap replaced: it serves again if the new one is taken out of service."""
        self._announced: Any = None
        """The model of the last ``model`` line: the next line's ``previous_model_id``."""
        self.quarantine = QuarantineStore(store_path(cfg.model.quarantine_file, cfg.health_file))
        self.layout: SensorLayout | None = None
        self.client: Any = None
        self.connected = False
        self.ring: RingBuffer | None = None
        self.trigger: Any = None
        """ThresholdTrigger, OnsetTrigger (runtime/onset.py) or ContinuousTrigger."""
        self.trigger_settings: TriggerSettings | None = None
        self._trigger_key: tuple | None = None
        """What the trigger was built from (runtime.model_serving): the same key keeps it, and its state."""
        self._grasp_requests: deque[tuple[bool, str]] = deque(maxlen=64)
        self.grasp_closed: bool | None = None
        """The robot's last word on its grasp (``set_grasp``), None before any."""
        self.control: ControlSocket | None = None
        self._messages = MessageLog()
        self.arm = ArmMotion(*arm_frames(DEFAULT_RATE_HZ, cfg.control.arm_settle_s, cfg.control.arm_max_move_s))
        """Which frames the robot's arm counts as moving in (``set_arm_moving``; runtime.arm_motion)."""
        self.arm_request: tuple[bool, str] | None = None
        """The latest ``set_arm_moving`` call: (moving, source)."""
        self.decision: ContinuousDecision | None = None
        """Continuous mode's report rule (confirm, margin, one report per interaction)."""
        self.watcher: ModelWatcher | None = None
        self._stop = False
        self._reload = False
        self.fatal: str | None = None
        """Why the daemon gave up (a device URL that can never open, a missing package), or None."""
        self._pending: list[int] = []
        self._refused_mark = 0
        """Frames the client had refused (CRC, undecodable, implausible) at the last stall."""
        self._held_since: float | None = None
        """Since when open windows have held back a model swap or a reload (``windows_hold``)."""
        self._backoff = cfg.device.reconnect_min_s
        self._next_connect = 0.0
        self.retry_notes = RetryNotes()
        """Which failed connection attempts get a log line (the first, then after 1, 10, 60 min)."""
        self._last_frame_t = 0.0
        self._next_health = 0.0
        self._connect_started: float | None = None
        self._link_up_at: float | None = None
        """When the device connection now up was made (a drop soon after counts as a failed attempt)."""
        self._back_note_due = False
        self._flapping = False
        self.connect_bound_s = CONNECT_BOUND_S
        self._hang_logged = False
        self.period_s = 1.0 / DEFAULT_RATE_HZ
        self.frame_clock = FrameClock(1000.0 * self.period_s, self.health, on_restart=self._restart_stream)
        """Feeds the model at its trained period: decimates faster streams, warns on slower ones."""
        self._rt_applied = False
        """Whether this link's first valid frame has applied ``realtime_priority`` (``raise_priority``)."""
        self._rt_before: realtime.Scheduling | None = None
        """The scheduling to restore, while the thread is raised."""
        self._rt_logged: int | None = None
        """The ``realtime_priority`` whose outcome was logged (one line per setting)."""
        self.garbage = GarbageSchedule()
        """Collects from the loop between windows; automatic collection is off once running (runtime.heap)."""
        self.rehearsal = Rehearsal()
        """Keeps the hot path warm for a due frame: the model runs once just before it, then the
        device is polled instead of slept on (runtime.rehearsal)."""
        self.listeners: list[FrameListener] = []
        """Called with every frame handled and every decision's stage timings (runtime.listeners);
        benchmarks and tests observe the real hot path through them. Empty: one list check per frame."""

    # -- control --------------------------------------------------------------------------------
    def request_stop(self, *_: Any) -> None:
        self._stop = True

    def request_reload(self, *_: Any) -> None:
        self._reload = True

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self.request_stop)
        signal.signal(signal.SIGINT, self.request_stop)
        signal.signal(signal.SIGHUP, self.request_reload)

    @property
    def window_open(self) -> bool:
        """Whether a trigger has fired and its window's last frame is still to come."""
        return bool(self._pending)

    def windows_hold(self, now: float) -> bool:
        """Whether open windows still hold back a model swap or a reload that wants in: it waits for
        their decisions, but at most ``HOLD_LIMIT_S``; then the open windows are dropped (one warning
        line), so a trigger that fires all the time cannot keep a new model or config out for ever."""
        if not self._pending:
            self._held_since = None
            return False
        if self._held_since is None:
            self._held_since = now
        window_s = self.model.meta.T * self.frame_clock.next_admitted_s() if self.model is not None else 0.0
        if now - self._held_since < max(HOLD_LIMIT_S, 2 * window_s):  # a slow stream's windows still end
            return True
        log.warning("a model swap or reload waited %g s for windows that kept opening; %d open window(s) "
                    "dropped undecided to let it in (the trigger fires all the time: see [trigger] "
                    "refractory_s and rearm_quiet_s)", now - self._held_since, len(self._pending))
        self._pending.clear()
        self.rehearsal.cancel()
        self._held_since = None
        return False

    def collect_garbage(self, now: float) -> None:
        """What the loop collects between frames (runtime.heap): not inside a window nor just before a
        due frame, unless held back too long."""
        due = self.rehearsal.due  # a perf_counter time; ``now`` may be another clock
        self.garbage.collect(now, self.window_open, None if due is None else due - time.perf_counter())

    # -- the hot path -----------------------------------------------------------------------------
    def handle_frame(self, frame: Any) -> None:
        """One frame: ring, trigger, and inference if this frame ends a window."""
        self.health.frames_received += 1
        number = self.frame_clock.admit(frame.number, frame.timestamp_ms)  # the model's frame count; -1: skip
        if number < 0:
            return
        if self.listeners:
            for listener in self.listeners:
                listener.on_frame(frame)
        self.latest_frame = frame
        ring = self.ring
        ring.push(frame.values, number)
        if self._grasp_requests:
            self._apply_grasp()
        self.arm.update(number)
        due = self.trigger.update(ring.latest(), number)
        if self.model is None:
            return
        pending = self._pending
        if due >= 0:
            pending.append(due)
        if pending and number >= pending[0]:
            due = pending.pop(0)
            if number == due and ring.count >= self.model.meta.T:
                if self.arm.touches(number - self.model.meta.T + 1):
                    self._judged_dormant()
                else:
                    self._classify(frame)
        elif pending and number + 1 == pending[0] and ring.count >= self.model.meta.T:
            self._expect_next(frame)  # keep warm for the frame that completes the window, due one period on

    def _judged_dormant(self) -> None:
        """A window that held frames of the arm's motion (runtime.arm_motion): the model does not run;
        continuous mode's report rule sees the dormant class."""
        if self.decision is not None:
            self.decision.update(self.decision.dormant)

    def _expect_next(self, frame: Any) -> None:
        """The next frame is due: rehearse its decision shortly before it arrives (runtime.rehearsal)."""
        model, ring = self.model, self.ring
        self.rehearsal.expect(frame.received + self.frame_clock.next_admitted_s(),
                              partial(self._rehearse, model, ring.window(model.meta.T)))

    def _rehearse(self, model: Any, window: Any) -> None:
        """The due frame's path once ahead of it, nothing sent or counted: the model, the output
        check, an event built and encoded (not sent), then the client's receive path (parse, CRC,
        decode, plausibility), the code that frame meets first; and the model once more, so that the
        largest part of the decision is also the last one warmed (paced stage table, medians: inference
        112-125 us without that run, 81-83 us with it)."""
        labels, scores = model.run_trusted(window)
        frame = self.latest_frame
        if output_problem(labels, scores, model.meta.n_classes) is None and frame is not None:
            _event(model, frame, int(labels[0]), scores, 0.0, False, 0).to_json().encode()
        rehearse = getattr(self.client, "rehearse", None)
        if rehearse is not None:
            rehearse()
        model.run_trusted(window)

    def _classify(self, frame: Any) -> None:
        """Run the model on the window ending at ``frame``, check, report; each stage stamped."""
        clock = time.perf_counter
        started = clock()
        self.rehearsal.cancel()
        model = self.model
        meta = model.meta
        window = self.ring.window(meta.T)  # a float32 [1, T, C] view of the ring: no copy
        windowed = clock()
        try:
            labels, scores = model.run_trusted(window)
        except Exception as exc:  # a graph that fails on real frames only
            self._take_out_of_service(model, f"inference failed on frames {frame.number - meta.T + 1}.."
                                             f"{frame.number}: {one_line(exc)}")
            return
        decided = clock()
        problem = output_problem(labels, scores, meta.n_classes)
        if problem:
            self._take_out_of_service(model, f"{problem} (frames {frame.number - meta.T + 1}..{frame.number})")
            return
        stamps = DecisionTimings(frame.received, started, windowed, decided, clock())
        latency_us = (decided - frame.received) * 1e6
        h = self.health
        h.decisions += 1
        h.record_latency(latency_us)
        missed = latency_us > self.period_s * 1e6
        if missed:
            h.missed_deadlines += 1
        index = int(labels[0])
        if self.decision is not None:  # continuous mode: one report per confirmed interaction
            index = self.decision.update(index, scores[0])
        cls = meta.classes[index] if index >= 0 else None
        if cls is not None and cls in self.cfg.scene.events:
            event = _event(model, frame, index, scores, latency_us, missed,
                           self.frame_clock.window_first(frame.number, meta.T))
            stamps.built = clock()
            encoded = self.sinks.encode(event)
            stamps.serialised = clock()
            h.events += 1
            if encoded is not None:
                self.sinks.send(*encoded)
            stamps.sent = clock()
            if self.on_event is not None:
                self.on_event(event)
        if self.listeners:
            for listener in self.listeners:
                listener.on_decision(frame, stamps)

    def _frame_failed(self, exc: BaseException) -> None:
        """An exception while handling one frame: counted, logged at most every 10 s, never fatal."""
        if self.health.frame_failed(one_line(exc)):
            log.error("frame handling failed (%d so far; the loop goes on): %s: %s", self.health.frame_errors,
                      type(exc).__name__, one_line(exc))

    # -- housekeeping ---------------------------------------------------------------------------
    def _housekeeping(self, now: float) -> None:
        self.collect_garbage(now)
        self.notifier.watchdog(now)
        self._swap_and_report(now)
        self._link_held()

    def _swap_and_report(self, now: float) -> None:
        """Take a pending model and write the health file when due (the loop and a slow connect)."""
        self._take_pending_model(now)
        if now >= self._next_health:
            self._next_health = now + HEALTH_PERIOD_S
            self.write_health(now)

    def write_health(self, now: float | None = None) -> None:
        h = self.health
        h.update_rate(now)
        self._absorb_client_stats()
        self._mark_refusals(time.monotonic() if now is None else now, HEALTH_PERIOD_S)
        h.sink_errors = self.sinks.errors
        h.events_invalid = self.sinks.invalid
        self.notifier.status(h.status_line())
        snapshot = h.snapshot()
        if self.status_file is not None:
            self.status_file.write(snapshot)
        self.sinks.health(snapshot)

    # -- main loop ------------------------------------------------------------------------------
    def run(self) -> int:
        """Serve until SIGTERM / request_stop(); returns 0, or 2 when the device URL can never
        work (``self.fatal`` says why)."""
        set_log_level(self.cfg.log_level)
        for warning in self.cfg.warnings:
            log.warning("%s", warning)
        self._start_watcher()
        self.start_control()
        settle_heap()
        self.notifier.ready(self.health.status_line())
        log.info("handover daemon ready (device %s, scene %s, mode %s)", self.cfg.device.url,
                 self.cfg.scene.pads, self.cfg.scene.mode)
        try:
            while not self._stop:
                if self._reload and not self.windows_hold(time.monotonic()):  # not inside a window
                    self._do_reload()
                now = time.monotonic()
                self._housekeeping(now)
                if not self.connected:
                    if now >= self._next_connect:
                        self._connect()
                    else:
                        time.sleep(min(READ_TIMEOUT_S, self._next_connect - now))
                    continue
                try:
                    frame = self.rehearsal.read(self.client.read_frame, READ_TIMEOUT_S)
                except Exception as exc:  # unplug, closed link, end of a replay: reconnect
                    self._fault(one_line(exc))
                    continue
                if frame is None:
                    if time.monotonic() - self._last_frame_t > self.cfg.device.stall_timeout_s:
                        self.health.stalls += 1
                        self._fault(self._stall_reason(), link_lost=False)
                    continue
                self._last_frame_t = time.monotonic()
                if not self._rt_applied:
                    self.raise_priority()
                if not self._flapping:  # a link that keeps dropping soon after connecting keeps backing off
                    self._backoff = self.cfg.device.reconnect_min_s
                try:
                    self.handle_frame(frame)
                except Exception as exc:  # never let one frame end the service
                    self._frame_failed(exc)
        finally:
            self.shutdown()
            self.lower_priority()
            release_heap()
        return 2 if self.fatal else 0

    def raise_priority(self) -> None:
        """The config's ``realtime_priority`` for this (the hot) thread, once the link delivers a valid
        frame: a device that sends only garbage never gets the CPU at real-time priority. One log line
        per setting says what came of it."""
        priority = self.cfg.realtime_priority
        before, line = realtime.enter_realtime(priority)
        self._rt_applied = True
        self._rt_before = before if priority > 0 else None
        if self._rt_logged != priority:
            self._rt_logged = priority
            log.info("%s", line)  # normal scheduling works, only with longer tails under load: not a warning

    def lower_priority(self) -> None:
        """Back to the scheduling the thread had (the link failed, the config changed, the daemon stops)."""
        if self._rt_before is not None:
            realtime.restore(self._rt_before)
        self._rt_applied, self._rt_before = False, None

    def apply_scheduling(self) -> None:
        """A reload's ``realtime_priority``: taken at once while streaming, else with the next frame."""
        if self._rt_applied:
            self.lower_priority()
            self.raise_priority()

    def shutdown(self) -> None:
        """STOPPING=1, stop the watcher, close the device, flush the sinks, final health."""
        self.notifier.stopping()
        if self.watcher is not None:
            self.watcher.stop(timeout=0.5)
        self.stop_control()
        self.rehearsal.cancel()
        self._close_client(stop_timeout=SHUTDOWN_STOP_S)
        self.health.device_state = "stopped" if not self.fatal else "failed"
        if self.fatal:
            self.health.report_error(self.fatal, "device")
        self.write_health()
        self.sinks.close()
        log.info("stopped: %d frames, %d events, %d missed deadlines", self.health.frames_received,
                 self.health.events, self.health.missed_deadlines)

